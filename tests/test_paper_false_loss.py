"""The paper suite's report carries issue 12's false-loss rate: per row, per sweep speed, and pooled
over the suite's episodes (right poses flagged lost over right poses, from each episode's loss block)."""

from dataclasses import replace

from evservo.bench import paper
from evservo.sim.episode import EpisodeConfig


def _summary(rate: float, right: int) -> dict:
    return {
        "completed": True, "lost_at_s": None, "servo_pos_rms_mm": 5.0, "servo_rot_rms_deg": 0.5,
        "gt_servo_pos_rms_mm": 5.0, "gt_servo_rot_rms_deg": 0.5, "gt_track_pos_rms_mm": 1.0,
        "gt_track_rot_rms_deg": 0.1, "lag_s": 0.01, "tracker_rate_hz": 900.0, "joint_speed_max_ratio": 0.5,
        "arm_limited_fraction": 0.0, "loss": {"false_loss_rate": rate, "right_samples": right},
    }  # fmt: skip


def test_the_report_pools_false_loss_over_episodes_and_names_those_above_one_percent(tmp_path):
    base = EpisodeConfig(duration_s=3.0)
    a = replace(base, distance_m=0.9, speed_mps=0.3, tracker="edft+", seed=2)
    b = replace(a, seed=3)
    sweep = replace(base, speed_mps=1.7, feedforward=True)
    episodes = [
        ("table1", paper.episode_key(a), a, _summary(0.0, 3000)),
        ("table1", paper.episode_key(b), b, _summary(0.04, 1000)),  # 40 of 1000 flagged
        ("sweep", paper.episode_key(sweep), sweep, _summary(0.016, 500)),  # 8 of 500
    ]
    text = paper.report(tmp_path, episodes, quick=True, wall_s=1.0)
    # The Table I row pools its two seeds: 40 of 4000 right poses.
    row = next(line for line in text.splitlines() if line.startswith("| box | 0.9 | trans | 0.3 | edft+"))
    assert "| 1.0 % |" in row
    assert "1.7 m/s: held" in text and "false loss 1.6 %" in text
    # Over the suite: 48 of 4500 = 1.07 %; the two episodes above 1 % are named, worst first.
    assert "48 of 4500 (1.07 %) over 3 episodes" in text
    over = text.split("Episodes above 1 %: ")[1]
    assert over.index(paper.episode_key(b)) < over.index(paper.episode_key(sweep))
    assert paper.episode_key(a) not in over


def test_episodes_without_the_count_are_left_out():
    assert paper._false_loss([{"loss": {"false_loss_rate": 0.5}}, {}]) == "—"
    assert paper._false_loss([{"loss": {"false_loss_rate": 0.25, "right_samples": 8}}]) == "25.0 %"
