"""The hot-path shortcuts of the controller and the environments equal the plain computations they replace."""

import math

import gymnasium as gym
import numpy as np
import pytest

import vswrist_gym  # noqa: F401  (registers the ids)
from vswrist_gym.control import AnalyticController, _finite_vector
from vswrist_gym.envs.rewards import row_sum_sq


def _postures(n, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform([-0.5, -0.9], [0.5, 0.9], size=(n, 2))


def test_scalar_gravity_torques_equal_the_numpy_reference_and_a_least_squares_solution():
    ctrl = AnalyticController(gravity_compensation=True)
    for ay, az in _postures(50):
        q1, Ja, dOc, dxc = ctrl._posture_kinematics(float(ay), float(az))
        fast = np.array(ctrl._min_norm_torques(Ja, ctrl._gravity_from_derivatives(dOc, dxc)))
        ref = ctrl._gravity_torques_reference(float(ay), float(az), Ja)
        np.testing.assert_allclose(fast, ref, rtol=1e-12, atol=1e-15 * np.abs(ref).max())
        # independent: the minimum-norm solution of J_a^T tau = dV_g/du by least squares
        J = np.array(Ja)
        w = ctrl.gravity_torque((ay, az))
        lsq = np.linalg.lstsq(J.T, w, rcond=None)[0]
        np.testing.assert_allclose(fast, lsq, rtol=1e-10, atol=1e-14)


@pytest.mark.parametrize("gravity", [False, True])
def test_step_equals_the_formula_from_the_reference_terms(gravity):
    ctrl = AnalyticController(gravity_compensation=gravity)
    K2, d0, tmax = 2.0 * ctrl.params.spring.K, ctrl.params.spring.delta0, ctrl._tau_max
    for (ay, az), lam in zip(_postures(30, 1), np.linspace(0.0, 1.0, 30)):
        theta = ctrl.step(np.array([ay, az, 0.2]), lam=float(lam))
        ay, az, _ = ctrl.posture_reference  # clipped to the range of motion
        q1, Ja, N = ctrl.kinematics_at((ay, az))
        tau = ctrl.lam * N
        if gravity:
            tau = np.clip(tau + ctrl._gravity_torques_reference(ay, az, Ja), -tmax, tmax)
        expected = np.append(q1 + d0 * np.arcsinh(tau / K2), 0.2)
        np.testing.assert_allclose(theta, expected, rtol=1e-12, atol=1e-14)


def test_array_fast_path_of_the_reference_check_still_rejects_nan_and_inf():
    assert _finite_vector("u", np.array([0.1, -0.2]), 2) == (0.1, -0.2)
    for bad in (np.array([np.nan, 0.0]), np.array([0.0, np.inf]), np.array([-np.inf, 1.0])):
        with pytest.raises(ValueError, match="u must be finite"):
            _finite_vector("u", bad, 2)
    with pytest.raises(ValueError, match="posture_ref"):
        AnalyticController().step(np.array([0.0, np.nan, 0.0]), lam=0.1)


def test_sum_of_squares_adds_in_order_for_one_world_and_a_batch():
    """``row_sum_sq`` and the coupler stiffness's leg sum: NumPy's reduction of fewer than 8 terms adds them in
    order, for one world's row and for a batch's rows alike (what makes the single env equal the batch)."""
    from vswrist_gym.envs.observations import coupler_stiffness
    rng = np.random.default_rng(3)
    for n in range(1, 8):
        for _ in range(200):
            X = rng.normal(size=(5, n)) * 10.0 ** rng.integers(-6, 6, size=(5, n))
            in_order = [float(sum(v * v for v in x.tolist())) for x in X]  # sum() starts at 0: ((0 + a) + b) ...
            np.testing.assert_array_equal(row_sum_sq(X), in_order)
            assert [row_sum_sq(x) for x in X] == in_order
    Ja, sig = rng.normal(size=(6, 3, 2)), rng.uniform(1, 100, size=(6, 3))
    by_leg = [[sum(s[k] * J[k, i] * J[k, j] for k in range(3)) for i, j in ((0, 0), (0, 1), (1, 1))]
              for J, s in zip(Ja, sig)]
    np.testing.assert_array_equal(coupler_stiffness(Ja, sig), by_leg)
    assert all(np.array_equal(coupler_stiffness(J, s), b) for J, s, b in zip(Ja, sig, by_leg))
    from vswrist_gym.stiffness import SpringLaw, spring_energy, stored_energy
    D, law = rng.uniform(-0.3, 0.3, size=(6, 3)), SpringLaw(rng.uniform(3, 5, size=(6, 1)), 0.1)
    per_spring = spring_energy(D, law).tolist()
    np.testing.assert_array_equal(stored_energy(D, law), [e0 + e1 + e2 for e0, e1, e2 in per_spring])
    assert [stored_energy(d, SpringLaw(k[0], 0.1)) for d, k in zip(D, law.K)] == [e0 + e1 + e2 for e0, e1, e2 in
                                                                                   per_spring]


def test_squared_norms_of_a_batch_are_each_worlds_dot_product():
    """The posture error's squared norm over a batch's rows (``squared_norms``: ``np.vecdot``) is each row's own
    ``e @ e`` as the single env computes it, to the bit: NumPy runs the same dot product (its BLAS kernel, whose
    order and rounding an in-order sum may miss by an ulp) row by row. Rows of 1-6 entries, scales over 12
    decades, and an empty batch."""
    from vswrist_gym.envs.rewards import squared_norms
    rng = np.random.default_rng(5)
    for n in range(1, 7):
        E = rng.normal(size=(300, n)) * 10.0 ** rng.integers(-6, 6, size=(300, 1))
        np.testing.assert_array_equal(squared_norms(E), [e @ e for e in E])
        assert all(squared_norms(e) == e @ e for e in E[:20])
    assert squared_norms(np.zeros((0, 3))).shape == (0,)


def test_observed_stiffness_equals_the_papers_formula_from_kinematics_at():
    env = gym.make("VSWrist/LoadHold-v0")
    u = env.unwrapped
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    for _ in range(5):
        env.step(rng.uniform(-1, 1, env.action_space.shape).astype(np.float32))
        _, Ja, _ = u.ctrl.kinematics_at(u._posture[:2])
        s = u.params.spring
        sig = 2.0 * s.K / s.delta0 * np.cosh(u._defl / s.delta0)
        S = Ja.T @ (sig[:, None] * Ja)
        np.testing.assert_allclose(u._obs_stiffness(), [S[0, 0], S[0, 1], S[1, 1]], rtol=1e-12)
        energy = 2.0 * s.K * s.delta0 * np.sum(np.cosh(u._defl / s.delta0) - 1.0)
        assert u._energy == pytest.approx(energy, rel=1e-14)
        assert math.isfinite(u._energy)
    env.close()


def _stepped_sim():
    from vswrist_gym.sim import WristSim
    sim = WristSim()
    sim.reset(u=(0.2, -0.3), lam=0.3)
    sim.apply_wrench((1.0, -2.0, 0.5), (0.01, 0.0, -0.02))
    sim.set_motor_references(sim.motor_references() + np.array([0.05, -0.03, 0.02, 0.1]))
    sim.step(0.02)
    return sim


def test_sync_kinematics_gives_the_poses_and_rates_of_the_full_forward_and_accessors_still_get_sensors():
    full, light = _stepped_sim(), _stepped_sim()
    full.sync()
    light.sync_kinematics()
    np.testing.assert_array_equal(light.posture(), full.posture())
    np.testing.assert_array_equal(light.posture_rate(), full.posture_rate())
    np.testing.assert_array_equal(light.coupler_pose(), full.coupler_pose())
    np.testing.assert_array_equal(light.hand_position(), full.hand_position())
    assert light.loop_closure_error() == full.loop_closure_error()
    # sensors and forces are not computed by sync_kinematics: the accessors that need them do a full forward
    np.testing.assert_array_equal(light.tool_wrench(), full.tool_wrench())
    np.testing.assert_array_equal(light.motor_torques(), full.motor_torques())
    # and the trajectory does not depend on which sync ran in between
    for s in (full, light):
        s.step(0.02)
    np.testing.assert_array_equal(light.get_state(), full.get_state())


def test_light_measurement_of_a_sensorless_task_equals_the_full_one():
    envs = [gym.make("VSWrist/LoadHold-v0") for _ in range(2)]
    envs[1].unwrapped.reads_sensors = True  # force the full mj_forward path
    rng = np.random.default_rng(5)
    actions = rng.uniform(-1, 1, (60,) + envs[0].action_space.shape).astype(np.float32)
    outs = []
    for env in envs:
        obs, _ = env.reset(seed=7)
        seq = [obs]
        for a in actions:
            obs, r, term, trunc, info = env.step(a)
            seq += [obs, r, info["posture_error"], info["elastic_energy"]]
        outs.append(seq)
        env.close()
    for x, y in zip(*outs):
        np.testing.assert_array_equal(x, y)
