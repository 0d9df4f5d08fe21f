"""WristSim validated against the analytic model (kinematics.py / stiffness.py), not against itself."""

from __future__ import annotations

import re
import subprocess
import sys

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

from vswrist_gym.kinematics import LEG_NAMES, RangeOfMotionError  # noqa: E402
from vswrist_gym.params import load_params  # noqa: E402
from vswrist_gym.sim import WristSim  # noqa: E402
from vswrist_gym.stiffness import coupler_stiffness, lambda_range, spring_torque  # noqa: E402

PRESETS = ("paper", "paper_knm")


def no_gravity(preset, **extra):
    return load_params(preset).replace(environment={"gravity": [0.0, 0.0, 0.0]}, **extra)


# ------------------------------------------------------------------------------------------- model
def test_every_element_named_and_home_keyframe_is_closed():
    sim = WristSim()
    m = sim.model
    for obj, count in ((mujoco.mjtObj.mjOBJ_BODY, m.nbody), (mujoco.mjtObj.mjOBJ_JOINT, m.njnt),
                       (mujoco.mjtObj.mjOBJ_ACTUATOR, m.nu), (mujoco.mjtObj.mjOBJ_SENSOR, m.nsensor),
                       (mujoco.mjtObj.mjOBJ_SITE, m.nsite), (mujoco.mjtObj.mjOBJ_EQUALITY, m.neq)):
        start = 1 if obj == mujoco.mjtObj.mjOBJ_BODY else 0  # body 0 is MuJoCo's world
        assert all(mujoco.mj_id2name(m, obj, i) for i in range(start, count))
    for name in ("hand", "tool", "coupler", "ps", "base"):
        assert mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, name) >= 0
    assert m.ncam >= 2
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_KEY, "home"))
    mujoco.mj_forward(m, d)
    assert np.abs(d.efc_pos[d.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY]).max() < 1e-12
    # home: coupler at (r, 0, 0) with the base orientation (domain notes)
    c = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "coupler")
    r = 2 * sim.params.geometry.d * np.sin(sim.params.geometry.alpha / 2)
    np.testing.assert_allclose(d.xpos[c], [r, 0, 0], atol=1e-12)
    np.testing.assert_allclose(d.xmat[c].reshape(3, 3), np.eye(3), atol=1e-12)


@pytest.mark.parametrize("u", [(0.0, 0.0), (0.6, -0.5), (-0.7, 0.8)])
def test_mujoco_legs_follow_the_dh_table(u):
    """Each leg's body after q4 sits at the analytic coupler frame for the analytic joint angles."""
    sim = WristSim()
    sim.reset(u=u)
    T = sim.kin.coupler_pose(np.array(u))
    m, d = sim.model, sim.data
    for name in LEG_NAMES:
        b = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "coupler" if name == "A" else f"leg{name}_end")
        np.testing.assert_allclose(d.xpos[b], T[:3, 3], atol=1e-12)
        np.testing.assert_allclose(d.xmat[b].reshape(3, 3), T[:3, :3], atol=1e-12)
    np.testing.assert_allclose(sim.posture()[:2], u, atol=1e-12)


def test_hand_is_the_papers_point_mass():
    sim = WristSim()
    sim.reset()
    m = sim.model
    p = sim.params.inertia
    assert m.body_mass[sim.hand_id] == pytest.approx(p.hand_mass)
    np.testing.assert_allclose(sim.hand_position(), sim.kin.coupler_pose(np.zeros(2))[:3, 3] + [p.hand_offset, 0, 0],
                               atol=1e-12)


# ---------------------------------------------------------------------------------------- statics
@pytest.mark.parametrize("preset", PRESETS)
def test_springs_carry_the_preload_and_posture_holds(preset):
    """Motors at the analytic references for (u, lam): the springs exert lam N and the posture stays at u."""
    p = no_gravity(preset)
    sim = WristSim(p)
    for u in ((0.0, 0.0), (0.6, 0.7), (-0.7, -0.6)):
        lo, hi = lambda_range(u, p)
        for lam in (0.9 * lo, 0.5 * hi, 0.9 * hi):  # at the very limit the motor loops saturate
            sim.reset(u=u, lam=lam)
            np.testing.assert_allclose(sim.spring_torques(), lam * sim.kin.internal_torque_basis(np.array(u)),
                                       atol=1e-9 * max(1.0, abs(lam)))
            sim.step(1.0)
            assert np.abs(sim.posture()[:2] - u).max() < 1e-3
            assert sim.loop_closure_error() < 1e-4
            assert not sim.warnings()


