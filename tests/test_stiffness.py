"""Springs and coupler stiffness against finite differences, the paper's formula and the domain notes."""

import numpy as np
import pytest

from conftest import random_postures
from vswrist_gym.kinematics import WristKinematics
from vswrist_gym.params import load_params
from vswrist_gym.stiffness import (closest_lambda, coupler_compliance, coupler_stiffness, lambda_range,
                                   max_leg_torque, motor_references, posture_terms, spring_deflection, spring_stiffness,
                                   spring_torque, stiffness_from_terms)


def test_spring_stiffness_is_derivative_of_torque(preset):
    delta = np.linspace(-1.5, 1.5, 61)
    h = 1e-7
    fd = -(spring_torque(delta + h, preset) - spring_torque(delta - h, preset)) / (2 * h)
    np.testing.assert_allclose(spring_stiffness(delta, preset), fd, rtol=1e-6)


def test_spring_law_is_the_papers(preset):
    p = load_params(preset).spring
    assert spring_torque(p.delta0, preset) == pytest.approx(-2 * p.K * np.sinh(1.0))
    assert spring_stiffness(0.0, preset) == pytest.approx(2 * p.K / p.delta0)


def test_spring_deflection_round_trips(preset):
    tau = np.linspace(-3.0, 3.0, 41)
    np.testing.assert_allclose(spring_torque(spring_deflection(tau, preset), preset), tau, rtol=1e-12, atol=1e-14)


def _wrench_fd(kin, u, theta, params, h=1e-6):
    """Finite-difference stiffness of w(u) = -J_a(u)^T tau_s(q1(u) - theta), J_a by differences of the IK too."""

    def Ja(u):
        return np.column_stack([(kin.joint_angles(u + e)[0::4] - kin.joint_angles(u - e)[0::4]) / (2e-6)
                                for e in np.eye(2) * 1e-6])

    def w(u):
        return -Ja(u).T @ spring_torque(kin.joint_angles(u)[0::4] - theta, params)

    return np.column_stack([(w(u + e) - w(u - e)) / (2 * h) for e in np.eye(2) * h]), w(u)


@pytest.mark.parametrize("frac", [-0.9, -0.3, 0.3, 0.9])
def test_complete_stiffness_equals_derivative_of_static_wrench(preset, frac):
    kin = WristKinematics(preset)
    for u in [np.array([0.0, 0.0]), np.array([0.4, -0.5]), np.array([-0.6, 0.7])]:
        lam = frac * lambda_range(u, preset)[1]
        theta = motor_references(u, lam, preset)
        S_fd, w0 = _wrench_fd(kin, u, theta, preset, h=1e-4)
        assert np.abs(w0).max() < 1e-6 * np.abs(S_fd).max()  # internal torque leaves the wrist balanced
        S = coupler_stiffness(u, lam, preset)
        assert np.linalg.norm(S - S_fd) <= 1e-4 * np.linalg.norm(S_fd)


def test_without_load_term_is_papers_formula(preset):
    kin = WristKinematics(preset)
    h = 1e-6
    for u in random_postures(kin, 5, seed=5):
        lam = 0.5 * lambda_range(u, preset)[1]
        Ja = np.column_stack([(kin.joint_angles(u + e)[0::4] - kin.joint_angles(u - e)[0::4]) / (2 * h)
                              for e in np.eye(2) * h])
        N = kin.internal_torque_basis(u)
        sigma = spring_stiffness(spring_deflection(lam * N, preset), preset)
        np.testing.assert_allclose(coupler_stiffness(u, lam, preset, include_load_term=False),
                                   Ja.T @ np.diag(sigma) @ Ja, rtol=1e-6)


def test_home_stiffness_is_0375_sigma_identity(preset):
    for lam in [0.0, 0.5 * lambda_range([0, 0], preset)[1]]:
        N = -np.ones(3) / np.sqrt(3)
        sigma = spring_stiffness(spring_deflection(lam * N[0], preset), preset)
        np.testing.assert_allclose(coupler_stiffness([0, 0], lam, preset, include_load_term=False),
                                   0.375 * sigma * np.eye(2), rtol=1e-9, atol=1e-12 * sigma)


