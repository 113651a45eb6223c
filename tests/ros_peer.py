"""The other end of tests/test_ros.py's nodes, run as a process of its own (the test process never
loads rclpy: a ROS process that hangs in DDS teardown is killed by the test, never waited on).

``python tests/ros_peer.py OUT.json twist TOPIC``: records every ``geometry_msgs/TwistStamped`` on
TOPIC (a fake arm controller, as MoveIt Servo would subscribe).
``python tests/ros_peer.py OUT.json track W H FX FY CX CY D0 D1 D2 D3 D4``: records ``ros track``'s
PoseStamped, /tf and status, and publishes CameraInfo with these intrinsics meanwhile.

With ``--ee-pose-topic T --ee-pose x,y,z,qx,qy,qz,qw`` the twist mode also publishes that (fixed)
end-effector pose as PoseStamped on T, as an arm's state publisher would, and stops publishing it
``--pose-after-twist`` seconds after the first twist (the arm's state publisher dies).

Runs until ``--max-s`` or ``--idle-exit`` seconds without a message once some came, then writes
OUT.json (before shutting ROS down) and exits. Prints ``ready`` once subscribed, ``sees NAME`` once
for every other node its graph shows, and ``matched`` once each of its topics (not /tf) has matched
an endpoint of another node (the tests wait for these: see ``_Procs.start_seen`` in test_ros.py).
"""

import argparse
import json
import sys
import time


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("out")
    ap.add_argument("mode", choices=("twist", "track"))
    ap.add_argument("params", nargs="*")
    ap.add_argument("--max-s", type=float, default=60.0)
    ap.add_argument("--idle-exit", type=float, default=2.0)
    ap.add_argument("--ns", default="", help="track: the namespace of its topics (not /tf)")
    ap.add_argument("--ee-pose-topic")
    ap.add_argument("--ee-pose")
    ap.add_argument("--pose-after-twist", type=float, default=float("inf"))
    args = ap.parse_args()

    import rclpy
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    qos = QoSProfile(depth=10_000, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.VOLATILE)  # fmt: skip
    rclpy.init()
    node = rclpy.create_node("evservo_test_peer")
    got: dict[str, list] = {}
    last = [None]

    def keep(kind, row):
        got.setdefault(kind, []).append(row)
        last[0] = time.monotonic()

    info_pub = info = pose_pub = pose = None
    ends = []  # publishers and subscriptions that must match another node's
    if args.mode == "twist":
        from geometry_msgs.msg import TwistStamped

        def on_twist(m):
            t, a = m.twist.linear, m.twist.angular
            stamp = m.header.stamp.sec + m.header.stamp.nanosec * 1e-9
            keep("twists", [time.monotonic(), stamp, m.header.frame_id, [t.x, t.y, t.z, a.x, a.y, a.z]])

        ends.append(node.create_subscription(TwistStamped, args.params[0], on_twist, qos))
        if args.ee_pose_topic:
            from geometry_msgs.msg import PoseStamped

            pose_pub = node.create_publisher(PoseStamped, args.ee_pose_topic, 10)
            ends.append(pose_pub)
            pose = PoseStamped()
            pose.header.frame_id = "base_link"
            p, o = pose.pose.position, pose.pose.orientation
            p.x, p.y, p.z, o.x, o.y, o.z, o.w = (float(v) for v in args.ee_pose.split(","))
    else:
        from geometry_msgs.msg import PoseStamped
        from sensor_msgs.msg import CameraInfo
        from std_msgs.msg import String
        from tf2_msgs.msg import TFMessage

        from evservo.ros.nodes import _qos

        def xyz(p):
            return [p.x, p.y, p.z]

        ns = args.ns or "/evservo"
        ends.append(node.create_subscription(PoseStamped, f"{ns}/pose", lambda m: keep("poses", xyz(m.pose.position)),
                                             _qos()))  # fmt: skip
        node.create_subscription(
            TFMessage, "/tf",
            lambda m: keep("tfs", [m.transforms[0].header.frame_id, m.transforms[0].child_frame_id,
                                   xyz(m.transforms[0].transform.translation)]),
            _qos(),
        )  # fmt: skip
        ends.append(node.create_subscription(String, f"{ns}/status", lambda m: keep("status", json.loads(m.data)),
                                             _qos()))  # fmt: skip
        w, h, fx, fy, cx, cy, *d = (float(v) for v in args.params)
        info = CameraInfo(width=int(w), height=int(h), distortion_model="plumb_bob")
        info.k = [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0]
        info.d = d
        info_pub = node.create_publisher(CameraInfo, f"{args.ns or '/event_camera'}/camera_info", 10)
        ends.append(info_pub)
    print("ready", flush=True)
    seen = {node.get_name()}
    matched = False
    start = time.monotonic()
    while time.monotonic() - start < args.max_s:
        for name in set(node.get_node_names()) - seen:
            print(f"sees {name}", flush=True)
            seen.add(name)
        if not matched and all(_matches(e) for e in ends):
            print("matched", flush=True)
            matched = True
        if last[0] is not None and time.monotonic() - last[0] > args.idle_exit:
            break
        if info_pub is not None:
            info_pub.publish(info)
        first_twist = got["twists"][0][0] if got.get("twists") else None
        if pose_pub is not None and (first_twist is None or time.monotonic() - first_twist < args.pose_after_twist):
            pose_pub.publish(pose)
        rclpy.spin_once(node, timeout_sec=0.02)
    with open(args.out, "w") as f:
        json.dump(got, f)
    node.destroy_node()
    rclpy.shutdown()
    return 0


def _matches(end) -> int:
    return end.get_subscription_count() if hasattr(end, "get_subscription_count") else end.get_publisher_count()


if __name__ == "__main__":
    sys.exit(main())
