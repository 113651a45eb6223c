"""Built-in trajectories: displacement from the start pose, with the documented peak rates."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from evservo import trajectories


@pytest.mark.parametrize("kind", trajectories.KINDS)
def test_every_kind_starts_at_the_start_pose_and_peaks_at_the_requested_speed(kind):
    traj = trajectories.make_trajectory(kind, speed_mps=0.3, rot_rate_dps=30.0)
    np.testing.assert_allclose(traj(np.array([0.0]))[0], np.eye(4), atol=1e-12)
    t = np.arange(0.0, 10.0, 1e-3)
    D = traj(t)
    # leave-return dashes across the view along LEAVE_DIR, the others move along x
    along = trajectories.LEAVE_DIR if kind == "leave-return" else np.array([1.0, 0.0, 0.0])
    speed = np.abs(np.diff(D[:, :3, 3] @ along)) / 1e-3
    assert speed.max() == pytest.approx(0.3, rel=1e-3)
    rates = np.rad2deg(np.linalg.norm(Rotation.from_matrix(D[1:, :3, :3] @ D[:-1, :3, :3].transpose(0, 2, 1))
                                      .as_rotvec(), axis=1)) / 1e-3  # fmt: skip
    if kind == "trans-rot":
        assert 30.0 <= rates.max() <= 30.0 * np.sqrt(1 + 0.8**2 + 0.78**2) * 1.05
    elif kind == "leave-return":  # turns 25° on its way back, at 0.3 m/s over √(0.7² LEAVE_M² + 0.05²)
        t_back = 1.5 * np.hypot(0.7 * trajectories.LEAVE_M, 0.05) / min(0.3, trajectories.RETURN_MPS)
        assert rates.max() == pytest.approx(1.5 * 25.0 / t_back, rel=1e-2)
    else:
        assert rates.max() == 0.0
