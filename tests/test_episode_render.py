"""The closed loop with the rendered event camera as its sensor: the camera follows the target while
the world-fixed background streams past, and EDFT+ holds the object throughout."""

import numpy as np
import pytest

from evservo import geometry
from evservo.sim.episode import EpisodeConfig, run_episode, summarize
from evservo.sim.sources import RenderedSource, make_event_source


def episode(source: str):
    return run_episode(
        EpisodeConfig(duration_s=0.3, distance_m=0.9, speed_mps=0.3, cost_model="fixed", event_source=source)
    )


@pytest.fixture(scope="module")
def reference_episode():
    """The closed loop on the reference ``render`` source (a render per tick), run once for this module."""
    return episode("render")


def test_rendered_closed_loop_holds_tracking(reference_episode):
    result = reference_episode
    s = summarize(result)
    assert s["completed"], s
    assert s["gt_track_pos_rms_mm"] < 3.0 and s["gt_track_rot_rms_deg"] < 1.0, s
    # The camera did move in the world, so the rendered background fired as well as the object.
    travel = np.linalg.norm(result.T_w_c[-1][:3, 3] - result.T_w_c[0][:3, 3])
    assert travel > 1e-3, travel


def test_rendered_source_sees_the_background_when_only_the_camera_moves(camera):
    from conftest import box_start_pose

    T_c_o = box_start_pose(0.6)
    src = RenderedSource(camera, "box", T_c_o, 0, seed=0, interpolate=True)
    T_w_c = np.eye(4)
    still = src.events_until(1000, T_c_o, T_w_c)
    # Move the camera 2 mm sideways but keep the object fixed relative to it (perfect servoing).
    moved = T_w_c.copy()
    moved[0, 3] += 0.002
    streaming = src.events_until(2000, T_c_o, moved)
    # Nothing moved in the first millisecond, so the source waited to render it with the second:
    # the batch covers both, and only the second streams.
    assert len(still) == 0 and src.covered_us == 2000
    ev_t = streaming["t"]
    assert np.all(np.diff(ev_t) >= 0) and ev_t.min() >= 0 and ev_t.max() < 2000
    assert (ev_t >= 1000).sum() > 20 * max((ev_t < 1000).sum(), 1)


def clip_counts(camera, interpolate: bool) -> tuple[np.ndarray, int]:
    """Per-pixel event counts of the rendered source (``render``'s imx636 preset) over an 80 ms clip
    in the closed loop's regime: the camera gliding sideways (the background streams), the box
    drifting and turning in it at ~0.1 px per 1 ms tick; and how many renders it took."""
    from conftest import box_start_pose

    T0 = box_start_pose(0.6)
    src = RenderedSource(camera, "box", T0, 0, seed=3, interpolate=interpolate)
    counts = np.zeros(camera.width * camera.height, np.int64)
    renders, covered = 0, 0
    batches = []
    for k in range(1, 81):
        drift = geometry.pose((4e-5 * k, 1e-5 * k, 0.0), (0.0, 0.0, 2e-4 * k))
        batches.append(src.events_until(1000 * k, drift @ T0, geometry.pose((5e-5 * k, 0.0, 0.0))))
        renders += src.covered_us != covered
        covered = src.covered_us
    batches += src.flush()
    ev = np.concatenate(batches)
    assert np.all(np.diff(ev["t"]) >= 0)
    np.add.at(counts, ev["y"].astype(np.int64) * camera.width + ev["x"], 1)
    return counts, renders + (covered < 80_000)


def test_renders_every_few_ticks_give_the_events_of_a_render_per_tick(camera):
    # The same clip rendered every tick (the reference) and only when something may have moved half a
    # pixel, the sensor stepped every tick on interpolated intensities in between. Measured: 27 of 80
    # renders; 106 702 / 106 683 firing pixels; 729 106 / 787 711 events (+8 %). The surplus sits on
    # pixels whose intensity jumps (the canvas has one sample per pixel, so an edge flips whole canvas
    # pixels): rendered every tick the jump falls into one 1 ms step, where the 100 µs refractory period
    # caps a pixel at ~10 events; interpolated it spreads over the ticks between renders.
    ref, ref_renders = clip_counts(camera, interpolate=False)
    fast, renders = clip_counts(camera, interpolate=True)
    assert ref_renders == 80 and renders <= 30, renders
    assert abs(int((fast > 0).sum()) - int((ref > 0).sum())) < 0.01 * (ref > 0).sum()
    assert 1.0 <= fast.sum() / ref.sum() < 1.1, (fast.sum(), ref.sum())
    # Pixel for pixel: 9 % of the events differ (measured), as the seed's noise would not make them.
    assert np.abs(fast - ref).sum() < 0.12 * ref.sum()


def test_rendering_every_few_ticks_keeps_the_closed_loops_tracking_error(reference_episode):
    # The episode of test_rendered_closed_loop_holds_tracking on the reference (a render per tick) and
    # on render-fast, which hands the tracker the ticks between renders late, together.
    ref, fast = summarize(reference_episode), summarize(episode("render-fast"))
    assert ref["completed"] and fast["completed"], (ref, fast)
    assert abs(fast["gt_track_pos_rms_mm"] - ref["gt_track_pos_rms_mm"]) < 0.3, (ref, fast)
    assert abs(fast["gt_track_rot_rms_deg"] - ref["gt_track_rot_rms_deg"]) < 0.15, (ref, fast)


def test_a_jump_first_renders_the_ticks_waiting_at_the_old_pose(camera):
    # The object drifts a tenth of a pixel a tick, so ticks wait for a render; then it jumps away (an
    # occluder hides it). The waiting ticks are rendered at once with the object where it was, and their
    # events lead the next batch: nothing is lost and the stream stays in time order.
    from conftest import box_start_pose

    T0 = box_start_pose(0.6)
    src = RenderedSource(camera, "box", T0, 0, seed=3, interpolate=True)
    drift = [geometry.pose((4e-5 * k, 0.0, 0.0)) @ T0 for k in range(4)]
    waited = [src.events_until(1000 * k, drift[k]) for k in (1, 2, 3)]
    assert src.covered_us == 0 and not any(len(w) for w in waited)
    away = T0.copy()
    away[0, 3] += 50.0
    src.jump(away)
    assert src.covered_us == 3000
    ev = src.events_until(4000, away)
    assert src.covered_us == 4000 and np.all(np.diff(ev["t"]) >= 0)
    # The drift fired over the three waiting ticks; the box vanishing fires in the fourth.
    assert (ev["t"] < 3000).sum() > 100 and (ev["t"] >= 3000).sum() > 1000


def test_render_hands_out_each_tick_at_once_and_render_fast_waits(camera):
    # `render` is the reference the latency figures rest on: each tick's events come out at that tick.
    # `render-fast` holds a tick that moved less than half a pixel for a later render.
    from conftest import box_start_pose

    T0 = box_start_pose(0.6)
    moved = geometry.pose((4e-5, 0.0, 0.0)) @ T0
    ref, fast = (make_event_source(name, camera, "box", T0, 0, seed=3) for name in ("render", "render-fast"))
    assert len(ref.events_until(1000, moved)) > 100 and ref.covered_us == 1000
    assert len(fast.events_until(1000, moved)) == 0 and fast.covered_us == 0
