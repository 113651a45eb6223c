"""Simulated arms, resolved-rate IK and the dual-robot scene."""

import numpy as np
import pytest

from evservo import geometry, trajectories
from evservo.control import Pbvs
from evservo.robots import PANDA, UR5E, Arm, PoseFollower, shift_twist, solve_joint_velocities
from evservo.robots.ik import joint_velocity_bounds
from evservo.sim.scene import DualArmScene, SceneConfig

# Franka's published kinematics (Craig's modified DH: a, d, alpha per joint, then the flange).
FRANKA_DH = [
    (0.0, 0.333, 0.0),
    (0.0, 0.0, -np.pi / 2),
    (0.0, 0.316, np.pi / 2),
    (0.0825, 0.0, np.pi / 2),
    (-0.0825, 0.384, -np.pi / 2),
    (0.0, 0.0, np.pi / 2),
    (0.088, 0.0, np.pi / 2),
]


def franka_dh_flange(q: np.ndarray) -> np.ndarray:
    def link(a, d, alpha, theta):
        ca, sa, ct, st = np.cos(alpha), np.sin(alpha), np.cos(theta), np.sin(theta)
        return np.array(
            [[ct, -st, 0, a], [st * ca, ct * ca, -sa, -d * sa], [st * sa, ct * sa, ca, d * ca], [0, 0, 0, 1]]
        )

    T = np.eye(4)
    for (a, d, alpha), qi in zip(FRANKA_DH, q, strict=True):
        T = T @ link(a, d, alpha, qi)
    return T @ link(0.0, 0.107, 0.0, 0.0)


@pytest.fixture(scope="module")
def scene():
    return DualArmScene()


def test_both_arms_load(scene):
    assert scene.model.nq == 13  # 6 UR5e joints + 7 Panda joints, nothing else
    assert isinstance(scene.ur, Arm) and isinstance(scene.panda, Arm)
    assert scene.ur.joint_positions().shape == (6,) and scene.panda.joint_positions().shape == (7,)
    # At q = 0 the Panda stands upright, its flange 0.088 m forward (towards the UR5e) of its base.
    np.testing.assert_allclose(scene.panda.fk(np.zeros(7))[:3, 3], [1.2 - 0.088, 0.0, 0.9265], atol=1e-3)


def test_scenes_of_one_layout_share_the_compilation_but_not_their_state(scene):
    other = DualArmScene()
    assert other.model is not scene.model and other.data is not scene.data
    np.testing.assert_array_equal(other.model.body_pos, scene.model.body_pos)
    other.model.body_pos[1] += 0.5  # a change to one scene's model ...
    assert not np.array_equal(other.model.body_pos[1], scene.model.body_pos[1])  # ... is its own
    # Another camera mount is another layout: its own compilation, the camera site where it says.
    moved = DualArmScene(SceneConfig(T_e_c=geometry.pose((0.0, 0.0, 0.15))))
    q = (PANDA.q_min + PANDA.q_max) / 2
    moved.panda.set_joint_positions(q)
    other.panda.set_joint_positions(q)
    lift = np.linalg.norm(moved.T_w_c()[:3, 3] - other.T_w_c()[:3, 3])
    assert lift == pytest.approx(0.10, abs=1e-9)


def test_panda_fk_matches_site_and_franka_kinematics(scene):
    rng = np.random.default_rng(3)
    T_w_base = geometry.pose((1.2, 0.0, 0.0), (0.0, 0.0, np.pi))
    # robosuite's hand frame is the flange turned −45° about its axis and 0.5 mm shorter (0.1065 m).
    T_flange_hand = geometry.pose((0.0, 0.0, -0.0005), (0.0, 0.0, -np.pi / 4))
    q_saved = scene.panda.joint_positions()
    for _ in range(5):
        q = rng.uniform(PANDA.q_min, PANDA.q_max)
        T_fk = scene.panda.fk(q)
        scene.panda.set_joint_positions(q)
        np.testing.assert_allclose(scene.T_w_c(), T_fk @ scene.panda.T_e_c, atol=1e-12)
        T_ref = T_w_base @ franka_dh_flange(q) @ T_flange_hand
        assert geometry.translation_error_m(T_fk, T_ref) < 1e-4
        assert geometry.rotation_error_rad(T_fk, T_ref) < 1e-3  # the MJCF quaternion has 3 digits
    scene.panda.set_joint_positions(q_saved)