def test_spring_torques_match_the_sinh_law():
    sim = WristSim()
    u = np.array([0.2, -0.3])
    sim.reset(u=u, lam=1.0)
    delta = sim.joint_angles()[0::4] - sim.motor_angles()[:3]
    np.testing.assert_allclose(sim.spring_torques(), spring_torque(delta, sim.params), rtol=1e-12)
    np.testing.assert_allclose(sim.deflections(), delta, rtol=1e-12)


def measure_stiffness(sim: WristSim, u, lam, du=2e-3):
    """Static stiffness by central finite differences: torque on the hand, settle, Sigma = dw_u / du."""
    u = np.asarray(u, dtype=float)
    S_guess = coupler_stiffness(u, lam, sim.params)  # only to size the load to about du
    W = sim.kin.coupler_twist_jacobian(u)[:3]  # torque tau on the coupler does work tau . W du
    to_torque = W @ np.linalg.inv(W.T @ W)
    loads, moves = [], []
    for i in range(2):
        w = S_guess @ (du * np.eye(2)[i])
        settled = []
        for sign in (1.0, -1.0):
            sim.reset(u=u, lam=lam)
            sim.apply_wrench(torque=to_torque @ (sign * w))
            for _ in range(400):
                sim.step(0.1)
                if np.abs(sim.posture_rate()).max() < 1e-8:
                    break
            assert np.abs(sim.posture_rate()).max() < 1e-6, "did not settle"
            settled.append(sim.posture()[:2])
        loads.append(w)
        moves.append((settled[0] - settled[1]) / 2)
    return np.column_stack(loads) @ np.linalg.inv(np.column_stack(moves))


def stiffness_case(preset, u, lam_fraction):
    p0 = load_params(preset)
    lo, hi = lambda_range(u, p0)
    lam = lam_fraction * (hi if lam_fraction > 0 else -lo)
    S_ref = coupler_stiffness(u, lam, p0)
    # damping near critical for the slowest mode (does not change the statics) so that it settles quickly
    c = 0.3 * np.sqrt(np.linalg.eigvalsh(S_ref).min() * 6e-3)
    sim = WristSim(no_gravity(preset, damping={"leg_joint": c}))
    S_sim = measure_stiffness(sim, u, lam)
    err = np.linalg.norm(S_sim - S_ref) / np.linalg.norm(S_ref)
    S_paper = coupler_stiffness(u, lam, p0, include_load_term=False)
    err_paper = np.linalg.norm(S_paper - S_sim) / np.linalg.norm(S_sim)
    return err, err_paper


STIFFNESS_POSTURES = ((0.0, 0.0), (0.5, 0.4), (-0.6, -0.5))
STIFFNESS_PRELOADS = (-0.8, 0.3, 0.9)  # fractions of the allowed range, both signs


@pytest.mark.parametrize("preset", PRESETS)
@pytest.mark.parametrize("u", STIFFNESS_POSTURES)
def test_static_stiffness_matches_analytic_with_load_term(preset, u):
    for frac in STIFFNESS_PRELOADS:
        err, err_paper = stiffness_case(preset, u, frac)
        assert err < 0.03, f"{preset} u={u} lam={frac}: {err:.3%} from the complete analytic stiffness"
        # the paper's formula misses the load term: measurably off at these preloads (domain notes ~13 %)
        assert err_paper > 3 * err


@pytest.mark.parametrize("preset", ["paper_fine", "paper_knm_fine"])
def test_static_stiffness_with_the_fine_step(preset):
    """The 0.25 ms presets change the integration, not the statics: same 3 % bound, both preload signs."""
    for frac in (-0.8, 0.9):
        err, _ = stiffness_case(preset, (0.5, 0.4), frac)
        assert err < 0.03, f"{preset} lam={frac}: {err:.3%} from the complete analytic stiffness"


