"""Event sources for the closed-loop simulation: turn the relative pose history into event batches.

A source is asked once per sensor batch for the events of ``[previous call, t_us)``, given the true
object pose in the camera frame ``T_c_o`` (4×4, metres) at ``t_us`` (µs). The episode runs the
source on every batch even while it drops the output (an injected dropout), so a source can keep
whatever per-pixel state it needs.

Sources are registered by name in :data:`EVENT_SOURCES`; a new one (e.g. a rendered ESIM camera) is
a callable with the :class:`SourceFactory` signature added there. The rendered sources
(:data:`RENDERED_SOURCES`) can also draw the robot arms (``make_event_source(..., arms=ArmMeshes(scene))``);
their ``events_until`` then also takes the links' poses in the camera (``occluders``).
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import TYPE_CHECKING, Protocol

import numpy as np

from evservo import _evcore, geometry
from evservo.synth import EdgeEventGenerator
from evservo.tracking import model_point_set

if TYPE_CHECKING:
    from evservo.sim.arms import ArmMeshes


class EventSource(Protocol):
    """Produces EventCD batches from the pose history, one interval at a time."""

    def events_until(self, t_us: int, T_c_o: np.ndarray, T_w_c: np.ndarray | None = None) -> np.ndarray:
        """Time-sorted EventCD events of ``[previous t_us, t_us)``; ``T_c_o`` is the object in the
        camera frame at ``t_us`` (µs, strictly increasing over calls) and ``T_w_c`` the camera in the
        world, for sources that see the world behind the object (``None``: the camera has not moved)."""
        ...


# (camera, object, T_c_o at t0_us, t0_us, seed) -> source starting at t0_us.
SourceFactory = Callable[[_evcore.Camera, str, np.ndarray, int, int], EventSource]

# Background activity of the sensor (events/s over the whole array). 50 kev/s on 1280×720 is
# ~0.05 Hz per pixel, the low end of an IMX636 in a lit room; it keeps time stamps advancing when
# nothing moves, as on the real sensor, so the tracker's pose time tells the controller the truth.
EDGE_NOISE_RATE_HZ = 50_000.0


# The edges source places its edge points by a rendering this many times finer than the sensor.
# S* puts an outline point half a rendered pixel outwards, at the far side's depth (off the surface);
# rendered at the sensor's own resolution, the source's outline would sit up to half a sensor pixel
# off the true one, and the tracker's S* (made the same way) would be graded on its own bias (the
# stop-go dropout episode: 1.76 mm at rest). A third of a pixel's rendering puts it within a sixth
# of a pixel of the true edge (0.2-0.3 mm at rest).
EDGE_RENDER_SCALE = 3


def scaled_camera(camera: _evcore.Camera, scale: float) -> _evcore.Camera:
    """The same lens on a sensor scaled by ``scale`` per side (intrinsics scaled about pixel centres,
    distortion unchanged since it acts on normalised coordinates)."""
    if scale == 1.0:
        return camera
    w, h = round(camera.width * scale), round(camera.height * scale)
    if w < 16 or h < 16:
        raise ValueError(f"scale {scale} leaves a {w}x{h} sensor; too small")
    cx, cy = (camera.cx + 0.5) * scale - 0.5, (camera.cy + 0.5) * scale - 0.5
    return _evcore.Camera(w, h, camera.fx * scale, camera.fy * scale, cx, cy, camera.dist)


def edge_points(camera: _evcore.Camera, obj: str, T_c_o0: np.ndarray, seed: int) -> np.ndarray:
    """The edges source's points (N, 3, object frame, metres): one per point of the sensor-resolution
    edge set of ``obj`` at ``T_c_o0`` (up to 30 000), moved to the nearest point of the set rendered
    :data:`EDGE_RENDER_SCALE` times finer (a fine point nearest to several is kept once).

    The fine set's positions, the sensor-resolution set's spacing: a pixel fires when any point enters
    it, so all of the fine set (about EDGE_RENDER_SCALE points per pixel of edge) would fire each edge
    pixel more often (box at 0.9 m, 3 s: 7.68 M events against 4.02 M, each episode 1.5x slower), and
    a random subsample of it to the same count leaves gaps and clumps along the edges that the
    sensor-resolution set does not have."""
    # Imported here: scipy.spatial takes half a second to import, which every command would pay.
    from scipy.spatial import cKDTree

    coarse = model_point_set(camera, obj, T_c_o0, n_points=30_000, seed=seed)
    fine_camera = scaled_camera(camera.rectified(), EDGE_RENDER_SCALE)
    fine = model_point_set(fine_camera, obj, T_c_o0, n_points=30_000, seed=seed)
    _, nearest = cKDTree(fine).query(coarse)
    return fine[np.unique(nearest)]


def edge_source(camera: _evcore.Camera, obj: str, T_c_o0: np.ndarray, t0_us: int, seed: int) -> EventSource:
    """Events where the model's edge points (:func:`edge_points`) change pixel, plus 20 % proportional
    noise and :data:`EDGE_NOISE_RATE_HZ` of background."""
    return EdgeEventGenerator(
        camera,
        edge_points(camera, obj, T_c_o0, seed),
        T_c_o0,
        t0_us,
        noise_fraction=0.2,
        noise_rate_hz=EDGE_NOISE_RATE_HZ,
        seed=seed,
    )


# Realism presets of the rendered camera: name -> (sensor preset, background cell side in metres).
# ``lab`` is the rendered reference suite's: the ``lab`` sensor preset (IMX636 noise and refractory
# period, hot pixels, 100 Hz mains flicker on every lit surface; its flicker_hz/flicker_depth are
# documented in crates/evcore/src/sim/params.rs) and a cluttered background of 2 cm cells.
REALISM: dict[str, tuple[str, float]] = {"imx636": ("imx636", 0.04), "lab": ("lab", 0.02)}


class RenderedSource:
    """The rendered event camera (:class:`evservo._evcore.SimCamera`: textured object and a textured
    background plane, the lens's distortion, the ESIM-style sensor model with the noise preset of
    ``realism``, see :data:`REALISM`) looking at the scene from the moving camera.

    The background plane is fixed in the world, 0.6 m behind the object's start position, so when the
    camera follows the object the world behind it streams past and fires, as on the real bench.

    By default every call is rendered (the reference: a tick's events reach the caller at that tick),
    split into sub-steps at interpolated poses when something in view moves more than
    :attr:`MAX_STEP_PX` (half a pixel). ``interpolate=True`` (the ``render-fast`` source) follows ESIM's
    adaptive sampling (Rebecq et al. 2018): a new frame is rendered only once something in view could
    move more than half a pixel since the last one, or :attr:`MAX_GAP_US` have passed. The sensor is
    still stepped at every tick in between, on each pixel's intensity interpolated linearly in time
    between the two renders (exact for an edge crossing a pixel's bilinear ramp at constant speed;
    the lighting's flicker is applied per tick), so only the drawing is saved. The events of the ticks
    in between are therefore handed out with the next render, late by up to :attr:`MAX_GAP_US`:
    :attr:`covered_us` says how far the events handed out are complete.

    With ``arms`` (:class:`~evservo.sim.arms.ArmMeshes`) the robot arms are drawn too, z-tested against
    the object and the background: :meth:`events_until` then takes the links' poses in the camera at
    ``t_us`` (``occluders``; omitted, they keep their last poses relative to the camera), interpolates
    them per sub-step like the object, and the half-pixel rule bounds their image motion as well."""

    MAX_STEP_PX = 0.5
    # The longest wait for a render (µs): the age of the oldest event a batch can carry. At the
    # loop's 0.3 m/s the fastest image motion is 0.08 px per 1 ms tick (median; 0.2 at most), so
    # half a pixel takes ~6 ticks; 5 ms keeps the tracker's pose at most a few ms staler.
    MAX_GAP_US = 5000
    BACKGROUND_BEHIND_M = 0.6

    def __init__(
        self,
        camera: _evcore.Camera,
        obj: str,
        T_c_o0: np.ndarray,
        t0_us: int,
        seed: int,
        arms: ArmMeshes | None = None,
        realism: str = "imx636",
        interpolate: bool = False,
    ) -> None:
        from evservo.models import load_object, to_core_mesh
        from evservo.sim.record import background_pose

        if realism not in REALISM:
            raise ValueError(f"unknown realism preset {realism!r}; choose one of {sorted(REALISM)}")
        preset, cell_m = REALISM[realism]
        self.T_c_bg0 = background_pose(float(T_c_o0[2, 3]), self.BACKGROUND_BEHIND_M)
        mesh = to_core_mesh(load_object(obj))
        self.sim = _evcore.SimCamera(camera, mesh, preset=preset, seed=seed, T_c_bg=self.T_c_bg0, cell_m=cell_m)
        self.interpolate = interpolate
        self.T_w_bg: np.ndarray | None = None
        # The last render: its time (µs) and the object, background and link poses in the camera.
        self.t_us, self.T_c_o, self.T_c_bg = int(t0_us), T_c_o0, self.T_c_bg0
        self.occ: np.ndarray | None = None
        # The newest tick not rendered yet, (t_us, T_c_o, T_c_bg, occluders, image motion px since
        # the last render), the times of the ticks before it since the last render (µs), and events
        # rendered early (by `jump`) for the next batch.
        self._pending: tuple[int, np.ndarray, np.ndarray, np.ndarray | None, float] | None = None
        self._ticks: list[int] = []
        self._early: list[np.ndarray] = []
        # After a jump the view changed by more than any motion bound: the next tick is rendered.
        self._jumped = False
        if arms is not None:
            self.sim.set_occluders(arms.core_meshes())
            self.occ = arms.camera_poses()
        self.sim.advance(T_c_o0, self.t_us, T_c_bg=self.T_c_bg0, occluders=self.occ)

    @property
    def covered_us(self) -> int:
        """Every event before this time (µs) has been handed out; later ones wait for a render."""
        return self.t_us

    def jump(self, T_c_o: np.ndarray) -> None:
        """Show the object at ``T_c_o`` from the next batch on without sweeping it there (it vanishes
        behind an occluder or reappears from behind one; see :mod:`evservo.sim.disturb`)."""
        self._early.extend(self.flush())
        self.T_c_o, self._jumped = T_c_o, True

    def flush(self) -> list[np.ndarray]:
        """Render the tick still waiting (if any) and return its events (none handed out before)."""
        if self._pending is None:
            return []
        tick, self._pending = self._pending, None
        return [self._render(*tick)]

    def _background(self, T_w_c: np.ndarray | None) -> np.ndarray:
        if T_w_c is None:
            return self.T_c_bg
        if self.T_w_bg is None:
            self.T_w_bg = T_w_c @ self.T_c_bg
        return geometry.inv(T_w_c) @ self.T_w_bg

    def _moved_px(self, T_c_o: np.ndarray, T_c_bg: np.ndarray, occ: np.ndarray | None) -> float:
        """Largest image motion (px) of anything in view between the last render and these poses."""
        return max(
            self.sim.max_displacement_px(self.T_c_o, T_c_o),
            # The camera's motion against the world, applied to the nearer object, bounds the image
            # motion of the background plane behind it.
            self.sim.max_displacement_px(self.T_c_o, T_c_bg @ geometry.inv(self.T_c_bg) @ self.T_c_o),
            # The arms' visible vertices (behind the camera or off the image they do not count).
            0.0 if occ is None else self.sim.occluder_displacement_px(self.occ, occ),
        )

    def _can_wait(self, t_us: int, moved_px: float) -> bool:
        """Whether a tick at ``t_us``, ``moved_px`` from the last render, may wait for a later one."""
        return (
            self.interpolate
            and not self._jumped
            and moved_px <= self.MAX_STEP_PX
            and t_us - self.t_us < self.MAX_GAP_US
        )

    def events_until(
        self, t_us: int, T_c_o: np.ndarray, T_w_c: np.ndarray | None = None, occluders: np.ndarray | None = None
    ) -> np.ndarray:
        t1 = int(t_us)
        newest = self.t_us if self._pending is None else self._pending[0]
        if t1 <= newest:
            raise ValueError(f"event source time must increase: {t1} µs after {newest} µs")
        if occluders is not None and self.occ is None:
            raise ValueError("occluder poses given to a rendered source built without arms")
        last_occ = self.occ if self._pending is None else self._pending[3]
        occ = last_occ if occluders is None else np.asarray(occluders, float)
        T_c_bg = self._background(T_w_c)
        batches, self._early = self._early, []
        moved_px = self._moved_px(T_c_o, T_c_bg, occ)
        if self._pending is not None and not self._can_wait(t1, moved_px):
            # This tick would stretch the line too far: render the one before, and measure again.
            batches.extend(self.flush())
            moved_px = self._moved_px(T_c_o, T_c_bg, occ)
        if self._can_wait(t1, moved_px):
            if self._pending is not None:
                self._ticks.append(self._pending[0])
            self._pending = (t1, T_c_o, T_c_bg, occ, moved_px)
        else:
            batches.append(self._render(t1, T_c_o, T_c_bg, occ, moved_px))
        # With the dtype given: numpy's concatenate otherwise packs EVENT_CD (drops the padding before
        # t), and the tracker must copy every event back into its layout (≈ 12 ns/event on the producer).
        return np.concatenate(batches, dtype=_evcore.EVENT_CD) if batches else np.zeros(0, _evcore.EVENT_CD)

    def _render(
        self, t1: int, T_c_o: np.ndarray, T_c_bg: np.ndarray, occ: np.ndarray | None, moved_px: float
    ) -> np.ndarray:
        """Render from the last render to the poses at ``t1`` (µs), in sub-steps of at most half a
        pixel, stepping the sensor at the waiting ticks on the way, and return the events of
        ``[last render, t1)``."""
        t0, ticks, self._ticks, self._jumped = self.t_us, self._ticks, [], False
        n = 1 if not np.isfinite(moved_px) else int(min(t1 - t0, max(1, np.ceil(moved_px / self.MAX_STEP_PX))))
        # Ticks wait only for a render within half a pixel: one step, which takes them all.
        assert n == 1 or not ticks, (n, ticks)
        batches = []
        for s in np.linspace(0.0, 1.0, n + 1)[1:]:
            t = t0 + round(s * (t1 - t0))
            batches.append(
                self.sim.advance(
                    _between(self.T_c_o, T_c_o, s),
                    t,
                    T_c_bg=_between(self.T_c_bg, T_c_bg, s),
                    occluders=None if occ is None else _between(self.occ, occ, s),
                    ticks=ticks or None,
                )
            )
        self.t_us, self.T_c_o, self.T_c_bg, self.occ = t1, T_c_o, T_c_bg, occ
        events = np.concatenate(batches, dtype=_evcore.EVENT_CD)  # not packed: see events_until
        # The sensor stamps each step's events in [its start, its end]; as when every tick is
        # rendered and handed out on its own, events stamped at a tick's end are not handed out.
        return events[~np.isin(events["t"], [*ticks, t1])] if ticks else events[events["t"] < t1]


def _between(T_a: np.ndarray, T_b: np.ndarray, s: float) -> np.ndarray:
    """:func:`evservo.geometry.interpolate`, exactly ``T_b`` at the end of the step (``s`` = 1, the only
    sub-step while nothing moves half a pixel per tick): the slerp returns it there only up to rounding,
    through scipy's rotation conversions, the wrapper's largest cost per tick."""
    return T_b if s == 1.0 else geometry.interpolate(T_a, T_b, s)


EVENT_SOURCES: dict[str, SourceFactory] = {
    "edges": edge_source,
    # The reference: a render per tick, each tick's events handed out at that tick.
    "render": RenderedSource,
    # The same camera rendered only every half pixel of image motion, the sensor stepped every tick in
    # between: faster, but a tick's events reach the tracker with the next render, up to 5 ms late.
    "render-fast": partial(RenderedSource, interpolate=True),
    "render-lab": partial(RenderedSource, realism="lab"),
}
# The sources that render the scene (and can draw the arms).
RENDERED_SOURCES = ("render", "render-fast", "render-lab")


def make_event_source(
    name: str,
    camera: _evcore.Camera,
    obj: str,
    T_c_o0: np.ndarray,
    t0_us: int,
    seed: int,
    arms: ArmMeshes | None = None,
) -> EventSource:
    """The source registered as ``name``, starting at ``t0_us`` (µs) with the object at ``T_c_o0``;
    ``arms``: also draw the robot arms (the rendered sources, :data:`RENDERED_SOURCES`, only)."""
    if name not in EVENT_SOURCES:
        raise ValueError(f"unknown event source {name!r}; choose one of {sorted(EVENT_SOURCES)}")
    if arms is not None:
        if name not in RENDERED_SOURCES:
            raise ValueError(f"rendering the arms needs a rendered event source {RENDERED_SOURCES}, not {name!r}")
        return EVENT_SOURCES[name](camera, obj, T_c_o0, t0_us, seed, arms=arms)  # type: ignore[call-arg]
    return EVENT_SOURCES[name](camera, obj, T_c_o0, t0_us, seed)
