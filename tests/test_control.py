"""AnalyticController: the closed-form fast path against the least-squares kinematics (a second derivation),
motor references against the spring law, the LM dynamics against brute-force search, input checks."""

import math

import numpy as np
import pytest

from vswrist_gym.control import AnalyticController
from vswrist_gym.kinematics import WristKinematics
from vswrist_gym.params import load_params
from vswrist_gym.stiffness import (coupler_compliance, coupler_stiffness, lambda_range, max_leg_torque,
                                   posture_terms, spring_torque, stiffness_from_terms)


@pytest.fixture(scope="module", params=["paper", "paper_knm"])
def params(request):
    return load_params(request.param)


def _postures(kin, n, seed=0):
    rng = np.random.default_rng(seed)
    return [np.zeros(2)] + [rng.uniform(kin.u_min, kin.u_max) for _ in range(n)]


def test_fast_path_matches_least_squares_kinematics(params):
    kin, ctrl = WristKinematics(params), AnalyticController(params)
    for u in _postures(kin, 60):
        q1, Ja, N = ctrl.kinematics_at(u)
        np.testing.assert_allclose(q1, kin.joint_angles(u)[0::4], atol=1e-12)
        np.testing.assert_allclose(Ja, kin.actuated_jacobian(u), atol=1e-10)
        np.testing.assert_allclose(N, kin.internal_torque_basis(u), atol=1e-10)


def test_fast_jacobian_is_the_derivative_of_q1():
    kin, ctrl = WristKinematics(), AnalyticController()
    h = 1e-6
    for u in _postures(kin, 10, seed=1):
        _, Ja, N = ctrl.kinematics_at(u)
        for j in range(2):
            e = np.zeros(2)
            e[j] = h
            fd = (kin.joint_angles(u + e, True)[0::4] - kin.joint_angles(u - e, True)[0::4]) / (2 * h)
            np.testing.assert_allclose(Ja[:, j], fd, atol=1e-8)
        np.testing.assert_allclose(Ja.T @ N, 0.0, atol=1e-12)
        assert np.all(N < 0) and math.isclose(np.linalg.norm(N), 1.0)


def test_home_values_from_the_domain_notes():
    _, Ja, N = AnalyticController().kinematics_at((0.0, 0.0))
    np.testing.assert_allclose(Ja, [[0, 0.5], [-math.sqrt(3) / 4, -0.25], [math.sqrt(3) / 4, -0.25]], atol=1e-12)
    np.testing.assert_allclose(N, -np.ones(3) / math.sqrt(3), atol=1e-12)


def test_motor_references_make_the_springs_exert_lambda_n(params):
    """At the reference posture the springs must carry exactly lam N (which J_a^T maps to no net torque)."""
    kin, ctrl = WristKinematics(params), AnalyticController(params)
    for i, u in enumerate(_postures(kin, 12, seed=2)):
        lo, hi = lambda_range(u, params)
        lam = (0.9 * hi) * (i / 6.0 - 1.0)
        theta = ctrl.step([u[0], u[1], 0.4], lam=lam)
        q1 = kin.joint_angles(u)[0::4]
        tau = spring_torque(q1 - theta[:3], params)
        np.testing.assert_allclose(tau, lam * kin.internal_torque_basis(u), atol=1e-9 * max(1.0, abs(lam)))
        assert theta[3] == 0.4
        assert ctrl.lam == pytest.approx(lam)


def test_stiffness_and_lambda_range_match_the_analytic_model(params):
    kin = WristKinematics(params)
    for include in (True, False):
        ctrl = AnalyticController(params, include_load_term=include)
        for u in _postures(kin, 5, seed=3):
            lo, hi = lambda_range(u, params)
            assert ctrl.lambda_range(u) == pytest.approx((lo, hi), rel=1e-10)
            for lam in (lo, 0.3 * lo, 0.0, 0.5 * hi, hi):
                ctrl.step([u[0], u[1], 0.0], lam=lam)
                ref = coupler_stiffness(u, lam, params, include_load_term=include)
                np.testing.assert_allclose(ctrl.stiffness(), ref, rtol=1e-6, atol=1e-9 * np.abs(ref).max())