@pytest.mark.slow
@pytest.mark.parametrize("preset", PRESETS)
def test_static_stiffness_exhaustive(preset):
    p = load_params(preset)
    rom = p.range_of_motion
    postures = [(a, b) for a in np.linspace(rom.rud_min, rom.rud_max, 4) * 0.95
                for b in np.linspace(rom.fe_min, rom.fe_max, 4) * 0.95]
    for u in postures:
        for frac in (-0.95, -0.5, -0.1, 0.0, 0.1, 0.5, 0.95):
            err, _ = stiffness_case(preset, u, frac)
            assert err < 0.03, f"{preset} u={u} lam={frac}: {err:.3%}"


# --------------------------------------------------------------------------------------- dynamics
# Loop closure under 10 s of random targets at the largest preload (vswrist_gym.tools.sim_bench.random_reference_run).
# The opening is chaotic: the motion amplifies rounding, so the same seed on another CPU peaks elsewhere (seed 0
# of `paper_knm` read 8.7e-5 on the development machine and 1.005e-4 on another of the same kind; here it moves
# between 7.7e-5 and 1.13e-4 when the preload changes in its 14th digit), within the spread that new seeds give.
# So each bound is the worst over 20 seeds times MARGIN, never one run's value. Measured with
#   vswrist bench-sim --no-python --rounds 1 --seconds 1 --sweep --seeds 20
# (2026-12-02 04:18 UTC, this 2-core dev machine under load from other sessions), worst (median) of seeds 0-19:
#                       commanded <= 3 rad/s            reference jumps
#   paper      1 ms     6.10e-5 (4.26e-5)               1.11e-2 (2.56e-3)
#   paper_knm  1 ms     1.14e-4 (9.35e-5)               9.36e-3 (7.24e-4)
#   paper      0.25 ms  3.34e-6 (2.25e-6)               5.74e-4 (4.64e-5)
#   paper_knm  0.25 ms  5.65e-6 (4.14e-6)               4.57e-4 (4.18e-5)
# and, with --params paper_identified (04:40 UTC, same machine and load):
#   paper_identified 1 ms  9.05e-5 (6.09e-5)            7.27e-3 (5.10e-3)
# In commanded motion the medians grow as dt^2.0-2.5 from 0.25 to 1 ms, so a factor 2 is about what a step 1.4x
# longer adds. Issue 3's criterion, closure < 1e-4, is therefore not guaranteed at the default 1 ms (`paper_knm`:
# median seed 9.4e-5, worst 1.14e-4) nor under jumps at any step tried (a few seeds swing the wrist toward
# singular leg configurations); it holds with a margin of 17x in commanded motion at 0.25 ms, and is tested there.
MARGIN = 2.0
CLOSURE_WORST = {  # (preset, timestep s, mode) -> worst over seeds 0-19, from the sweep above
    ("paper", 1e-3, "commanded"): 6.10e-5, ("paper", 1e-3, "jumps"): 1.11e-2,
    ("paper_knm", 1e-3, "commanded"): 1.14e-4, ("paper_knm", 1e-3, "jumps"): 9.36e-3,
    ("paper_fine", 2.5e-4, "commanded"): 3.34e-6, ("paper_fine", 2.5e-4, "jumps"): 5.74e-4,
    ("paper_knm_fine", 2.5e-4, "commanded"): 5.65e-6, ("paper_knm_fine", 2.5e-4, "jumps"): 4.57e-4,
    ("paper_identified", 1e-3, "commanded"): 9.05e-5, ("paper_identified", 1e-3, "jumps"): 7.27e-3,
}


def closure_bound(preset, timestep, mode):
    return MARGIN * CLOSURE_WORST[preset, timestep, mode]


def _reference_run(preset, posture_rate):
    from vswrist_gym.tools.sim_bench import random_reference_run

    r = random_reference_run(load_params(preset), posture_rate, seed=0)
    assert r["torque"] <= 1.0 + 1e-12
    assert not r["warnings"]
    return r


