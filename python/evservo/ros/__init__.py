"""ROS 2 support (``make ros``): message packages PyPI lacks, generated into the venv
(:mod:`evservo.ros.msgs`), and the nodes behind ``evservo ros`` (:mod:`evservo.ros.nodes`).

Nothing here is imported by ``import evservo``; rclpy and the generated messages load only when a
ROS command runs.
"""