def test_lambda_is_clipped_to_the_torque_and_deflection_limits(params):
    ctrl = AnalyticController(params)
    _, hi = ctrl.lambda_range((0.0, 0.0))
    ctrl.step((0, 0, 0), lam=1e6)
    assert ctrl.lam == pytest.approx(hi)
    theta = ctrl.step((0, 0, 0), lam=-1e6)
    assert ctrl.lam == pytest.approx(-hi)
    q1 = WristKinematics(params).joint_angles(np.zeros(2))[0::4]
    delta = q1 - theta[:3]
    assert np.all(np.abs(delta) <= params.spring.deflection_limit + 1e-12)
    assert np.all(np.abs(spring_torque(delta, params)) <= max_leg_torque(params) * (1 + 1e-12))
    ctrl.step((0, 0, 0))                      # neither lam nor compliance: keep lam
    assert ctrl.lam == pytest.approx(-hi)


def test_posture_reference_is_clipped_to_the_range_of_motion():
    p = load_params()
    rom = p.range_of_motion
    ctrl = AnalyticController(p)
    theta = ctrl.step((5.0, -5.0, 10.0), lam=0.0)
    np.testing.assert_allclose(ctrl.posture_reference, [rom.rud_max, rom.fe_min, rom.ps_max])
    np.testing.assert_allclose(theta[:3], WristKinematics(p).joint_angles(np.array([rom.rud_max, rom.fe_min]))[0::4])
    assert theta[3] == rom.ps_max


@pytest.mark.parametrize("kwargs, name", [
    ({"posture_ref": (0.0, np.nan, 0.0)}, "posture_ref"),
    ({"posture_ref": (0.0, 0.0, np.inf)}, "posture_ref"),
    ({"posture_ref": (0.0, 0.0)}, "posture_ref"),
    ({"posture_ref": (0.0, 0.0, 0.0), "lam": np.nan}, "lam"),
    ({"posture_ref": (0.0, 0.0, 0.0), "compliance_ref": [[1.0, 0.0], [0.0, np.inf]]}, "compliance_ref"),
    ({"posture_ref": (0.0, 0.0, 0.0), "lam": 1.0, "compliance_ref": np.eye(2)}, "lam"),
])
def test_bad_references_raise_naming_the_argument(kwargs, name):
    with pytest.raises(ValueError, match=name):
        AnalyticController().step(**kwargs)


def test_bad_dt_raises():
    with pytest.raises(ValueError, match="dt"):
        AnalyticController(dt=0.0)


@pytest.mark.parametrize("u", [(0.0, 0.0), (0.3, -0.4), (-0.6, 0.7)])
def test_lm_reaches_a_reachable_compliance_within_one_percent(params, u):
    """c_r = C(u, lam*) is reachable: from lam = 0 the LM dynamics must reach lam* (an independent
    brute-force search over lam confirms lam* is the minimiser)."""
    u = np.asarray(u)
    lo, hi = lambda_range(u, params)
    lam_star = 0.4 * hi
    c_ref = coupler_compliance(u, lam_star, params)
    ctrl = AnalyticController(params, dt=0.02)
    ctrl.reset((u[0], u[1], 0.0), lam=0.0)
    for _ in range(100):                                  # 2 s
        ctrl.step((u[0], u[1], 0.0), compliance_ref=c_ref)
    assert ctrl.lam == pytest.approx(lam_star, rel=0.01)
    np.testing.assert_allclose(ctrl.compliance(), c_ref, rtol=0.02, atol=1e-6 * np.abs(c_ref).max())


