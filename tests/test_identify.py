"""The identification of the paper's unknown motor dynamics (vswrist_gym.identify) and its preset."""

import json
import math

import numpy as np
import pytest

pytest.importorskip("mujoco")

import test_control  # noqa: E402  (the closed-loop checks, reused for the identified preset)
import test_sim  # noqa: E402  (the simulator's validation checks, reused for the identified preset)

from vswrist_gym import identify as I  # noqa: E402
from vswrist_gym.params import load_params  # noqa: E402
from vswrist_gym.tools.reproduce import PAPER, implied_load_scenario  # noqa: E402

IDENTIFIED = "paper_identified"


def test_paper_precision_is_half_the_last_printed_digit():
    # the paper prints 0.15 rad, 0.007 rad, 0.07 N m, 1.72 N m
    assert I.paper_precision(0.15) == pytest.approx(0.005)
    assert I.paper_precision(0.007) == pytest.approx(0.0005)
    assert I.paper_precision(0.07) == pytest.approx(0.005)
    assert I.paper_precision(1.72) == pytest.approx(0.005)


@pytest.mark.parametrize("truth", [{"motor.time_constant": 0.008, "damping.leg_joint": 0.0025},
                                   {"motor.time_constant": 0.04, "damping.leg_joint": 0.012}])
def test_fit_recovers_known_parameters_from_synthetic_targets(truth):
    """Targets made by the simulator at a known set, the fit started from `paper`'s values (20 ms, 0.005):
    the fit must land on the known set. 1.5 s trials keep it cheap; the recovery holds to 1e-4 relative on
    this machine, 2 % is left for other CPUs (the trials are damped, not chaotic)."""
    base = load_params("paper")
    unknowns = [u for u in I.UNKNOWNS if u.name in truth]
    target = I.four_numbers(I.with_values(base, truth), 1.5)
    problem = I.Problem(base, unknowns, 1.5, target=target)
    result = I.fit(problem, problem.base_z(), prior_weight=0.0)
    found = problem.values(result["z"])
    for name, value in truth.items():
        assert found[name] == pytest.approx(value, rel=0.02), name


def test_speed_limit_is_not_seen_by_the_four_numbers():
    """The trial's motors turn far slower than any plausible speed limit, so the limit cannot be identified:
    the four numbers at its lower and upper bound are the same."""
    base = load_params("paper")
    unknown = next(u for u in I.UNKNOWNS if u.name == "motor.speed_limit")
    lo = I.four_numbers(I.with_values(base, {unknown.name: unknown.lo}), 1.5)
    hi = I.four_numbers(I.with_values(base, {unknown.name: unknown.hi}), 1.5)
    np.testing.assert_allclose(lo, hi, rtol=1e-9)


def test_kd_follows_kp_at_the_base_damping_ratio():
    base = load_params("paper")
    p = I.with_values(base, {"motor.kp": 4 * base.motor.kp})
    zeta = lambda m: m.kd / (2 * math.sqrt(m.kp * m.rotor_inertia))  # noqa: E731
    assert zeta(p.motor) == pytest.approx(zeta(base.motor), rel=1e-12)


def test_bad_target_and_bounds_are_named():
    with pytest.raises(ValueError, match="target"):
        I.Problem(load_params("paper"), I.UNKNOWNS, 1.5, target=[0.15, -0.007, 0.07, 1.72])
    with pytest.raises(ValueError, match="paper_knm"):
        I.identify("paper_knm", duration=1.5)
    bad = I.Unknown("motor", "kp", 10.0, 1.0, "")
    with pytest.raises(ValueError, match="motor.kp"):
        I.Problem(load_params("paper"), [bad], 1.5)


def test_identified_preset_changes_only_the_unknowns():
    """Everything the paper gives (and every other choice) is `paper`'s."""
    paper, ident = load_params("paper"), load_params(IDENTIFIED)
    unknown = {u.name for u in I.UNKNOWNS} | {"motor.kd"}
    for section in ("geometry", "range_of_motion", "spring", "motor", "inertia", "damping", "environment",
                    "control", "simulation"):
        a, b = getattr(paper, section), getattr(ident, section)
        for key in a.__dataclass_fields__:
            if f"{section}.{key}" not in unknown:
                assert getattr(a, key) == getattr(b, key), f"{section}.{key}"
    for u in I.UNKNOWNS:
        assert u.lo <= getattr(getattr(ident, u.section), u.key) <= u.hi, u.name


@pytest.fixture(scope="module")
def implied():
    return {name: implied_load_scenario(load_params(name), 4.0)[0] for name in ("paper", IDENTIFIED)}


def test_identified_preset_against_the_papers_numbers_under_the_implied_load(implied):
    """The issue's target, number by number: LS error and both torques within 1.5x of the paper's, both
    ratios >= 15 (measured 15.5 and 23.5: the trials are damped and deterministic, MuJoCo's cross-CPU
    differences move them by far less than the 3 % margin), and the HS error 1.5x below `paper`'s. The HS
    error itself is not within 1.5x (1.7x): see test_hs_error_floor_lies_outside_the_motor_parameters."""
    ours, today = implied[IDENTIFIED], implied["paper"]
    for key in ("rms_error_ls", "rms_torque_ls", "rms_torque_hs"):
        assert 1 / 1.5 <= ours[key] / PAPER[key] <= 1.5, key
    assert ours["error_ratio_ls_over_hs"] >= 15.0
    assert ours["torque_ratio_hs_over_ls"] >= 15.0
    assert ours["rms_error_hs"] < today["rms_error_hs"] / 1.4


