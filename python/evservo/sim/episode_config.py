"""What a simulated episode runs (:class:`EpisodeConfig`), apart from the simulator that runs it: the
command line builds its options from these fields without importing MuJoCo or the scene."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evservo import trajectories
from evservo.control.hold import COAST_S
from evservo.sim.disturb import check_spells
from evservo.sim.sources import EVENT_SOURCES, RENDERED_SOURCES
from evservo.tracking import FRONTENDS, SOLVERS

COST_MODELS = ("measured", "fixed")
PREDICTORS = ("velocity", "acceleration")
TICK_US = 1000  # physics step and event batch
#: Longest episode: the per-tick (1 kHz) record is preallocated, ~0.4 kB a tick.
MAX_DURATION_S = 3600.0


@dataclass(frozen=True)
class EpisodeConfig:
    """What to run. Lengths in metres, times in seconds, speeds in m/s.

    ``trajectory``: a kind of :mod:`evservo.trajectories` or a CSV path; the displacement of the object
    in the world frame from its start pose, at peak speed ``speed_mps`` (``rot_rate_dps`` for the
    rotating kinds), entered over ``ramp_s`` with a smooth velocity ramp.
    ``distance_m``: camera–object depth Z at the start. ``view_rotvec_rad``: the object's start
    orientation relative to facing the camera (camera frame); the default shows three faces of the
    box, as on the bench (a face-on plane leaves its out-of-plane rotation nearly unobservable, and
    PBVS turns rotation noise into camera motion through the Z lever arm).
    ``tracker``: solver (``edft+``, ``edopts``, ``edft``).
    ``cost_model``: ``measured`` charges the tracker's compute time to the simulated clock (CPU time
    of the calling thread: the solver is single-threaded, and on a shared machine wall time would
    also charge whatever other processes took); ``fixed`` charges ``lm_cost_s`` per LM step,
    ``search_cost_s`` per search step and ``ingest_event_cost_s`` per ingested event (reproducible).
    Ingest is charged to the producer's timeline, the steps to the solver's (:class:`ClockedTracker`).
    ``dropout_s``: ``(start, end)`` window whose events are lost (sensor or link failure).
    ``lost_pos_m``, ``lost_rot_deg``: tracking counts as lost, and the episode ends, once the estimate
    is this far from the truth at the estimate's time.
    ``feedforward``: our controller (the target's motion fed forward, within what the Panda can deliver
    at its configuration, image motion first, catch-up no faster than ``max_image_rate_rad_s``; the
    camera up to the Panda's own Cartesian limits); off: the paper's literal Eq. (5)–(6) (within
    :class:`~evservo.limits.CartesianLimits`' defaults, half of those). ``predictor``: how feed-forward
    extrapolates the target across the pose's age and the Panda's command latency: ``"velocity"`` (constant velocity) or
    ``"acceleration"`` (constant acceleration).
    Timing (seconds): ``sensing_latency_s`` from an event to the tracker (3.5 ms, the paper's
    measurement); the tracker's compute per ``cost_model``; the controller every ``control_period_s``;
    each arm's command link: the UR5e (RTDE) commanded every ``ur_period_s`` with ``ur_latency_s``
    from write to servo, the Panda (FCI) every ``panda_period_s`` with ``panda_latency_s``.
    ``render_arms``: draw the UR5e and the Panda into the rendered event camera too (their moving
    links occlude the scene and fire events; see :mod:`evservo.sim.arms`); needs a rendered
    ``event_source`` (``"render"``, ``"render-fast"``, ``"render-lab"``).
    Robustness (issue 12; see :mod:`evservo.sim.disturb`): ``occlusions`` full occlusion spells of the
    object; ``noise_s`` a spell of pure noise at ``noise_rate_hz`` (events/s) instead of the scene;
    ``model`` the tracker's model when it is not the object's (a wrong model); ``start_lost`` the
    tracker starts without a pose and searches (the desired pose is captured once locked);
    ``reacquire`` the tracker renders its viewpoint template bank at start-up so that it finds the
    object again by itself after a loss (always on with ``start_lost``);
    ``end_on_loss`` False runs the episode to its end through losses, scoring the tracker's ``lost``
    flag (``summary["loss"]``) instead of ending at the first estimate off the truth.
    The loop's reaction to a loss (:class:`~evservo.control.hold.LossHold`): ``coast_s`` how long
    after the newest trusted pose it follows the object's predicted motion before braking (0: brake at
    once); ``false_losses`` spells (seconds) in which the tracker's ``lost`` flag is forced on whatever
    its pose (a false loss on purpose, to test that reaction; scored like the tracker's own).
    """

    object: str = "box"
    tracker: str = "edft+"
    frontend: str = "scarf"
    trajectory: str = "trans"
    speed_mps: float = 0.3
    rot_rate_dps: float = 30.0
    distance_m: float = 0.9
    view_rotvec_rad: tuple[float, float, float] = (0.35, -0.45, 0.1)
    duration_s: float = 20.0
    seed: int = 1
    feedforward: bool = False
    cost_model: str = "measured"
    lm_cost_s: float = 0.001
    search_cost_s: float = 0.0004
    ingest_event_cost_s: float = 25e-9
    event_source: str = "edges"
    sensing_latency_s: float = 0.0035
    control_period_s: float = 0.002
    ur_period_s: float = 0.002
    ur_latency_s: float = 0.003
    panda_period_s: float = 0.001
    panda_latency_s: float = 0.001
    stiffness: float = 20.0
    ramp_s: float = 0.5
    dropout_s: tuple[float, float] | None = None
    lost_pos_m: float = 0.05
    lost_rot_deg: float = 15.0
    log_rate_hz: float = 100.0
    render_arms: bool = False
    max_image_rate_rad_s: float = 0.5
    predictor: str = "velocity"
    occlusions: tuple[tuple[float, float], ...] = ()
    noise_s: tuple[float, float] | None = None
    noise_rate_hz: float = 1e7
    model: str | None = None
    start_lost: bool = False
    reacquire: bool = False
    end_on_loss: bool = True
    coast_s: float = COAST_S
    false_losses: tuple[tuple[float, float], ...] = ()

    def __post_init__(self) -> None:
        if self.tracker not in SOLVERS:
            raise ValueError(f"unknown tracker {self.tracker!r}; choose one of {SOLVERS}")
        if self.frontend not in FRONTENDS:
            raise ValueError(f"unknown front-end {self.frontend!r}; choose one of {FRONTENDS}")
        if self.cost_model not in COST_MODELS:
            raise ValueError(f"unknown cost model {self.cost_model!r}; choose one of {COST_MODELS}")
        if self.event_source not in EVENT_SOURCES:
            raise ValueError(f"unknown event source {self.event_source!r}; choose one of {sorted(EVENT_SOURCES)}")
        if not (self.duration_s > 0 and self.distance_m > 0 and self.speed_mps >= 0 and self.ramp_s >= 0):
            raise ValueError("duration and distance must be > 0, speed and ramp >= 0")
        numbers = dict(duration_s=self.duration_s, distance_m=self.distance_m, speed_mps=self.speed_mps,
                       rot_rate_dps=self.rot_rate_dps, ramp_s=self.ramp_s, stiffness=self.stiffness)  # fmt: skip
        for name, v in numbers.items():
            if not np.isfinite(v):
                raise ValueError(f"{name} must be finite, got {v}")
        if self.seed < 0:
            raise ValueError(f"seed must be >= 0, got {self.seed}")
        # The trajectory (a kind or a CSV file) is checked here, before any simulation is set up.
        trajectories.make_trajectory(self.trajectory, speed_mps=self.speed_mps, rot_rate_dps=self.rot_rate_dps)
        if self.duration_s > MAX_DURATION_S:
            raise ValueError(f"duration must be at most {MAX_DURATION_S:g} s (per-tick record), got {self.duration_s}")
        if not (self.lm_cost_s > 0 and self.search_cost_s > 0 and self.sensing_latency_s >= 0):
            raise ValueError("step costs must be > 0 and the latency >= 0")
        if not self.ingest_event_cost_s >= 0:
            raise ValueError(f"ingest_event_cost_s must be >= 0, got {self.ingest_event_cost_s}")
        for name in ("control_period_s", "ur_period_s", "panda_period_s"):
            if round(getattr(self, name) * 1e6) % TICK_US or getattr(self, name) <= 0:
                raise ValueError(f"{name} must be a positive multiple of 1 ms")
        if not (self.ur_latency_s >= 0 and self.panda_latency_s >= 0 and self.max_image_rate_rad_s > 0):
            raise ValueError("command latencies must be >= 0 and max_image_rate_rad_s > 0")
        if self.predictor not in PREDICTORS:
            raise ValueError(f"unknown predictor {self.predictor!r}; choose one of {PREDICTORS}")
        if self.render_arms and self.event_source not in RENDERED_SOURCES:
            raise ValueError(
                f"render_arms draws the arms in the rendered event camera: it needs a rendered event source "
                f"{RENDERED_SOURCES} (--events render), not {self.event_source!r}"
            )
        if self.dropout_s is not None and not self.dropout_s[0] < self.dropout_s[1]:
            raise ValueError("dropout_s must be (start, end) with start < end")
        check_spells(self.occlusions, "occlusions")
        check_spells(self.false_losses, "false_losses")
        if not (np.isfinite(self.coast_s) and self.coast_s >= 0):
            raise ValueError(f"coast_s must be finite and >= 0, got {self.coast_s}")
        check_spells(() if self.noise_s is None else (self.noise_s,), "noise_s")
        if not (np.isfinite(self.noise_rate_hz) and self.noise_rate_hz >= 0):
            raise ValueError(f"noise_rate_hz must be finite and >= 0, got {self.noise_rate_hz}")