def test_lm_rate_is_the_papers_formula_with_g_and_its_derivative_from_the_analytic_model(params):
    """d(lam)/dt = -alpha H/(H^2 + nu) G, G = ||C - c_r||_F from ``stiffness``, H = dG/dlam by central differences."""
    u = np.array([0.2, -0.3])
    terms = posture_terms(u, params)
    c_ref = np.array([[0.9, 0.1], [0.05, 1.3]]) * coupler_compliance(u, 0.3 * lambda_range(u, params)[1], params)[0, 0]
    ctrl = AnalyticController(params)
    ctrl.reset((u[0], u[1], 0.0))

    def G(lam):
        return np.linalg.norm(np.linalg.inv(stiffness_from_terms(terms, lam, params)) - c_ref)

    hi = lambda_range(u, params)[1]
    for lam in (-0.5 * hi, 0.1 * hi, 0.6 * hi):
        h = 1e-6 * hi
        H = (G(lam + h) - G(lam - h)) / (2 * h)
        expected = -params.control.lm_alpha * H / (H * H + params.control.lm_nu) * G(lam)
        assert ctrl.lm_rate(lam, c_ref) == pytest.approx(expected, rel=1e-5)


def _brute_force_minimiser(u, c_ref, params, lo, hi, n=4001):
    """Dense scan of G over [lo, hi], then a second dense scan around the best point."""
    terms = posture_terms(u, params)

    def scan(grid):
        return np.array([np.linalg.norm(np.linalg.inv(stiffness_from_terms(terms, lam, params)) - c_ref)
                         for lam in grid])

    grid = np.linspace(lo, hi, n)
    i = int(np.argmin(scan(grid)))
    fine = np.linspace(grid[max(i - 1, 0)], grid[min(i + 1, n - 1)], 2001)
    return fine, scan(fine)


def test_lm_converges_to_the_minimiser_of_g_for_an_unreachable_reference():
    """Anisotropic c_r that no lam reaches: the LM dynamics settle where dG/dlam = 0, at the minimiser a
    brute-force 1-D search finds (on the side of lam = 0 the dynamics leave towards)."""
    p = load_params()
    u = np.array([0.3, 0.2])
    c_soft = coupler_compliance(u, 0.5, p)
    c_ref = np.diag([0.3 * c_soft[0, 0], 1.5 * c_soft[1, 1]])
    ctrl = AnalyticController(p)
    ctrl.reset((u[0], u[1], 0.0), lam=0.0)
    for _ in range(300):                                  # 6 s
        ctrl.step((u[0], u[1], 0.0), compliance_ref=c_ref)
    lo, hi = lambda_range(u, p)
    grid, G = _brute_force_minimiser(u, c_ref, p, 0.0 if ctrl.lam > 0 else lo, hi if ctrl.lam > 0 else 0.0)
    assert G.min() > 1e-3 * np.linalg.norm(c_ref)          # unreachable indeed
    best = grid[np.argmin(G)]
    assert ctrl.lam == pytest.approx(best, abs=2 * (grid[1] - grid[0]) + 1e-4 * abs(best))
    assert abs(ctrl.lm_rate(ctrl.lam, c_ref)) < 1e-3 * max(1.0, abs(ctrl.lam))


def test_gravity_compensation_balances_the_weight_of_hand_and_coupler():
    """tau_g must satisfy J_a^T tau_g = dV_g/du, with V_g from the exact forward kinematics (finite differences)."""
    p = load_params()
    kin = WristKinematics(p)
    ctrl = AnalyticController(p, gravity_compensation=True)
    g = np.asarray(p.environment.gravity)

    def V(u):
        T = kin.coupler_pose(u, allow_outside=True)
        hand = T[:3, 3] + p.inertia.hand_offset * T[:3, 0]
        return -(p.inertia.hand_mass * hand + p.inertia.coupler_mass * T[:3, 3]) @ g

    for _ in _balanced_postures(ctrl, kin, V, p, seed=4):
        pass


def _balanced_postures(ctrl, kin, V, p, seed: int):
    """Postures at which tau_g equals the finite difference of V_g and the springs' torques at lam = 0 balance it
    through J_a^T; yields each posture after checking it."""
    h = 1e-6
    for u in _postures(kin, 6, seed=seed):
        dV = np.array([(V(u + e) - V(u - e)) / (2 * h) for e in (np.array([h, 0]), np.array([0, h]))])
        np.testing.assert_allclose(ctrl.gravity_torque(u), dV, atol=1e-7)
        theta = ctrl.step([u[0], u[1], 0.0], lam=0.0)
        q1, Ja, _ = ctrl.kinematics_at(u)
        np.testing.assert_allclose(Ja.T @ spring_torque(q1 - theta[:3], p), dV, atol=1e-7)
        yield u


