"""evservo bench --suite robustness: its plan covers the issue's scenarios for the three solvers, and its
episodes are cached by configuration hash like the paper suite's (a rerun reuses them)."""

import json
from dataclasses import replace

from evservo.bench import robustness
from evservo.sim.episode import EpisodeConfig


def test_the_plan_covers_the_issue_scenarios_for_every_solver():
    names = {name for name, _ in robustness.plan()}
    assert names == {"occlusion-0.5s", "occlusion-2s", "leave-return", "events-stop", "wrong-model", "pure-noise",
                     "start-without-pose"}  # fmt: skip
    solvers = {cfg.tracker for _, cfg in robustness.plan()}
    assert solvers == {"edft+", "edopts", "edft"}
    assert all(not cfg.end_on_loss and cfg.event_source == "edges" for _, cfg in robustness.plan())
    keys = [robustness.episode_key(n, c) for n, c in robustness.plan()]
    assert len(set(keys)) == len(keys)


def test_every_disturbance_leaves_time_to_see_a_relock_within_the_bound():
    # A re-lock slower than the time left after a disturbance reads "never": each episode runs 0.6 s past its
    # disturbance, twice the issue's 0.3 s re-lock bound (pure-noise once ran only 0.2 s past it).
    for quick in (False, True):
        for name, cfg in robustness.scenarios(quick).items():
            spells = [
                *cfg.occlusions,
                *([cfg.dropout_s] if cfg.dropout_s else []),
                *([cfg.noise_s] if cfg.noise_s else []),
            ]
            if spells:
                end = max(t1 for _, t1 in spells)
                assert cfg.duration_s >= end + 0.6 - 1e-9, name


def test_a_rerun_reuses_the_finished_episodes(tmp_path, monkeypatch):
    short = EpisodeConfig(duration_s=0.25, cost_model="fixed", end_on_loss=False, occlusions=((0.1, 0.2),))
    monkeypatch.setattr(robustness, "scenarios", lambda quick=False: {"occlusion-0.1s": short})
    first = robustness.run(tmp_path, quick=True)
    assert first["reused"] == 0 and len(first["rows"]) == 1
    loss = first["rows"][0]["summary"]["loss"]
    assert loss["wrong_spells"] >= 1  # the object was hidden: every pose in the spell is wrong
    md = (tmp_path / "robustness.md").read_text()
    assert "| occlusion-0.1s | edft+ |" in md
    again = robustness.run(tmp_path, quick=True)
    assert again["reused"] == 1
    assert json.loads((tmp_path / "robustness.json").read_text())["rows"][0]["summary"]["loss"] == loss
    # Another configuration under the same key is not taken for the cached one.
    monkeypatch.setattr(
        robustness, "scenarios", lambda quick=False: {"occlusion-0.1s": replace(short, occlusions=((0.1, 0.15),))}
    )
    assert robustness.run(tmp_path, quick=True)["reused"] == 0


