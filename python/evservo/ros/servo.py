"""The ROS 2 servo node behind ``evservo ros servo`` (rclpy, after ``make ros``): the real loop of
:mod:`evservo.realloop` with its event source a topic and its arm a twist topic.

* Events: ``event_camera_msgs/EventPacket`` (``evt3`` or ``mono``) on ``events_topic``, decoded as
  one stream (as ``ros track``), subscribed best effort so that it matches any driver's publisher.
* Arm: a :class:`~evservo.robots.twist_sink.TwistSink` behind the rig's
  :class:`~evservo.robots.safety.SafetyGate` (limits, workspace, watchdog) publishing
  ``geometry_msgs/TwistStamped`` on ``twist_topic``: the end-effector twist in end-effector axes,
  ``header.frame_id = ee_frame``, one message per control cycle, a zero twist on every halt (the
  loop's watchdog and end, the gate's watchdog, Ctrl-C) — the input of MoveIt Servo
  (``/servo_node/delta_twist_cmds``) or of a Cartesian velocity controller. Reliable and volatile,
  as those subscribe; the loop starts only once a subscriber has matched (twists sent before would
  be lost).
* Arm pose: the newest ``geometry_msgs/PoseStamped`` on ``ee_pose_topic`` (the end effector in the
  robot base frame; older than ``ee_pose_timeout_s`` counts as a lost link, which stops the run),
  or, without one, the sent twists integrated (see :mod:`evservo.robots.twist_sink`).

rclpy runs in a context of its own with its executor in a background thread and no signal handlers
of its own: Ctrl-C reaches the loop as ``KeyboardInterrupt``, the loop stops the arm (a zero twist)
and the publisher waits, boundedly, for that last twist to be acknowledged before the node goes.
"""

from __future__ import annotations

import contextlib
import queue
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import replace
from typing import Any

import numpy as np

from evservo import _evcore
from evservo.interrupt import StopOnInterrupt
from evservo.io import EVENT_CD
from evservo.realloop import RealLoopConfig, RealLoopResult, run_real_loop
from evservo.robots.config import RigConfig
from evservo.ros.nodes import _camera_from_info, _ros, subscribed

#: Longest wait for the last (zero) twist to be acknowledged by its subscribers on the way out (s).
ACK_TIMEOUT_S = 2.0