def test_gravity_compensation_holds_a_payload_on_the_ps_axis():
    """With a payload of point masses (m, x) at O_c + x x_c, tau_g balances their weight too (V_g from the exact
    forward kinematics); without one, the torques are those of the hand and coupler alone, to the bit."""
    p = load_params()
    kin = WristKinematics(p)
    payload = ((0.03, 0.02), (0.3, 0.17))
    ctrl = AnalyticController(p, gravity_compensation=True, payload=payload)
    plain, empty = AnalyticController(p, gravity_compensation=True), AnalyticController(p, gravity_compensation=True,
                                                                                           payload=())
    g = np.asarray(p.environment.gravity)

    def V(u):
        T = kin.coupler_pose(u, allow_outside=True)
        points = [(p.inertia.hand_mass, p.inertia.hand_offset), (p.inertia.coupler_mass, 0.0), *payload]
        return -sum(m * (T[:3, 3] + x * T[:3, 0]) for m, x in points) @ g

    for u in _balanced_postures(ctrl, kin, V, p, seed=5):
        assert np.array_equal(plain.step([u[0], u[1], 0.0], lam=0.3), empty.step([u[0], u[1], 0.0], lam=0.3))
    with pytest.raises(ValueError, match="payload"):
        AnalyticController(p, gravity_compensation=True, payload=((-0.1, 0.1),))


# ------------------------------------------------------------------ closed loop in the MuJoCo simulator
def _settle(sim, max_s=30.0):
    for _ in range(int(max_s / 0.1)):
        sim.step(0.1)
        if np.abs(sim.posture_rate()).max() < 1e-7:
            break
    assert np.abs(sim.posture_rate()).max() < 1e-5, "did not settle"


def _damped(preset, u, lam):
    """Gravity off; leg damping near critical for the slowest mode (the statics do not depend on it)."""
    p0 = load_params(preset)
    S = coupler_stiffness(u, lam, p0)
    c = 0.3 * np.sqrt(np.linalg.eigvalsh(S).min() * 6e-3)
    return p0.replace(environment={"gravity": [0.0, 0.0, 0.0]}, damping={"leg_joint": max(c, p0.damping.leg_joint)})


LEVEL_FRACTIONS = (0.0, 0.05, 0.3, 0.9)    # of the allowed internal torque: soft to stiff


@pytest.mark.parametrize("preset", ["paper", "paper_knm"])
def test_closed_loop_holds_the_posture_at_each_stiffness_level(preset):
    from vswrist_gym.sim import WristSim
    target = np.array([0.3, -0.4, 0.2])
    for frac in LEVEL_FRACTIONS:
        lam = frac * lambda_range(target[:2], preset)[1]
        p = _damped(preset, target[:2], lam)
        sim, ctrl = WristSim(p), AnalyticController(p)
        sim.reset((0.0, 0.0), 0.0, 0.0)
        ctrl.reset((0.0, 0.0, 0.0), 0.0)
        for _ in range(25):                                  # 0.5 s of control at 50 Hz, then hold
            sim.set_motor_references(ctrl.step(target, lam=lam))
            sim.step(0.02)
        _settle(sim)
        err = np.abs(sim.posture() - target)
        assert err.max() < 0.01, f"{preset} lam={lam:.3g}: posture error {err} rad"