@pytest.mark.parametrize("preset", PRESETS)
def test_loop_closes_through_ten_seconds_of_random_references_at_the_largest_preload(preset):
    """The commanded posture (RUD, FE and PS) moving at up to 3 rad/s toward random targets at the largest
    preload, gravity on: no warning or NaN, torques within limits, the welds within the measured worst x 2
    after every 1 ms substep."""
    assert _reference_run(preset, posture_rate=3.0)["closure"] < closure_bound(preset, 1e-3, "commanded")


@pytest.mark.parametrize("preset", PRESETS)
def test_reference_jumps_at_the_largest_preload_stay_finite(preset):
    """Reference jumps at the largest preload saturate the motors and swing the wrist hard, past its range toward
    singular leg configurations: no warning or NaN, torques within limits; the welds open far more than under
    commanded motion (docs/model.md), within the measured worst x 2."""
    assert _reference_run(preset, posture_rate=None)["closure"] < closure_bound(preset, 1e-3, "jumps")


@pytest.mark.parametrize("preset", ["paper_fine", "paper_knm_fine"])
def test_loop_closes_below_1e_4_in_commanded_motion_with_the_fine_step(preset):
    """Issue 3's criterion, closure < 1e-4 through 10 s of random references at the largest preload, where it
    holds with a margin: the 0.25 ms presets, the commanded posture moving at up to 3 rad/s (worst of 20 seeds
    17x below it)."""
    assert load_params(preset).simulation.timestep == pytest.approx(2.5e-4)
    closure = _reference_run(preset, posture_rate=3.0)["closure"]
    assert closure < closure_bound(preset, 2.5e-4, "commanded") < 1e-4


@pytest.mark.parametrize("preset", ["paper_fine", "paper_knm_fine"])
def test_reference_jumps_with_the_fine_step(preset):
    """Reference jumps with the 0.25 ms presets: the welds open about 20x less than at 1 ms (worst of 20 seeds),
    most seeds below 1e-4 but not all (docs/model.md); within the measured worst x 2, no warning, torques within
    limits."""
    assert _reference_run(preset, posture_rate=None)["closure"] < closure_bound(preset, 2.5e-4, "jumps")
def test_two_simulators_with_different_springs_in_one_process():
    """Stepped in turn (with a foreign model in between), each sim deflects under the same load as the
    analytic compliance of its own K predicts; the foreign model gets no spring forces."""
    u, lam = np.zeros(2), 0.0  # no preload: sigma_s = 2K/delta0, so the compliance scales with 1/K
    sims = [WristSim(no_gravity("paper", damping={"leg_joint": 3e-3})),
            WristSim(no_gravity("paper", damping={"leg_joint": 3e-3}, spring={"K": 0.012}))]
    foreign = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><body><joint type="hinge"/><geom size="0.1" mass="1"/></body></worldbody></mujoco>')
    foreign_data = mujoco.MjData(foreign)
    tau = np.array([0.0, 0.0, 1e-4])  # N m about Z_b, i.e. flexion/extension
    W = sims[0].kin.coupler_twist_jacobian(u)[:3]
    for sim in sims:
        sim.reset(u=u, lam=lam)
        sim.apply_wrench(torque=tau)
    for _ in range(1000):
        for sim in sims:
            sim.step(0.02)
            mujoco.mj_step(foreign, foreign_data)
    assert np.all(foreign_data.qfrc_passive == 0.0)
    moves = []
    for sim in sims:
        expected = np.linalg.solve(coupler_stiffness(u, lam, sim.params), W.T @ tau)
        moved = sim.posture()[:2] - u
        np.testing.assert_allclose(moved, expected, rtol=0.03, atol=1e-3 * np.abs(expected).max())
        moves.append(np.abs(moved).max())
    assert moves[0] == pytest.approx(3.0 * moves[1], rel=0.05)


def test_state_roundtrip_is_exact():
    sim = WristSim()
    sim.reset(u=(0.2, 0.1), lam=1.0)
    sim.set_motor_references(sim.motor_angles() + [0.1, -0.05, 0.02, 0.5])
    sim.apply_wrench(force=(0.0, 0.0, -1.0))
    sim.step(0.1)
    s = sim.get_state()
    sim.step(0.2)
    first = (sim.data.qpos.copy(), sim.posture())
    sim.set_state(s)
    sim.step(0.1)
    sim.posture()  # a lazy forward in between must not change the trajectory
    sim.step(0.1)
    np.testing.assert_array_equal(sim.data.qpos, first[0])
    np.testing.assert_array_equal(sim.posture(), first[1])