@pytest.mark.parametrize("Z", [0.6, 0.9])
def test_start_configuration_puts_target_on_axis_at_depth(scene, Z):
    T_c_o = scene.reset_to_start(Z)
    assert T_c_o[2, 3] == pytest.approx(Z, abs=0.01)
    assert np.hypot(T_c_o[0, 3], T_c_o[1, 3]) < 0.02
    # Face-on: the box's z axis (through its thickness) is along the optical axis.
    assert T_c_o[2, 2] > np.cos(np.deg2rad(2.0))
    for arm, L in ((scene.ur, UR5E), (scene.panda, PANDA)):
        q = arm.joint_positions()
        assert np.all(q > L.q_min + 0.3) and np.all(q < L.q_max - 0.3)  # well inside the ranges


def test_ur_carries_target_along_04_mps_trajectory_within_5mm(scene):
    scene.reset_to_start(0.9)
    T_w_o0 = scene.T_w_o()
    traj = trajectories.make_trajectory("trans", speed_mps=0.4)

    def T_w_o_ref(t_s: float) -> np.ndarray:
        return trajectories.apply(traj(np.array([t_s])), T_w_o0)[0]

    follower = PoseFollower(scene.ur, T_w_o_ref, T_e_x=scene.config.T_e_o, period_s=0.002)
    t0 = scene.t_s
    errs, pos = [], []
    rot = 0.0
    for _ in range(1500):  # 3 s: IK at 500 Hz, physics at 1 kHz
        follower.command(scene.t_s - t0)
        scene.step(2)
        T_ref = T_w_o_ref(scene.t_s - t0)
        errs.append(geometry.translation_error_m(scene.T_w_o(), T_ref))
        rot = max(rot, geometry.rotation_error_rad(scene.T_w_o(), T_ref))
        pos.append(scene.T_w_o()[:3, 3])
    errs = np.array(errs)
    pos = np.array(pos)
    speed = np.linalg.norm(pos[5:] - pos[:-5], axis=1) / 0.010  # over 10 ms
    # The trajectory starts at full speed from rest, which takes the joints' acceleration limits ~0.3 s
    # to absorb (peak lag 16 mm); from then on the target moves at up to 0.4 m/s well within 5 mm.
    settled = round(0.5 / 0.002)
    assert speed[settled:].max() == pytest.approx(0.404, rel=0.03)
    assert errs[settled:].max() < 0.001
    assert errs.max() < 0.02
    assert rot < np.deg2rad(0.5)


def test_panda_resolves_camera_twist_within_joint_limits(scene):
    h, period = scene.config.physics_dt_s, 0.002
    arm = scene.panda
    slow = np.array([0.2, -0.1, 0.05, 0.0, 0.3, 0.2])
    fast = np.array([2.5, 0.0, 0.0, 0.0, 0.0, 3.0])
    for v_c, achievable in ((slow, True), (fast, False)):
        scene.reset_to_start(0.6)
        qds, tw = [], []
        for _ in range(200):  # 0.4 s
            T_w_c, T_w_e = scene.T_w_c(), arm.T_w_e()
            arm.command_twist(shift_twist(v_c, T_w_c[:3, 3], T_w_e[:3, 3]), period)
            for _ in range(round(period / h)):
                qds.append(arm.qd.copy())
                scene.step()
            tw.append(shift_twist(arm.twist_w(), T_w_e[:3, 3], T_w_c[:3, 3]))
        qds = np.array(qds)
        assert np.all(np.abs(qds) <= PANDA.qd_max + 1e-12)
        assert np.all(np.abs(np.diff(qds, axis=0)) <= PANDA.qdd_max * h * (1 + 1e-9))
        # Jerk within the datasheet's limit, except where a joint arrives at its velocity limit (safety
        # wins: the acceleration drops to zero there at once).
        jerk = np.abs(np.diff(qds, 2, axis=0)) / h**2
        free = np.abs(qds) < PANDA.qd_max - 1e-9
        free = free[:-2] & free[1:-1] & free[2:]
        assert np.all(jerk <= np.where(free, PANDA.qddd_max * (1 + 1e-6), np.inf))
        assert np.any(jerk[free] > 0.5 * PANDA.qddd_max.min())  # the limit is approached: it does bite
        if achievable:
            np.testing.assert_allclose(tw[-1], v_c, atol=0.02 * np.linalg.norm(v_c))
        else:
            assert np.any(np.isclose(np.abs(qds).max(axis=0), PANDA.qd_max))  # a joint saturated