@pytest.mark.parametrize("preset", ["paper", "paper_knm"])
def test_stiffness_measured_in_the_simulator_follows_the_commanded_lambda(preset):
    """Central finite differences of the settled posture under small torques on the hand: Sigma = dw_u/du
    must equal the controller's complete stiffness within 3 % (relative Frobenius), for several lambdas."""
    from vswrist_gym.sim import WristSim
    u = np.array([0.3, -0.2])
    kin = WristKinematics(preset)
    W = kin.coupler_twist_jacobian(u)[:3]
    to_torque = W @ np.linalg.inv(W.T @ W)
    for frac in (-0.5, 0.05, 0.3, 0.9):
        lo, hi = lambda_range(u, preset)
        lam = frac * (hi if frac > 0 else -lo)
        p = _damped(preset, u, lam)
        sim, ctrl = WristSim(p), AnalyticController(p)
        ctrl.reset((u[0], u[1], 0.0), lam)
        S_cmd = ctrl.stiffness()
        theta = ctrl.step((u[0], u[1], 0.0), lam=lam)
        loads, moves = [], []
        for i in range(2):
            w = S_cmd @ (2e-3 * np.eye(2)[i])
            settled = []
            for sign in (1.0, -1.0):
                sim.reset((0.0, 0.0), 0.0, 0.0)
                sim.set_motor_references(theta)
                sim.apply_wrench(torque=to_torque @ (sign * w))
                _settle(sim)
                settled.append(sim.posture()[:2])
            loads.append(w)
            moves.append((settled[0] - settled[1]) / 2)
        S_sim = np.column_stack(loads) @ np.linalg.inv(np.column_stack(moves))
        err = np.linalg.norm(S_sim - S_cmd) / np.linalg.norm(S_cmd)
        assert err < 0.03, f"{preset} lam={lam:.3g}: measured stiffness {err:.2%} from the commanded one"


# ------------------------------------------------------------------ the analytic agent
class _FakeEnv:
    """The two members of the env contract the agent uses: obs_slices and reference_to_action."""

    ctrl_dt = 0.1

    def __init__(self):
        self.obs_slices = {"posture": slice(0, 3), "target": slice(3, 6)}
        self.calls = []

    @property
    def unwrapped(self):
        return self

    def reference_to_action(self, posture_ref, stiffness):
        self.calls.append((np.array(posture_ref), stiffness))
        return np.append(np.asarray(posture_ref) / 2.0, stiffness)


def test_agent_maps_the_target_and_fixed_stiffness_through_the_env():
    from vswrist_gym.agents.analytic import AnalyticAgent
    env = _FakeEnv()
    agent = AnalyticAgent(env, stiffness=0.25)
    obs = np.array([9.0, 9.0, 9.0, 0.1, -0.2, 0.3], dtype=np.float32)
    action, state = agent.predict(obs, deterministic=True)
    np.testing.assert_allclose(env.calls[-1][0], [0.1, -0.2, 0.3], rtol=1e-6)
    assert env.calls[-1][1] == 0.25 and state is None
    np.testing.assert_allclose(action, [0.05, -0.1, 0.15, 0.25], rtol=1e-6)
    batch, _ = agent.predict(np.stack([obs, obs]))              # vectorised envs: one row each
    assert batch.shape == (2, 4)
    dict_action, _ = agent.predict({"target": obs[3:6]})        # dict observations
    np.testing.assert_allclose(dict_action, action)


def test_agent_schedule_follows_episode_time_and_restarts():
    from vswrist_gym.agents.analytic import AnalyticAgent
    env = _FakeEnv()                                            # ctrl_dt = 0.1 s
    agent = AnalyticAgent.from_config(env, {"schedule": {"times": [0.0, 0.3], "values": [-1.0, 0.5]}})
    obs = np.zeros(6)
    got = [agent.predict(obs, episode_start=np.array([i == 0]))[0][3] for i in range(5)]
    assert got == [-1.0, -1.0, -1.0, 0.5, 0.5]                  # t = 0, 0.1, 0.2, 0.3, 0.4 s
    assert agent.predict(obs, episode_start=np.array([True]))[0][3] == -1.0


@pytest.mark.parametrize("bad", [{"stiffness": 1.5}, {"stiffness": float("nan")},
                                 {"schedule": {"times": [0.3, 0.1], "values": [0, 0]}}, {"speed": 1}])
def test_agent_rejects_bad_settings(bad):
    from vswrist_gym.agents.analytic import AnalyticAgent
    with pytest.raises(ValueError):
        AnalyticAgent.from_config(_FakeEnv(), bad)