def test_hs_error_floor_lies_outside_the_motor_parameters():
    """docs/reproduce.md: no motor makes the HS error reach 1.5x of the paper's 0.007 rad. With ideal motors
    (time constant one physics step, kp 1e5, beyond the plausible bounds) the HS error still exceeds 1.5 x
    0.007 = 0.0105 rad (measured 0.0111; 5 % margin), and the load alone, with the reference held, gives
    about the paper's number (stiffness x error is how the implied load was derived: 0.0064 rad measured)."""
    budget = I.hs_error_budget(load_params(IDENTIFIED), 4.0)
    assert budget["ideal_motors_T_one_step_kp_1e5"] > 1.5 * PAPER["rms_error_hs"]
    assert budget["load_alone_reference_held_at_centre"] == pytest.approx(PAPER["rms_error_hs"], rel=0.15)
    # the two parts add about in quadrature (tracking and load deflection are nearly uncorrelated)
    quad = math.hypot(budget["tracking_alone_no_load"], budget["load_alone_reference_held_at_centre"])
    assert budget["as_identified"] == pytest.approx(quad, rel=0.15)


# ---------------------------------------------- the simulator's validation checks on the identified preset
def test_springs_carry_the_preload_and_posture_holds():
    test_sim.test_springs_carry_the_preload_and_posture_holds(IDENTIFIED)


@pytest.mark.parametrize("u", test_sim.STIFFNESS_POSTURES)
def test_static_stiffness_matches_analytic_with_load_term(u):
    test_sim.test_static_stiffness_matches_analytic_with_load_term(IDENTIFIED, u)


def test_loop_closes_through_ten_seconds_of_random_references_at_the_largest_preload():
    test_sim.test_loop_closes_through_ten_seconds_of_random_references_at_the_largest_preload(IDENTIFIED)


def test_reference_jumps_at_the_largest_preload_stay_finite():
    test_sim.test_reference_jumps_at_the_largest_preload_stay_finite(IDENTIFIED)


def test_motor_step_response_respects_the_speed_limit_without_windup():
    """test_sim's step response (2 rad PS step, 0.5 rad on motor A), with the overshoot bound of a motor
    whose reference filter no longer slows it before the target: with a 2 ms low-pass the setpoint arrives
    at the speed limit, and a motor without windup then overshoots by at most its stopping distance at the
    torque limit, J v^2 / (2 tau_max), plus the setpoint's lead kd v / kp (0.21 + 0.02 rad for the PS motor;
    measured 0.18). The 20 ms filter of `paper` brakes earlier (< 0.1 rad, test_sim)."""
    p = load_params(IDENTIFIED)
    sim = test_sim.WristSim(p)
    sim.reset(lam=0.5 * test_sim.lambda_range(np.zeros(2), p)[1])
    theta = sim.motor_angles() + [0.5, 0.0, 0.0, 2.0]
    sim.set_motor_references(theta)
    fastest, overshoot = 0.0, 0.0
    for _ in range(100):
        sim.step(0.01)
        fastest = max(fastest, float(np.abs(sim.motor_velocities()).max()))
        overshoot = max(overshoot, sim.motor_angles()[3] - theta[3])
    m = p.motor
    scale = m.ps_torque_limit / m.torque_limit               # the PS motor: model/builder.py
    j_ps = m.rotor_inertia * scale + p.inertia.ps_inertia
    bound = j_ps * m.speed_limit ** 2 / (2 * m.ps_torque_limit) + m.kd * m.speed_limit / m.kp
    assert fastest <= m.speed_limit * 1.01
    assert overshoot < bound
    np.testing.assert_allclose(sim.motor_angles()[[0, 3]], theta[[0, 3]], atol=1e-3)


def test_closed_loop_holds_the_posture_at_each_stiffness_level():
    test_control.test_closed_loop_holds_the_posture_at_each_stiffness_level(IDENTIFIED)


def test_stiffness_measured_in_the_simulator_follows_the_commanded_lambda():
    test_control.test_stiffness_measured_in_the_simulator_follows_the_commanded_lambda(IDENTIFIED)


@pytest.mark.slow
def test_identify_command_writes_a_consistent_result(tmp_path):
    """The whole identification (1.5 s trials): the chosen set fits within the paper's precision of the best
    fit and lies inside the bounds; the speed limit is not seen."""
    assert I.main(["--out", str(tmp_path), "--quick"]) == 0
    res = json.loads((tmp_path / "identify.json").read_text())
    for key in I.KEYS:
        assert abs(res["identified"]["numbers"][key] - res["best"]["numbers"][key]) \
            <= 1.02 * res["paper_precision"][key] + 1e-12, key
    for u in res["unknowns"]:
        assert u["lo"] <= res["identified"]["values"][u["name"]] <= u["hi"]
    assert abs(res["elasticity"]["rms_error_hs"]["motor.speed_limit"]) < 1e-6