def test_tool_wrench_is_the_weight_it_holds_at_rest():
    m_tool = 0.2

    def scene(spec):
        g = spec.body("tool").add_geom()
        g.name = "tool_mass"
        g.type = mujoco.mjtGeom.mjGEOM_SPHERE
        g.size = [0.01, 0, 0]
        g.mass = m_tool

    p = load_params("paper_knm").replace(damping={"leg_joint": 0.5})
    sim = WristSim(p, scene_fn=scene)
    sim.reset()
    sim.step(3.0)
    assert np.abs(sim.posture_rate()).max() < 1e-4
    g = np.array(p.environment.gravity)
    # at rest the hand holds the tool against gravity: it pushes with -m g
    np.testing.assert_allclose(sim.tool_wrench()[:3], -m_tool * g, atol=1e-3)


def test_applied_wrench_is_held_and_bad_input_is_named():
    sim = WristSim()
    sim.apply_wrench(force=(1.0, 2.0, 3.0))
    sim.step(0.01)
    np.testing.assert_array_equal(sim.data.xfrc_applied[sim.hand_id], [1, 2, 3, 0, 0, 0])
    with pytest.raises(ValueError, match="multiple of the timestep"):
        sim.step(0.0005)
    with pytest.raises(ValueError, match="motor references"):
        sim.set_motor_references([0.0, 0.0, 0.0])
    with pytest.raises(RangeOfMotionError):
        sim.reset(u=(1.2, 0.0))
    with pytest.raises(ValueError, match="lam"):
        sim.reset(u=(0.0, 0.0), lam=1e3)


def test_posture_rate_is_the_derivative_of_the_posture():
    """Semi-implicit Euler moves the joints by h * (new velocity): (p(t+h) - p(t)) / h = rate(t+h) + O(h v^2)."""
    sim = WristSim(load_params("paper").replace(simulation={"timestep": 1e-4, "constraint_timeconst": 2e-4}))
    sim.reset(u=(0.3, -0.2), lam=1.0)
    sim.set_motor_references(sim.motor_angles() + [0.3, -0.2, 0.1, 1.0])
    sim.step(0.05)
    h = sim.timestep
    p0 = sim.posture()
    sim.step(h)
    rate = sim.posture_rate()
    np.testing.assert_allclose((sim.posture() - p0) / h, rate, rtol=1e-3, atol=1e-4)
    assert np.abs(rate[:2]).max() > 0.1


@pytest.mark.parametrize("preset", PRESETS)
def test_motor_step_response_respects_the_speed_limit_without_windup(preset):
    """A 2 rad step of the PS reference and 0.5 rad of motor A: the motors reach their references, never
    faster than the speed limit, with little overshoot although the torque saturates on the way."""
    p = load_params(preset)
    sim = WristSim(p)
    sim.reset(lam=0.5 * lambda_range(np.zeros(2), p)[1])
    theta = sim.motor_angles() + [0.5, 0.0, 0.0, 2.0]
    sim.set_motor_references(theta)
    fastest, overshoot, saturated = 0.0, 0.0, False
    for _ in range(100):
        sim.step(0.01)
        fastest = max(fastest, float(np.abs(sim.motor_velocities()).max()))
        overshoot = max(overshoot, sim.motor_angles()[3] - theta[3])
        saturated |= abs(sim.motor_torques()[3]) >= p.motor.ps_torque_limit - 1e-9
    assert saturated
    assert fastest <= p.motor.speed_limit * 1.01
    assert overshoot < 0.1
    np.testing.assert_allclose(sim.motor_angles()[[0, 3]], theta[[0, 3]], atol=1e-3)


