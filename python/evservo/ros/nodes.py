"""The ROS 2 nodes behind ``evservo ros play`` and ``evservo ros track`` (rclpy, after ``make ros``).

``play``: any file :mod:`evservo.io` reads, published as ``event_camera_msgs/EventPacket``
(``evt3``, one packet per ``packet_us`` of events, encoded by the Rust EVT 3.0 encoder as one stream)
in real time × ``rate``.

``track``: subscribes to EventPacket (``evt3`` or ``mono``), decodes the packets as one stream,
slices it on the same 1 ms event-time grid as ``evservo track`` and runs the same tracker on each
slice, so its poses equal ``evservo track``'s on the same events whatever the packet boundaries
and delivery timing. As there, an empty slice inside the stream advances the tracker's stream time
(``Tracker.advance_time``), so a gap in the events reads ``lost`` 20 ms in on the event clock; the
node learns of the gap only from the first packet after it (an empty packet or its header stamp
carry no sensor time it could trust, so they advance nothing). Per update it publishes
``geometry_msgs/PoseStamped`` (``T_c_o``, frame ``camera_frame``), the same transform on ``/tf``
(``tf2_msgs/TFMessage``, child ``object_frame``) and a ``std_msgs/String`` status (JSON: ``t_us``
event time of the slice end, ``lost``, ``confidence``, ``cost``, ``inlier_fraction``,
``n_events``). Intrinsics from ``--camera FILE`` or else the first
``sensor_msgs/CameraInfo`` on the camera-info topic.
"""

from __future__ import annotations

import json
import queue
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from evservo import _evcore

#: Deep queues: a tracker must see every packet (a lost evt3 packet corrupts the stream).
QUEUE_DEPTH = 10_000


def _ros() -> Any:
    try:
        import rclpy
    except ImportError as e:
        raise ValueError("ROS 2 support is not installed in this environment: run `make ros`") from e
    return rclpy