class RosNode:
    """An rclpy node in its own context, spun by an executor thread (context manager)."""

    def __init__(self, name: str) -> None:
        rclpy = _ros()
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions

        self.context = rclpy.Context()
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node(name, context=self.context)
        self._executor = SingleThreadedExecutor(context=self.context)
        self._executor.add_node(self.node)
        self._thread = threading.Thread(target=self._spin, name=f"{name}-spin", daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        from rclpy.executors import ExternalShutdownException

        with contextlib.suppress(ExternalShutdownException):
            self._executor.spin()

    def close(self) -> None:
        self._executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        if self.context.ok():
            self.context.shutdown()
        self._thread.join(timeout=2.0)

    def __enter__(self) -> RosNode:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _best_effort(depth: int) -> Any:
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(depth=depth, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.VOLATILE)  # fmt: skip


class EventTopic:
    """EventPacket messages on a topic as an event source for the real loop: an iterable of EVENT_CD
    batches that yields an empty batch after ``poll_s`` without a message (so the loop's camera
    thread can be halted) and ends on :meth:`close`."""

    def __init__(self, node: Any, topic: str, poll_s: float = 0.05) -> None:
        from event_camera_msgs.msg import EventPacket

        self.topic, self.poll_s = topic, poll_s
        self._q: queue.Queue[Any] = queue.Queue()
        self._closed = threading.Event()
        node.create_subscription(EventPacket, topic, self._q.put, _best_effort(1000))

    def __iter__(self) -> Iterator[np.ndarray]:
        from evservo import bags

        decode = None
        while not self._closed.is_set():
            try:
                msg = self._q.get(timeout=self.poll_s)
            except queue.Empty:
                yield np.empty(0, dtype=EVENT_CD)
                continue
            if decode is None:
                decode = bags.message_decoder(bags.EVENT_PACKET, msg.encoding, msg.width, msg.height, self.topic)
            yield decode(msg)

    def close(self) -> None:
        self._closed.set()


def wait_camera_info(node: Any, topic: str, timeout_s: float) -> _evcore.Camera:
    """The intrinsics of the first ``sensor_msgs/CameraInfo`` on ``topic``; ``TimeoutError`` if none
    comes within ``timeout_s``."""
    from sensor_msgs.msg import CameraInfo

    box: queue.Queue[Any] = queue.Queue(maxsize=1)
    sub = node.create_subscription(CameraInfo, topic, lambda m: box.full() or box.put(m), 10)
    try:
        return _camera_from_info(box.get(timeout=timeout_s))
    except queue.Empty:
        raise TimeoutError(
            f"no sensor_msgs/CameraInfo on {topic} within {timeout_s:g} s: give --camera or --config"
        ) from None
    finally:
        node.destroy_subscription(sub)


class EePoseTopic:
    """The newest ``geometry_msgs/PoseStamped`` on a topic as the arm's end-effector pose (4×4, m);
    calling it raises ``ConnectionError`` when the newest is older than ``timeout_s`` (host time of
    arrival) or none came."""

    def __init__(self, node: Any, topic: str, timeout_s: float) -> None:
        from geometry_msgs.msg import PoseStamped

        self.topic, self.timeout_s = topic, timeout_s
        self._latest: tuple[float, np.ndarray] | None = None
        node.create_subscription(PoseStamped, topic, self._on_pose, _best_effort(1))

    def _on_pose(self, msg: Any) -> None:
        from scipy.spatial.transform import Rotation

        p, o = msg.pose.position, msg.pose.orientation
        T = np.eye(4)
        T[:3, :3] = Rotation.from_quat([o.x, o.y, o.z, o.w]).as_matrix()
        T[:3, 3] = p.x, p.y, p.z
        self._latest = (time.monotonic(), T)

    def wait(self, timeout_s: float) -> None:
        """Wait for the first pose; ``ConnectionError`` if none within ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while self._latest is None and time.monotonic() < deadline:
            time.sleep(0.01)
        self()

    def __call__(self) -> np.ndarray:
        latest = self._latest
        if latest is None:
            raise ConnectionError(f"no end-effector pose on {self.topic}")
        age = time.monotonic() - latest[0]
        if age > self.timeout_s:
            raise ConnectionError(f"end-effector pose on {self.topic} is {age:.3f} s old (limit {self.timeout_s:g} s)")
        return latest[1].copy()


def twist_publisher(node: Any, topic: str, frame_id: str) -> tuple[Callable[[np.ndarray, float], None], Any]:
    """``(send, publisher)``: ``send(v_e_e, dt_s)`` publishes a TwistStamped in ``frame_id``."""
    from geometry_msgs.msg import TwistStamped
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    qos = QoSProfile(depth=10, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.VOLATILE)  # fmt: skip
    pub = node.create_publisher(TwistStamped, topic, qos)

    def send(v: np.ndarray, _dt_s: float) -> None:
        msg = TwistStamped()
        msg.header.stamp = node.get_clock().now().to_msg()
        msg.header.frame_id = frame_id
        lin, ang = msg.twist.linear, msg.twist.angular
        lin.x, lin.y, lin.z = (float(x) for x in v[:3])
        ang.x, ang.y, ang.z = (float(x) for x in v[3:])
        pub.publish(msg)

    return send, pub


def run_servo(
    model: str, init_pose: np.ndarray, rig: RigConfig, cfg: RealLoopConfig, *, camera: _evcore.Camera | None = None,
    desired: np.ndarray | None = None, solver: str = "edft+", events_topic: str = "/event_camera/events",
    camera_info_topic: str = "/event_camera/camera_info", twist_topic: str = "/servo_node/delta_twist_cmds",
    ee_frame: str = "tool0", ee_pose_topic: str | None = None, ee_pose_timeout_s: float = 0.2,
    viewer: Any = None, meta: dict[str, Any] | None = None, progress: Callable[[str], None] | None = None,
) -> RealLoopResult:  # fmt: skip
    """Run the loop through ROS (see the module docstring) and return what happened. Intrinsics:
    ``camera``, else the rig's. ``viewer``: a :class:`~evservo.viewer.RerunViewer` (closed here)."""
    from rclpy.duration import Duration

    from evservo.robots.twist_sink import TwistSink
    from evservo.runtime.live_view import viewing
    from evservo.tracking import Tracker

    say = progress or (lambda _msg: None)
    with RosNode("evservo_servo") as ros:
        events = EventTopic(ros.node, events_topic)
        if camera is None:
            say(f"waiting up to {cfg.start_timeout_s:g} s for CameraInfo on {camera_info_topic}")
            camera = wait_camera_info(ros.node, camera_info_topic, cfg.start_timeout_s)
        pose, workspace = None, rig.workspace
        if ee_pose_topic is not None:
            pose = EePoseTopic(ros.node, ee_pose_topic, ee_pose_timeout_s)
            pose.wait(cfg.start_timeout_s)
        elif workspace is not None:
            say(
                "note: the rig's workspace box is not enforced: "
                "without --ee-pose-topic the arm's pose in its base frame is unknown"
            )
            workspace = None
        send, pub = twist_publisher(ros.node, twist_topic, ee_frame)
        if not cfg.dry_run:
            # Twists sent before the arm's controller matched would be lost, and with nobody
            # listening the loop would servo nothing.
            say(f"waiting up to {cfg.start_timeout_s:g} s for a subscriber on {twist_topic}")
            if not subscribed(pub, cfg.start_timeout_s):
                raise ConnectionError(
                    f"no subscriber on {twist_topic} within {cfg.start_timeout_s:g} s: "
                    "is the servo controller running (or give --dry-run)?"
                )
        tracker = Tracker(camera, model, init_pose, solver=solver)
        arm = TwistSink(
            send, pose=pose, link=f"the twist subscribers of {twist_topic}", T_e_c=rig.T_e_c, limits=rig.limits,
            workspace=workspace, dry_run=cfg.dry_run,
        )  # fmt: skip
        try:
            with viewing(viewer, tracker, events) as (source, on_cycle):
                result = run_real_loop(arm, source, tracker, cfg, desired, progress=say, meta=meta, on_cycle=on_cycle)
        finally:
            with StopOnInterrupt() as late:  # a Ctrl-C now must not cut the last twist (or the outputs) short
                events.close()
                arm.close()  # a last zero twist
                if not pub.wait_for_all_acked(Duration(seconds=ACK_TIMEOUT_S)):
                    say(
                        f"warning: the last (zero) twist on {twist_topic} was not acknowledged within "
                        f"{ACK_TIMEOUT_S:g} s"
                    )
    return replace(result, interrupted=True) if late.requested else result