def test_qp_is_exact_when_feasible_and_brakes_before_position_limit():
    rng = np.random.default_rng(5)
    J = rng.normal(size=(6, 6))
    q = np.zeros(6)
    qd = np.zeros(6)
    v = J @ np.full(6, 0.01)  # 0.01 rad/s per joint: within every bound over 2 ms
    qd_sol = solve_joint_velocities(J, v, q, qd, 0.002, UR5E, damping=0.0)
    np.testing.assert_allclose(qd_sol, 0.01, atol=1e-9)
    # 1 mrad from the Panda's joint-4 upper limit, moving towards it at 0.5 rad/s: the bound lets it
    # move on only as fast as it can still stop, √(2 · 12.5 · 0.001) = 0.158 rad/s.
    q = np.array([0, 0, 0, PANDA.q_max[3] - 0.001, 0, 1.5, 0])
    qd = np.array([0, 0, 0, 0.5, 0, 0, 0])
    lb, ub = joint_velocity_bounds(q, qd, 0.002, PANDA)
    assert ub[3] == pytest.approx(np.sqrt(2 * 12.5 * 0.001))
    assert lb[3] == ub[3]  # braking harder than the acceleration limit allows: safety wins
    # Joint 4 at rest accelerating at 10 rad/s² (jerk limit 6250 rad/s³): over 2 ms its acceleration can
    # fall by 12.5 rad/s² at most, to −2.5, so it cannot slow down by more than 2.5 · 0.002 = 0.005 rad/s;
    # without the acceleration now, the acceleration window alone allows ±12.5 · 0.002 = 0.025 rad/s.
    q[3] = -1.5
    qd[3] = 0.0
    lb, ub = joint_velocity_bounds(q, qd, 0.002, PANDA, qdd=np.array([0, 0, 0, 10.0, 0, 0, 0]))
    assert (lb[3], ub[3]) == pytest.approx((-0.005, 0.025))
    lb, ub = joint_velocity_bounds(q, qd, 0.002, PANDA)
    assert (lb[3], ub[3]) == pytest.approx((-0.025, 0.025))


def servo_run(scene, feedforward: bool, duration_s: float = 4.0) -> np.ndarray:
    """Pbvs on the Panda against the UR5e moving the target at 0.4 m/s, poses from a 100 Hz ground-truth
    oracle, control at 500 Hz; returns the translation error of T_c_o (m) after the first second."""
    T_c_o_des = scene.reset_to_start(0.6)
    T_w_o0 = scene.T_w_o()
    traj = trajectories.make_trajectory("trans", speed_mps=0.4)
    follower = PoseFollower(
        scene.ur, lambda t: trajectories.apply(traj(np.array([t])), T_w_o0)[0], T_e_x=scene.config.T_e_o
    )
    ctrl = Pbvs(feedforward=feedforward, period_s=0.002)
    t0 = scene.t_s
    ctrl.start(scene.T_w_c(), scene.T_c_o(), t_s=0.0)
    errs = []
    for k in range(1, round(duration_s / 0.002) + 1):
        t = scene.t_s - t0
        follower.command(t)
        T_w_c, T_w_e = scene.T_w_c(), scene.panda.T_w_e()
        v_c = shift_twist(scene.panda.twist_w(), T_w_e[:3, 3], T_w_c[:3, 3])
        cmd = ctrl.update(t, T_w_c, v_c, scene.T_c_o() if k % 5 == 0 else None)
        assert cmd.state == "ok"
        scene.panda.command_twist(shift_twist(cmd.v_c_w, T_w_c[:3, 3], T_w_e[:3, 3]), 0.002)
        scene.step(2)
        if t > 1.0:
            errs.append(geometry.translation_error_m(scene.T_c_o(), T_c_o_des))
    return np.array(errs)