def test_leave_return_leaves_the_view_wholly_and_comes_back_to_rest_in_it():
    """The suite's leave-return, played by the target arm alone (no tracker) and seen from a camera at rest
    at the start pose: the arm follows the commanded path within 10 mm; the object leaves the view wholly
    (none of 200 model edge points in the image) for over 1 s, never nearer the camera than 0.5 m, is
    half in view again with over twice the issue's 0.3 s re-lock bound of the episode left, and comes to
    rest (< 1 mm/s) whole in view before it ends. Before (1.5 m/s along world x) the arm swung 315 mm off the path,
    the object came to 0.075 m of the lens, never left the view wholly and was still moving at 0.63 m/s
    at the end (benches/RESULTS.md, issue 12, "Round 15")."""
    import numpy as np

    from evservo import _evcore, geometry, trajectories
    from evservo.robots.follow import PoseFollower
    from evservo.sim.episode import ramped_time
    from evservo.sim.scene import DualArmScene
    from evservo.tracking import model_point_set

    cfg = robustness.scenarios()["leave-return"]
    scene = DualArmScene()
    T_c_o0 = scene.reset_to_start(cfg.distance_m, cfg.view_rotvec_rad)
    T_w_o0, T_c_w = scene.T_w_o(), geometry.inv(scene.T_w_c())
    traj = trajectories.make_trajectory(cfg.trajectory, speed_mps=cfg.speed_mps)

    def wanted(t_s: float) -> np.ndarray:
        return trajectories.apply(traj(np.array([ramped_time(t_s, cfg.ramp_s)])), T_w_o0)[0]

    follower = PoseFollower(scene.ur, wanted, T_e_x=scene.config.T_e_o, period_s=cfg.ur_period_s)
    camera = _evcore.Camera.imx636()
    points = model_point_set(camera, cfg.object, T_c_o0, n_points=200, seed=cfg.seed)
    n = round(cfg.duration_s * 1e3)
    off_m, in_view, p_c = np.zeros(n), np.zeros(n), np.zeros((n, 3))
    for k in range(n):
        if k % round(cfg.ur_period_s * 1e3) == 0:
            follower.command(k * 1e-3)
        scene.step(1)
        T_w_o = scene.T_w_o()
        off_m[k] = np.linalg.norm(T_w_o[:3, 3] - wanted((k + 1) * 1e-3)[:3, 3])
        T_c_o = T_c_w @ T_w_o
        p = points @ T_c_o[:3, :3].T + T_c_o[:3, 3]
        uv = camera.project(p)
        inside = (
            (p[:, 2] > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < camera.width) & (uv[:, 1] >= 0) & (uv[:, 1] < camera.height)
        )
        in_view[k], p_c[k] = inside.mean(), T_c_o[:3, 3]
    assert off_m.max() < 0.01, off_m.max()
    assert np.sum(in_view == 0) * 1e-3 > 1.0
    assert p_c[:, 2].min() > 0.5
    speed_mps = np.linalg.norm(np.diff(p_c, axis=0), axis=1) / 1e-3
    back = np.flatnonzero(np.cumsum(in_view == 0) > 0)[0]  # from the moment it is wholly out
    reappeared_s = (back + np.argmax(in_view[back:] >= 0.5)) * 1e-3
    assert reappeared_s < cfg.duration_s - 0.6, reappeared_s
    moving = np.flatnonzero(speed_mps > 1e-3)
    assert moving[-1] < n - 100, moving[-1]
    assert np.all(in_view[moving[-1] :] == 1.0)


def test_leave_return_relocks_within_300_ms_of_the_return_and_trusts_only_right_poses():
    """The suite's leave-return (quick, fixed cost model: a global pass is charged like an LM step, so the
    outcome does not hang on the machine's load): the box is wholly out of the view from about 1.6 s,
    half in view again at about 2.47 s while still moving back, at rest from 3.25 s. The tracker must
    trust a pose within the issue's 300 ms of that reappearance, and every pose it trusts from then on
    must be within 10 mm / 5° of the truth at the pose's own time. Main never re-locked here: the sweep's
    candidates nearest the truth were 15–26° turned and 19–171 mm off, out of LM's reach; the place
    search (the bank at the fresh events' blob, each view at the depth its size matches) puts seeds within
    10–70 mm / 5–15° and a descent on the fresh events takes them into it (benches/RESULTS.md, issue 12,
    "Round 17")."""
    import numpy as np

    from evservo.geometry import pose_errors
    from evservo.runtime.loss import reappearances
    from evservo.sim.episode import run_episode
    from evservo.sim.episode_config import TICK_US

    cfg = replace(robustness.scenarios(quick=True)["leave-return"], cost_model="fixed")
    r = run_episode(cfg)
    gone = np.flatnonzero(~r.seen)
    assert len(gone) and r.t_s[gone].max() - r.t_s[gone].min() > 0.5, "the box must leave the view"
    back_s = [t for t in reappearances(r.t_s, r.seen) if t > r.t_s[gone].min()][-1]
    trusted = ~r.lost & (r.t_s >= back_s)
    assert trusted.any(), "never re-locked after the return"
    relock_s = r.t_s[np.argmax(trusted)] - back_s
    assert relock_s <= 0.3, relock_s
    idx = np.clip(np.round(r.est_t_s / (TICK_US * 1e-6)).astype(int), 0, len(r.t_s) - 1)
    pos_m, rot_rad = pose_errors(r.T_c_o_est[trusted], r.T_c_o_true[idx[trusted]])
    assert pos_m.max() <= 0.010 and np.rad2deg(rot_rad.max()) <= 5.0, (pos_m.max(), np.rad2deg(rot_rad.max()))
