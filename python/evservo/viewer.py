"""A live view of a tracking or servoing run in rerun (``--viewer rerun``, ``--viewer-save run.rrd``).

rerun-sdk is an optional extra (``pip install 'evservo[viewer]'``, about 700 MB), imported only when a
viewer is asked for. The loops call one object, :class:`RerunViewer`, once per update
(:meth:`RerunViewer.track` from ``evservo track``, :meth:`RerunViewer.servo` from
``evservo servo --sim``); it logs at most once per ``period_us`` of sensor time (30 Hz by default)
and sums the events in between, so a 1 kHz loop is not slowed by logging. The real loops
(``servo --robot``, ``ros servo``) call :meth:`RerunViewer.servo` from a thread of their own
(:class:`~evservo.runtime.live_view.LiveView`), never from the control loop; with the threaded
tracker there the distance field is not shown (it lives inside the tracker's thread).

What is logged, on the timeline ``sensor_time`` (the run's event time):

* ``camera/events``: the events since the last log as an image (ON white, OFF black on grey, PNG);
  ``camera/sstar``: S* projected at the estimate (rectified pixels), drawn over it;
* ``field/distance``: the tracker's distance field over its region, ``field/sstar``: S* on it;
* ``world/camera`` (pinhole with the intrinsics) and ``world/object`` (the estimate), plus
  ``world/object_true`` when the truth is known; for servoing the world frame is the bench's
  and ``world/object_desired`` is where the object should be;
* plots ``errors/track_pos_mm`` / ``errors/track_rot_deg`` (estimate vs truth),
  ``errors/servo_pos_mm`` / ``errors/servo_rot_deg`` (estimate vs desired), ``tracking/lost``,
  ``tracking/events``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from evservo import _evcore
from evservo.geometry import pose_errors

__all__ = ["VIEWERS", "RerunViewer", "open_viewer"]

#: Values of ``--viewer``.
VIEWERS = ("rerun",)
#: Sensor time between two logged frames (µs): 30 Hz.
DEFAULT_PERIOD_US = 33_333
#: Port of rerun's web viewer on this machine.
WEB_PORT = 9090
_INSTALL_HINT = "the rerun viewer needs rerun-sdk: pip install 'evservo[viewer]' (or make viewer)"


def open_viewer(kind: str | None, save: str | Path | None, *, spawn: bool = True) -> RerunViewer | None:
    """The viewer the ``--viewer`` / ``--viewer-save`` options ask for, or None. ``--viewer-save``
    alone records to the file without showing anything; with ``--viewer rerun`` the recording is
    also served to a local web viewer (``spawn=False`` only records)."""
    if kind is None and save is None:
        return None
    if kind is not None and kind not in VIEWERS:
        raise ValueError(f"unknown viewer {kind!r}; choose one of {VIEWERS}")
    if save is not None and Path(save).suffix != ".rrd":
        raise ValueError(f"--viewer-save needs a .rrd file name, got {save}")
    return RerunViewer(save=save, serve=kind is not None and spawn)


class RerunViewer:
    """Logs a run to rerun. ``save``: an ``.rrd`` file to write; ``serve``: also serve the
    recording to rerun's web viewer on this machine (prints its address)."""

    def __init__(
        self, *, save: str | Path | None = None, serve: bool = False, period_us: int = DEFAULT_PERIOD_US,
    ) -> None:  # fmt: skip
        try:
            import rerun as rr
        except ImportError as e:
            raise ValueError(_INSTALL_HINT) from e
        if save is None and not serve:
            raise ValueError("a viewer needs somewhere to send the recording: save= or serve=True")
        self._rr = rr
        self._camera: _evcore.Camera | None = None
        self._period_us = period_us
        self._rec = rr.RecordingStream("evservo")
        if save is not None:
            self._rec.save(str(save))
        if serve:
            url = self._rec.serve_grpc()
            rr.serve_web_viewer(web_port=WEB_PORT, connect_to=url, open_browser=False)
            # Served from this process: the page shows the run while it lasts (--viewer-save keeps it).
            print(f"viewer: open http://127.0.0.1:{WEB_PORT} (rerun web viewer, recording at {url})")
        self._next_us: int | None = None
        self._pending: list[np.ndarray] = []
        self._logged = 0

    @property
    def frames_logged(self) -> int:
        """Frames logged so far (one per ``period_us`` of sensor time with updates)."""
        return self._logged

    def _static_world(self, camera: _evcore.Camera) -> None:
        """The world's axes and the camera's pinhole, logged once with the first frame."""
        rr = self._rr
        self._camera = camera
        self._rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        self._rec.log(
            "world/camera",
            rr.Pinhole(image_from_camera=np.asarray(camera.k), resolution=[camera.width, camera.height],
                       camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=0.1),
            static=True,
        )  # fmt: skip

    def _due(self, t_us: int, events: np.ndarray) -> bool:
        """Collect the events; True when a frame is to be logged at ``t_us``."""
        self._pending.append(events)
        if self._next_us is not None and t_us < self._next_us:
            return False
        self._next_us = (t_us // self._period_us + 1) * self._period_us
        self._rec.set_time("sensor_time", duration=t_us * 1e-6)
        return True

    def track(
        self, t_us: int, events: np.ndarray, est: Any, tracker: Any, T_c_o_true: np.ndarray | None = None
    ) -> None:
        """One tracker update at ``t_us`` (µs) on ``events``; ``est`` the estimate (``T_c_o``,
        ``lost``), ``tracker`` the :class:`~evservo.tracking.Tracker` (its field and S*), and the
        true ``T_c_o`` when known. The camera frame is the world frame."""
        if not self._due(t_us, events):
            return
        self._log_camera_views(tracker, est)
        self._pose("world/camera", np.eye(4))
        self._pose("world/object", est.T_c_o)
        if T_c_o_true is not None:
            self._pose("world/object_true", T_c_o_true)
            self._errors("track", est.T_c_o, T_c_o_true)

    def servo(
        self, t_us: int, events: np.ndarray, est: Any, tracker: Any, *, T_w_c: np.ndarray,
        T_c_o_des: np.ndarray, T_w_o_true: np.ndarray | None = None, threaded: bool = False,
    ) -> None:  # fmt: skip
        """One control tick of a servo run: as :meth:`track`, in the bench's world frame (camera
        at ``T_w_c``), with the servo error of the estimate against ``T_c_o_des``. ``threaded``:
        the tracker runs its own thread (the real loop), whose S* and field this cannot read: S*
        is projected at ``est`` instead and the field is not shown."""
        if not self._due(t_us, events):
            return
        self._log_camera_views(tracker, est, threaded)
        self._pose("world/camera", T_w_c)
        self._pose("world/object", T_w_c @ est.T_c_o)
        self._pose("world/object_desired", T_w_c @ T_c_o_des)
        self._errors("servo", est.T_c_o, T_c_o_des)
        if T_w_o_true is not None:
            self._pose("world/object_true", T_w_o_true)
            self._errors("track", est.T_c_o, np.linalg.inv(T_w_c) @ T_w_o_true)

    def close(self) -> None:
        """Flush and close the recording (the ``.rrd`` is complete after this)."""
        self._rec.flush()
        self._rec.disconnect()

    def _log_camera_views(self, tracker: Any, est: Any, threaded: bool = False) -> None:
        rr, rec = self._rr, self._rec
        events = np.concatenate(self._pending) if self._pending else np.empty(0)
        self._pending = []
        if self._camera is None:
            self._static_world(tracker.camera)
        cam = tracker.camera
        rec.log(
            "camera/events", rr.EncodedImage(contents=_event_png(events, cam.width, cam.height), media_type="image/png")
        )
        if threaded:
            pts = _project_in_view(cam, tracker.points_o, est.T_c_o)
            field, (x0, y0) = np.zeros((0, 0), np.float32), (0, 0)
        else:
            pts = np.asarray(tracker.projected_points())
            field, (x0, y0) = tracker.field()
        rec.log("camera/sstar", rr.Points2D(pts, colors=[255, 40, 40], radii=0.8))
        field = np.asarray(field, dtype=np.float32)
        if field.size:
            rec.log("field/distance", rr.Image(field))
            rec.log("field/sstar", rr.Points2D(pts - [x0, y0], colors=[255, 40, 40], radii=0.8))
        rec.log("tracking/lost", rr.Scalars(float(est.lost)))
        rec.log("tracking/events", rr.Scalars(float(len(events))))
        self._logged += 1

    def _pose(self, path: str, T: np.ndarray) -> None:
        self._rec.log(path, self._rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]))

    def _errors(self, kind: str, T_a: np.ndarray, T_b: np.ndarray) -> None:
        pos_m, rot_rad = pose_errors(T_a[None], T_b[None])
        self._rec.log(f"errors/{kind}_pos_mm", self._rr.Scalars(float(pos_m[0]) * 1e3))
        self._rec.log(f"errors/{kind}_rot_deg", self._rr.Scalars(float(np.rad2deg(rot_rad[0]))))