def test_closed_loop_servo_follows_moving_target(scene):
    rms = {ff: float(np.sqrt(np.mean(servo_run(scene, ff) ** 2))) for ff in (False, True)}
    # Eq. 6 alone lags a ramp by 2 v / √k (0.18 m at 0.4 m/s); the sinusoid's RMS stays below that.
    assert 0.05 < rms[False] < 0.12, rms
    assert rms[True] < 0.65 * rms[False], rms


def test_reach_passes_what_the_panda_can_do_and_cuts_the_rest_image_first(scene):
    from evservo.control import saturation
    from evservo.robots.reach import ReachableTwist

    scene.reset_to_start(0.6)
    reach = ReachableTwist(scene.panda)
    dt = 0.002
    small = np.array([0.004, -0.002, 0.001, 0.0, 0.005, 0.0])  # reachable from rest within one period
    assert reach(small, np.eye(6), dt) is small and not reach.saturated
    # From rest no joint may change speed by more than q̈_max·dt: 0.5 m/s is out of reach.
    T_w_c = scene.T_w_c()
    A = saturation.image_motion_matrix(T_w_c, T_w_c[:3, :3] @ [0, 0, 0.6] + T_w_c[:3, 3], 0.1)
    W = saturation.image_priority_weights(A, 0.6)
    big = np.concatenate([T_w_c[:3, :3] @ [0.5, 0.0, 0.3], T_w_c[:3, :3] @ [0.0, -0.4, 0.0]])
    cut = {}
    for name, weights in (("image", W), ("plain", np.eye(6))):
        cut[name] = reach(big, weights, dt)
        assert reach.saturated
        lb, ub = joint_velocity_bounds(scene.panda.joint_positions(), scene.panda.qd, dt, PANDA)
        J = reach.camera_jacobian()
        # What it returns is the camera twist of joint velocities inside the limits.
        qd = solve_joint_velocities(J, cut[name], scene.panda.joint_positions(), scene.panda.qd, dt, PANDA,
                                    damping=1e-9)  # fmt: skip
        assert np.all(qd >= lb - 1e-9) and np.all(qd <= ub + 1e-9)
        np.testing.assert_allclose(J @ qd, cut[name], atol=1e-6)
    # Image first: what is left out moves the object's centre in the image less than an even cut would
    # (measured 0.29 vs 0.56 rad/s).
    img = {k: np.linalg.norm(A[:3] @ (v - big)) for k, v in cut.items()}
    assert img["image"] < 0.7 * img["plain"], img


def test_delayed_arm_acts_on_commands_after_the_latency(scene):
    from evservo.robots.delay import DelayedArm

    scene.reset_to_start(0.9)
    link = DelayedArm(scene.panda, 0.003)
    v = np.array([0.0, 0.0, 0.002, 0.0, 0.0, 0.0])
    link.command_twist(v, 0.001)
    for t_us in (1000, 2000):
        link.deliver(t_us)
        assert not np.any(scene.panda.qd_target)  # not arrived yet
    link.deliver(3000)
    assert np.linalg.norm(scene.panda.jacobian() @ scene.panda.qd_target - v) < 1e-4
    link.stop()
    link.deliver(5999)
    assert np.any(scene.panda.qd_target)
    link.deliver(6000)
    assert not np.any(scene.panda.qd_target)