def _qos() -> Any:
    """Reliable and transient-local: a subscriber that matched late still gets what was sent."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(
        depth=QUEUE_DEPTH, history=HistoryPolicy.KEEP_LAST, reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL,
    )  # fmt: skip


def _stamp(msg_stamp: Any, t_us: int) -> None:
    msg_stamp.sec, msg_stamp.nanosec = t_us // 1_000_000, t_us % 1_000_000 * 1000


def play(path: str | Path, topic: str, rate: float = 1.0, packet_us: int = 1000, wait_s: float = 10.0) -> int:
    """Publish the events of ``path`` on ``topic`` in real time × ``rate``; waits up to ``wait_s``
    for a subscriber first (packets sent before one matched would be lost). Returns the number of
    packets sent."""
    rclpy = _ros()
    from event_camera_msgs.msg import EventPacket

    from evservo import io

    if not rate > 0:
        raise ValueError(f"--rate must be > 0, got {rate}")
    meta = io.info(path)
    encoder = _evcore.Evt3Encoder(meta["width"], meta["height"])
    rclpy.init()
    node = rclpy.create_node("evservo_play")
    try:
        pub = node.create_publisher(EventPacket, topic, _qos())
        subscribed(pub, wait_s)  # none in time: play to nobody, as a driver does
        wall0, t0, seq = None, None, 0
        for ev in io.open_events(path, delta_t_us=packet_us):
            if len(ev) == 0:
                continue
            t_first = int(ev["t"][0])
            if wall0 is None:
                wall0, t0 = time.monotonic(), t_first
            delay = wall0 + (t_first - t0) * 1e-6 / rate - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            msg = EventPacket()
            _stamp(msg.header.stamp, t_first)
            msg.header.frame_id = "event_camera"
            msg.width, msg.height, msg.seq, msg.time_base = meta["width"], meta["height"], seq, 0
            msg.encoding, msg.is_bigendian = "evt3", False
            msg.events = encoder.encode(np.ascontiguousarray(ev))
            pub.publish(msg)
            seq += 1
        # Reliable delivery drains before the publisher (and its transient-local history) goes away; a
        # subscriber still matching (a slow start) gets the history meanwhile.
        if not pub.wait_for_all_acked(rclpy.duration.Duration(seconds=max(10.0, wait_s))):
            raise RuntimeError(f"{topic}: the subscribers did not acknowledge all {seq} packets within {wait_s:g} s")
        return seq
    finally:
        node.destroy_node()
        rclpy.try_shutdown()  # a Ctrl-C has shut the context down already (rclpy's own SIGINT handler)


def subscribed(pub: Any, timeout_s: float) -> bool:
    """Whether ``pub`` has matched a subscriber within ``timeout_s`` (waits for it). Messages
    published before discovery matched the two never reach that subscriber (volatile topics)."""
    deadline = time.monotonic() + timeout_s
    while pub.get_subscription_count() == 0:
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.01)
    return True


def _camera_from_info(msg: Any) -> _evcore.Camera:
    d = list(msg.d)[:5] + [0.0] * max(0, 5 - len(msg.d))
    k = list(msg.k)
    return _evcore.Camera(int(msg.width), int(msg.height), k[0], k[4], k[2], k[5], tuple(d))


def track(
    model: str, init_pose: np.ndarray, *, camera: _evcore.Camera | None = None,
    events_topic: str = "/event_camera/events", camera_info_topic: str = "/event_camera/camera_info",
    pose_topic: str = "/evservo/pose", status_topic: str = "/evservo/status", camera_frame: str = "camera",
    object_frame: str = "object", solver: str = "edft+", batch_us: int = 1000, idle_exit_s: float | None = None,
    viewer: Any = None,
) -> int:  # fmt: skip
    """Run the tracking node until Ctrl-C, or until ``idle_exit_s`` without packets once some came and
    the intrinsics are known (packets that came before them wait in the queue).
    ``viewer``: a :class:`~evservo.viewer.RerunViewer` shown every update (the caller closes it).
    Returns the number of poses published; raises ``ValueError`` when it ends with packets but never
    got a CameraInfo to track them with."""
    rclpy = _ros()
    from event_camera_msgs.msg import EventPacket
    from geometry_msgs.msg import PoseStamped, TransformStamped
    from scipy.spatial.transform import Rotation
    from sensor_msgs.msg import CameraInfo
    from std_msgs.msg import String
    from tf2_msgs.msg import TFMessage

    from evservo import bags, events, io
    from evservo.tracking import Tracker

    packets: queue.Queue[Any] = queue.Queue()
    cam_box: list[_evcore.Camera | None] = [camera]
    last_packet = [time.monotonic(), False]
    ending = threading.Event()  # set when the node stops: a worker waiting for intrinsics gives up
    rclpy.init()
    node = rclpy.create_node("evservo_track")
    try:
        pose_pub = node.create_publisher(PoseStamped, pose_topic, _qos())
        tf_pub = node.create_publisher(TFMessage, "/tf", _qos())
        status_pub = node.create_publisher(String, status_topic, _qos())

        def on_packet(msg: Any) -> None:
            last_packet[0], last_packet[1] = time.monotonic(), True
            packets.put(msg)

        def on_info(msg: Any) -> None:
            if cam_box[0] is None:
                cam_box[0] = _camera_from_info(msg)

        node.create_subscription(EventPacket, events_topic, on_packet, _qos())
        if camera is None:
            node.create_subscription(CameraInfo, camera_info_topic, on_info, 10)
        intrinsics = f" and {camera_info_topic}" if camera is None else ""
        print(f"ros track: listening on {events_topic}{intrinsics}", flush=True)
        published = [0]
        failure: list[BaseException] = []

        def blocks() -> Iterator[np.ndarray]:
            decode = None
            while (msg := packets.get()) is not None:
                if decode is None:
                    decode = bags.message_decoder(bags.EVENT_PACKET, msg.encoding, msg.width, msg.height, events_topic)
                yield decode(msg)

        def work() -> None:
            try:
                trk, t_max = None, None
                end = None
                for ev in io._block_time_slices(blocks(), batch_us):
                    while cam_box[0] is None:  # events before the intrinsics wait for them
                        if ending.wait(0.01):
                            raise ValueError(
                                f"event packets came on {events_topic} but no sensor_msgs/CameraInfo on "
                                f"{camera_info_topic}: give the intrinsics with --camera FILE"
                            )
                    if trk is None:
                        trk = Tracker(cam_box[0], model, init_pose, solver=solver)
                        end = (int(ev["t"][0]) // batch_us + 1) * batch_us
                    ev, _, t_max = events.clamp_time(ev, t_max)
                    # An empty slice: a later packet's events show that none came before its end.
                    est = trk.update_slice(ev, end, t_max)
                    _publish(est, end)
                    if viewer is not None:
                        viewer.track(end, ev, est, trk)
                    end += batch_us
            except BaseException as e:  # reported by the main thread
                failure.append(e)

        def _publish(est: Any, end_us: int) -> None:
            T = np.asarray(est.T_c_o)
            q = Rotation.from_matrix(T[:3, :3]).as_quat()
            now = node.get_clock().now().to_msg()
            pose = PoseStamped()
            pose.header.stamp, pose.header.frame_id = now, camera_frame
            p, o = pose.pose.position, pose.pose.orientation
            p.x, p.y, p.z = (float(v) for v in T[:3, 3])
            o.x, o.y, o.z, o.w = (float(v) for v in q)
            pose_pub.publish(pose)
            tf = TransformStamped()
            tf.header.stamp, tf.header.frame_id, tf.child_frame_id = now, camera_frame, object_frame
            tr, rot = tf.transform.translation, tf.transform.rotation
            tr.x, tr.y, tr.z = p.x, p.y, p.z
            rot.x, rot.y, rot.z, rot.w = o.x, o.y, o.z, o.w
            tf_pub.publish(TFMessage(transforms=[tf]))
            status = dict(t_us=end_us, lost=bool(est.lost), confidence=float(est.confidence), cost=float(est.cost),
                          inlier_fraction=float(est.inlier_fraction), n_events=int(est.n_events))  # fmt: skip
            status_pub.publish(String(data=json.dumps(status)))
            published[0] += 1

        worker = threading.Thread(target=work, name="evservo-track", daemon=True)
        worker.start()
        warned = False
        try:
            while rclpy.ok() and worker.is_alive():
                rclpy.spin_once(node, timeout_sec=0.05)
                quiet_s = time.monotonic() - last_packet[0] if last_packet[1] else 0.0
                if cam_box[0] is None and quiet_s > 2.0 and not warned:
                    warned = True
                    print(f"ros track: {packets.qsize()} event packets wait for a sensor_msgs/CameraInfo on "
                          f"{camera_info_topic} (or give --camera FILE)", file=sys.stderr, flush=True)  # fmt: skip
                if idle_exit_s is not None and quiet_s > idle_exit_s and cam_box[0] is not None:
                    break
        except KeyboardInterrupt:
            pass
        ending.set()
        packets.put(None)  # flush the last partial slice
        worker.join()
        if failure:
            raise failure[0]
        # Let reliable delivery of the last poses finish.
        for pub in (pose_pub, tf_pub, status_pub):
            pub.wait_for_all_acked(rclpy.duration.Duration(seconds=2.0))
        return published[0]
    finally:
        node.destroy_node()
        rclpy.try_shutdown()  # a Ctrl-C has shut the context down already (rclpy's own SIGINT handler)