def test_python_fallback_callbacks_match_the_compiled_ones():
    from vswrist_gym.model import native

    runs = []
    for backend in ("c", "python"):
        sim = WristSim(backend=backend)
        try:
            assert sim.model.nplugin == (5 if backend == "c" else 0)  # each really runs its own path
            sim.reset(u=(0.2, 0.3), lam=2.0)
            sim.set_motor_references(sim.motor_angles() + [0.2, -0.1, 0.3, 0.5])
            sim.step(0.1)
            runs.append(sim.data.qpos.copy())
        finally:
            native.install("c")
    np.testing.assert_allclose(runs[0], runs[1], atol=1e-9)



def test_divergence_raises_instead_of_silently_resetting(tmp_path, monkeypatch):
    """MuJoCo resets the state when it meets NaN or huge values; the simulator must say so."""
    from vswrist_gym.sim import SimulationError

    monkeypatch.chdir(tmp_path)  # MuJoCo's default warning handler writes MUJOCO_LOG.TXT into the cwd
    sim = WristSim()
    sim.reset(lam=1.0)
    sim.data.qvel[0] = 1e12  # beyond MuJoCo's mjMAXVAL: what a diverging integration produces
    with pytest.raises(SimulationError):
        sim.step(0.01)


def test_bench_sim_command_prints_the_overhead_ratio():
    """``vswrist bench-sim`` as a user runs it (small budget): one line per path, with the ratio to bare mj_step
    near 1 for the compiled plugin (the springs and motors add little to a substep) and well above it for
    the pure-Python loop."""
    # 2 s x 3 rounds (a few seconds of wall time): the best of rounds and the median of ~300 paired windows stay
    # put when other processes take the CPU for a while, where one 0.2 s round could be swamped
    out = subprocess.run([sys.executable, "-m", "vswrist_gym.cli", "bench-sim", "--params", "paper",
                          "--seconds", "2", "--rounds", "3"], capture_output=True, text=True, timeout=300,
                         check=True).stdout
    ratios = dict(re.findall(r"^\s+(full, C plugin \(default\)|Python loop, mj_step per substep)\s.*?ratio "
                             r"([0-9.]+)", out, flags=re.M))
    assert set(ratios) == {"full, C plugin (default)", "Python loop, mj_step per substep"}, out
    assert 0.8 < float(ratios["full, C plugin (default)"]) < float(ratios["Python loop, mj_step per substep"])


def test_reset_many_is_each_reset_alone_and_checks_before_it_changes_anything():
    """``WristSim.reset_many`` (a batch's worlds that reset together) puts each simulator where its own ``reset``
    would (to the bit on the dev machine; 1e-12 rad allowed, since another CPU's BLAS may round a stack of
    matrices differently from one, far below the 1e-9 the batch's equivalence test allows); a bad internal
    torque in one of them raises naming it and leaves every simulator as it was. Independent check: the springs
    then carry lam N (the spring law at the simulated deflections)."""
    p = WristSim().params  # the simulator's default parameters
    us = [(0.1, -0.2), (-0.3, 0.25), (0.0, 0.0)]
    pss = [0.2, -0.4, 0.0]
    lams = [0.4 * lambda_range(np.array(u), p)[1] for u in us]
    many = [WristSim() for _ in us]
    WristSim.reset_many(many, us, pss, lams)
    for s, u, ps, lam in zip(many, us, pss, lams):
        alone = WristSim()
        alone.reset(u=u, ps=ps, lam=lam)
        for field in ("qpos", "ctrl", "act", "qvel"):
            np.testing.assert_allclose(getattr(s.data, field), getattr(alone.data, field), rtol=0, atol=1e-12,
                                       err_msg=field)
    from vswrist_gym.kinematics import WristKinematics
    for s, u, lam in zip(many, us, lams):
        N = WristKinematics(p).internal_torque_basis(np.array(u))
        np.testing.assert_allclose(spring_torque(s.deflections(), p), lam * N, atol=1e-9)
    for s in many:  # away from the reset state, so that a reset half done would show
        s.step(0.01)
    before = [s.data.qpos.copy() for s in many]
    with pytest.raises(ValueError, match="lam = 1e\\+06 N m is outside"):
        WristSim.reset_many(many, us, pss, [lams[0], 1e6, lams[2]])
    for s, q in zip(many, before):
        np.testing.assert_array_equal(s.data.qpos, q)