def test_agent_on_a_real_environment_tracks_the_target():
    gym = pytest.importorskip("gymnasium")
    import vswrist_gym  # noqa: F401  (registers the environments)
    from vswrist_gym.agents.analytic import AnalyticAgent
    env = gym.make("VSWrist/LoadHold-v0")
    obs, _ = env.reset(seed=0)
    agent = AnalyticAgent(env, stiffness=1.0)
    errors = []
    for _ in range(50):
        action, _ = agent.predict(obs)
        assert env.action_space.contains(action)
        obs, _, terminated, truncated, info = env.step(action)
        errors.append(info["posture_error"])
        if terminated or truncated:
            break
    assert np.all(np.isfinite(errors)) and np.median(errors) < 0.1
    env.close()


@pytest.mark.parametrize("gravity", [False, True])
def test_batched_step_is_the_scalar_step_world_by_world(params, gravity):
    """``step_batch`` (arrays over N controllers, what a batch of worlds runs) against N calls of the scalar
    ``step``: references inside and outside the range of motion, lam inside and beyond the allowed range."""
    ctrl = AnalyticController(params, gravity_compensation=gravity)
    rng = np.random.default_rng(5)
    n = 200
    refs = rng.uniform(-2.0, 2.0, (n, 3))
    lams = rng.uniform(-2.0, 2.0, n) * ctrl.lambda_range((0.0, 0.0))[1]
    theta, lam_c, u = ctrl.step_batch(refs, lams)
    for i in range(n):
        want = ctrl.step(refs[i], lam=lams[i])
        np.testing.assert_allclose(theta[i], want, rtol=0, atol=1e-12)
        assert abs(lam_c[i] - ctrl.lam) <= 1e-12 * max(1.0, abs(ctrl.lam))
        np.testing.assert_allclose(u[i], ctrl.posture_reference, rtol=0, atol=1e-15)
    q1, Ja, _, _ = ctrl.posture_kinematics_batch(u[:, 0], u[:, 1])
    for i in (0, n // 2, n - 1):
        q1_s, Ja_s, N_s = ctrl.kinematics_at(u[i, :2])
        np.testing.assert_allclose(q1[i], q1_s, rtol=0, atol=1e-12)
        np.testing.assert_allclose([[Ja[0][k, i], Ja[1][k, i]] for k in range(3)], Ja_s, rtol=0, atol=1e-12)
        np.testing.assert_allclose([x[i] for x in ctrl.basis_batch(Ja)], N_s, rtol=0, atol=1e-12)


def test_a_bound_controller_keeps_its_command_in_the_given_arrays(params):
    """``bind``: the command (clipped posture reference, lam) moves into the caller's arrays with its values, the
    controller writes it there, and goes on from what the caller writes there (as a batch's ``step_batch`` rows)."""
    ctrl = AnalyticController(params)
    twin = AnalyticController(params)
    for c in (ctrl, twin):
        c.step((0.1, -0.2, 0.3), lam=0.5)
    ref, lam = np.full((2, 3), np.nan), np.full(2, np.nan)
    ctrl.bind(ref[1], lam[1:])
    np.testing.assert_array_equal(ref[1], twin.posture_reference)
    assert lam[1] == twin.lam == ctrl.lam
    ctrl.step((9.0, 0.05, 0.0), lam=1e6)  # clipped, into the arrays
    np.testing.assert_array_equal(ref[1], ctrl.posture_reference)
    assert ref[1, 0] == params.range_of_motion.rud_max and lam[1] == ctrl.lam == ctrl.lambda_range()[1]
    _, lam_c, u = twin.step_batch(np.array([[0.2, 0.1, 0.0]]), np.array([0.3]))
    ref[1], lam[1] = u[0], lam_c[0]
    np.testing.assert_array_equal(ctrl.step((0.2, 0.1, 0.0)), twin.step((0.2, 0.1, 0.0), lam=0.3))
    assert np.isnan(ref[0]).all() and np.isnan(lam[0])
