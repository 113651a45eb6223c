import os
from pathlib import Path

import numpy as np
import pytest

import evservo
from evservo import geometry, trajectories
from evservo.synth import edge_events
from evservo.tracking import model_point_set

#: The real Prophesee recordings (shared/event-samples beside the repository, or $EVSERVO_SAMPLES).
SAMPLES = Path(os.environ.get("EVSERVO_SAMPLES", Path(__file__).resolve().parents[2] / "shared/event-samples"))


@pytest.fixture
def unloaded_cpus():
    """For a test whose bound is in wall-clock time (a recording replayed at real time): skip, saying
    so, when other processes keep more than 1.5 runnable threads per core on average over the last
    minute; the bound then measures the machine, not the code. CI's own load stays below that."""
    cores = os.cpu_count() or 1
    load = os.getloadavg()[0]
    if load > 1.5 * cores:
        pytest.skip(f"real-time bound not meaningful: load {load:.1f} on {cores} cores")


@pytest.fixture(scope="session")
def camera():
    return evservo.Camera.imx636()


def box_start_pose(z_m: float = 0.6) -> np.ndarray:
    """The box seen obliquely enough that three faces show."""
    return geometry.pose((0.0, 0.0, z_m), (0.35, -0.45, 0.1))


@pytest.fixture(scope="session")
def box_sequence(camera):
    """The box moving at 0.4 m/s with rotation for 2 s at Z = 0.6 m: 1 ms batches of edge events
    with 20 % noise, and the true T_c_o at the end of each batch."""
    T0 = box_start_pose(0.6)
    dense = model_point_set(camera, "box", T0, n_points=30000, seed=1)
    times = np.arange(0, 2_000_001, 1000, dtype=np.int64)
    traj = trajectories.make_trajectory("trans-rot", speed_mps=0.4, rot_rate_dps=30.0)
    poses = trajectories.apply(traj(times * 1e-6), T0)
    batches = edge_events(camera, dense, poses, times, noise_fraction=0.2, seed=2)
    return T0, batches, poses[1:]