def test_load_term_sign_and_size_at_paper_preset():
    """Domain notes: the load term is about 13 %, stiffening for positive lambda (our sign), softening otherwise."""
    for u in [np.zeros(2), np.array([0.3, 0.5])]:
        lam = 0.8 * lambda_range(u)[1]
        paper = coupler_stiffness(u, lam, include_load_term=False)
        for sign in (+1, -1):
            full = coupler_stiffness(u, sign * lam)
            ratio = np.trace(full) / np.trace(paper)
            assert sign * (ratio - 1) == pytest.approx(0.13, abs=0.03)
            assert np.all(np.linalg.eigvalsh(sign * (full - paper)) > 0)


def test_stiffness_positive_definite_and_grows_with_lambda(preset):
    kin = WristKinematics(preset)
    for u in random_postures(kin, 15, seed=6):
        lo, hi = lambda_range(u, preset)
        previous = None
        for lam in np.linspace(0.0, hi, 6):
            for include in (True, False):
                S = coupler_stiffness(u, lam, preset, include_load_term=include)
                np.testing.assert_allclose(S, S.T, atol=1e-12 * np.abs(S).max())
                assert np.all(np.linalg.eigvalsh(S) > 0)
            eig = np.linalg.eigvalsh(coupler_stiffness(u, lam, preset))
            if previous is not None:
                assert np.all(eig > previous)
            previous = eig
        assert np.all(np.linalg.eigvalsh(coupler_stiffness(u, lo, preset)) > 0)


def test_motor_references_load_springs_with_internal_torque(preset):
    kin = WristKinematics(preset)
    for u in random_postures(kin, 10, seed=7):
        lam = 0.7 * lambda_range(u, preset)[1]
        theta = motor_references(u, lam, preset)
        tau = spring_torque(kin.joint_angles(u)[0::4] - theta, preset)
        np.testing.assert_allclose(tau, lam * kin.internal_torque_basis(u), rtol=1e-9)
        assert np.abs(kin.actuated_jacobian(u).T @ tau).max() < 1e-9 * abs(lam)


def test_lambda_range_respects_torque_and_deflection_limits(preset):
    p = load_params(preset)
    kin = WristKinematics(preset)
    for u in random_postures(kin, 10, seed=8):
        lo, hi = lambda_range(u, preset)
        assert lo == -hi
        tau = hi * kin.internal_torque_basis(u)
        assert np.abs(tau).max() == pytest.approx(max_leg_torque(preset))
        assert np.abs(tau).max() <= p.motor.torque_limit * (1 + 1e-12)
        assert np.abs(spring_deflection(tau, preset)).max() <= p.spring.deflection_limit * (1 + 1e-12)
    assert lambda_range([0, 0], preset, margin=0.5)[1] == pytest.approx(0.5 * lambda_range([0, 0], preset)[1])


def test_closest_lambda_recovers_reachable_reference(preset):
    u = np.array([0.2, -0.1])
    hi = lambda_range(u, preset)[1]
    for lam in [-0.6 * hi, 0.05 * hi, 0.8 * hi]:
        assert closest_lambda(u, coupler_compliance(u, lam, preset), preset) == pytest.approx(lam, rel=1e-6, abs=1e-9)


def test_closest_lambda_matches_brute_force_for_unreachable_reference(preset):
    u = np.array([-0.3, 0.4])
    lo, hi = lambda_range(u, preset)
    C0 = coupler_compliance(u, 0.3 * hi, preset)
    c_ref = np.array([[C0[0, 0] * 3.0, 0.0], [0.0, C0[1, 1] * 0.4]])  # anisotropic: no lambda reaches it
    grid = np.linspace(lo, hi, 200_001)
    terms = posture_terms(u, preset)

    def G_of(x):
        return np.linalg.norm(np.linalg.inv(stiffness_from_terms(terms, x, preset)) - c_ref)

    G = [G_of(x) for x in grid[::100]]
    i = int(np.argmin(G)) * 100
    fine = grid[max(i - 100, 0): i + 101]
    G_fine = [G_of(x) for x in fine]
    brute = fine[int(np.argmin(G_fine))]
    best = closest_lambda(u, c_ref, preset)
    assert best == pytest.approx(brute, abs=2 * (grid[1] - grid[0]))
    assert np.linalg.norm(coupler_compliance(u, best, preset) - c_ref) <= min(G_fine) + 1e-12


def test_bad_compliance_reference_is_rejected():
    with pytest.raises(ValueError, match="compliance reference"):
        closest_lambda([0, 0], np.full((2, 2), np.nan))