def _project_in_view(camera: _evcore.Camera, points_o: np.ndarray, T_c_o: np.ndarray) -> np.ndarray:
    """Model points (object frame, m) at ``T_c_o`` in rectified pixels, those in front of the camera
    and inside the image only, (N, 2)."""
    T = np.asarray(T_c_o, dtype=float)
    pts_c = np.asarray(points_o, dtype=float) @ T[:3, :3].T + T[:3, 3]
    pts_c = pts_c[pts_c[:, 2] > 1e-6]
    px = np.asarray(camera.project(pts_c, distort=False)).reshape(-1, 2)
    inside = (px[:, 0] >= 0) & (px[:, 0] < camera.width) & (px[:, 1] >= 0) & (px[:, 1] < camera.height)
    return px[inside]


def _event_png(events: np.ndarray, width: int, height: int) -> bytes:
    """Events as a grey image, ON white and OFF black (the last event of a pixel wins), PNG-encoded:
    event images are mostly flat, so PNG keeps them small and exact."""
    import cv2

    img = np.full((height, width), 128, np.uint8)
    if len(events):
        img[events["y"], events["x"]] = np.where(events["p"] > 0, 255, 0).astype(np.uint8)
    ok, png = cv2.imencode(".png", img)
    if not ok:
        raise RuntimeError("PNG encoding of the event image failed")
    return png.tobytes()
