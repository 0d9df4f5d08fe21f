"""Kinematics against independent facts: FK/IK round trips, Euler angles, finite differences, home values."""

import numpy as np
import pytest

from conftest import random_postures
from vswrist_gym.kinematics import RangeOfMotionError, WristKinematics


def euler_zyx_angles(R):
    """ZYX Euler angles (alpha_z, alpha_y, alpha_x) of R, extracted independently of the package."""
    return (np.arctan2(R[1, 0], R[0, 0]), np.arctan2(-R[2, 0], np.hypot(R[0, 0], R[1, 0])),
            np.arctan2(R[2, 1], R[2, 2]))


def test_fk_ik_round_trip_10000_postures_all_legs(kin):
    worst = 0.0
    worst_between_legs = 0.0
    for u in random_postures(kin, 10_000, seed=1):
        T = kin.coupler_pose(u)
        frames = [kin.leg_forward(kin.leg_inverse(T, leg), leg) for leg in range(3)]
        worst = max(worst, max(np.abs(F - T).max() for F in frames))
        worst_between_legs = max(worst_between_legs, np.abs(frames[0] - frames[1]).max(),
                                 np.abs(frames[0] - frames[2]).max())
    assert worst < 1e-10
    assert worst_between_legs < 1e-10


def test_home_pose_matches_domain_notes(kin):
    T = kin.coupler_pose([0.0, 0.0])
    r = 2 * 0.049 * np.sin(np.pi / 8)
    np.testing.assert_allclose(T[:3, 3], [r, 0, 0], atol=1e-15)
    np.testing.assert_allclose(T[:3, :3], np.eye(3), atol=1e-15)
    for leg in range(3):
        np.testing.assert_allclose(kin.leg_inverse(T, leg), [np.pi / 8, np.pi / 2, 3 * np.pi / 2, -np.pi / 8],
                                   atol=1e-12)


def test_coupler_pose_euler_angles_and_posture(kin):
    r = 2 * kin.d * np.sin(kin.alpha / 2)
    for u in random_postures(kin, 500, seed=2):
        T = kin.coupler_pose(u)
        az, ay, ax = euler_zyx_angles(T[:3, :3])
        np.testing.assert_allclose([ay, az], u, atol=1e-12)
        np.testing.assert_allclose(kin.posture(T), u, atol=1e-12)
        # no twist: the rotation axis is perpendicular to X_b (antisymmetric part has no x component)
        assert abs(T[2, 1] - T[1, 2]) < 1e-12
        # O_c on the sphere of radius 2 d sin(alpha/2), on the bisector of X_b and X_c
        assert abs(np.linalg.norm(T[:3, 3]) - r) < 1e-12
        assert np.linalg.norm(np.cross(T[:3, 3], np.array([1.0, 0, 0]) + T[:3, 0])) < 1e-12


def test_paper_printed_q1_is_not_exact(kin):
    """The paper's q1 expression has |(x0, y0)|^2 as its second atan2 argument (domain notes)."""
    u = np.array([0.3, 0.4])
    T = kin.coupler_pose(u)
    x, y, z = T[:3, 3]
    ca, sa, d, eta = np.cos(kin.alpha), np.sin(kin.alpha), kin.d, 0.0
    q2 = np.arccos((y * np.sin(eta) - z * np.cos(eta)) / (d * sa))
    paper_q1 = np.arctan2(x * (1 - ca) + (y * np.cos(eta) + z * np.sin(eta)) * sa * np.sin(q2),
                          d * (1 - ca) * (2 - (1 + ca) * np.cos(q2) ** 2))
    exact = kin.leg_inverse(T, 0)
    assert abs(paper_q1 - exact[0]) > 1e-3
    assert np.abs(kin.leg_forward(exact, 0) - T).max() < 1e-12


def test_ik_jacobian_matches_central_differences(kin):
    h = 1e-6
    for u in random_postures(kin, 20, seed=3, margin=1e-3):
        J = kin.ik_jacobian(u)
        Jfd = np.column_stack([(kin.joint_angles(u + e) - kin.joint_angles(u - e)) / (2 * h) for e in np.eye(2) * h])
        assert np.abs(J - Jfd).max() <= 1e-6 * np.abs(Jfd).max()
        np.testing.assert_array_equal(kin.actuated_jacobian(u), J[[0, 4, 8]])


def test_internal_torque_basis_is_unit_null_vector(kin):
    for u in random_postures(kin, 200, seed=4):
        Ja = kin.actuated_jacobian(u)
        N = kin.internal_torque_basis(u)
        assert abs(np.linalg.norm(N) - 1) < 1e-12
        assert np.abs(Ja.T @ N).max() < 1e-12
        assert np.all(N < 0)  # the documented sign: all springs loaded the same way


def test_home_jacobian_and_null_space_values(kin):
    Ja = kin.actuated_jacobian([0.0, 0.0])
    s = np.sqrt(3) / 4
    np.testing.assert_allclose(Ja, [[0, 0.5], [-s, -0.25], [s, -0.25]], atol=1e-12)
    np.testing.assert_allclose(kin.internal_torque_basis([0.0, 0.0]), -np.ones(3) / np.sqrt(3), atol=1e-12)


def test_end_effector_pose_adds_ps_rotation_about_coupler_x(kin):
    u, ps = np.array([0.2, -0.3]), 0.7
    Tc, Te = kin.coupler_pose(u), kin.end_effector_pose(u, ps)
    np.testing.assert_allclose(Te[:3, 3], Tc[:3, 3])
    np.testing.assert_allclose(Te[:3, 0], Tc[:3, 0], atol=1e-15)  # the PS axis is the coupler X axis
    assert abs(Te[:3, 1] @ Tc[:3, 1] - np.cos(ps)) < 1e-12


def test_range_of_motion_is_enforced(kin):
    with pytest.raises(RangeOfMotionError, match="FE"):
        kin.coupler_pose([0.0, np.deg2rad(60)])
    with pytest.raises(RangeOfMotionError, match="outside the range of motion"):
        kin.ik_jacobian([np.deg2rad(-50), 0.0])
    T = kin.coupler_pose([0.0, np.deg2rad(60)], allow_outside=True)
    assert abs(kin.posture(T)[1] - np.deg2rad(60)) < 1e-12
    with pytest.raises(ValueError, match="finite"):
        kin.coupler_pose([np.nan, 0.0])


def test_legs_evenly_spaced_about_base_x():
    kin = WristKinematics("paper_knm")
    axes = [kin.leg_frames(np.zeros(4), leg)[0][:3, 2] for leg in range(3)]
    for a in axes:
        assert abs(a[0]) < 1e-15  # first axes perpendicular to X_b
    for i in range(3):
        assert abs(axes[i] @ axes[(i + 1) % 3] - np.cos(2 * np.pi / 3)) < 1e-12


def test_motor_side_angles_are_the_full_inverse_kinematics_q1():
    """The q1-only path gives exactly the q1 of the full leg inverse (same operations), and those reach the coupler
    through forward kinematics (an independent check of the values)."""
    from vswrist_gym.kinematics import WristKinematics

    kin = WristKinematics()
    rng = np.random.default_rng(7)
    lo, hi = kin.u_min, kin.u_max
    for _ in range(200):
        u = rng.uniform(lo, hi)
        q = kin.joint_angles(u)
        assert np.array_equal(kin.motor_side_angles(u), q[0::4])
        T = kin.coupler_pose(u)
        for leg in range(3):
            np.testing.assert_allclose(kin.leg_forward(q[4 * leg:4 * leg + 4], leg)[:3, 3], T[:3, 3], atol=1e-12)


def test_a_stack_of_postures_gives_each_postures_numbers(kin):
    """The kinematics takes leading axes (a batch's resets compute all their postures in one pass): each row of a
    stacked call is the single posture's result, to the bit on one machine (stacked matmul and solve make the
    same BLAS/LAPACK call per matrix); 1e-13 across machines (the values are of order 1: a few hundred ulps of room for
    a BLAS that rounds a stack differently). Independent check: the stacked basis is a unit
    null vector of each posture's J_a^T."""
    U = random_postures(kin, 40, seed=11)
    stacked = {"joint_angles": kin.joint_angles(U), "ik_jacobian": kin.ik_jacobian(U),
               "internal_torque_basis": kin.internal_torque_basis(U), "coupler_pose": kin.coupler_pose(U),
               "motor_side_angles": kin.motor_side_angles(U)}
    for name, many in stacked.items():
        one = np.array([getattr(kin, name)(u) for u in U])
        assert many.shape == one.shape, name
        np.testing.assert_allclose(many, one, rtol=0, atol=1e-13, err_msg=name)
    Ja = stacked["ik_jacobian"][:, 0::4, :]
    N = stacked["internal_torque_basis"]
    np.testing.assert_allclose(np.einsum("nk,nki->ni", N, Ja), 0.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(N, axis=1), 1.0, atol=1e-14)
    assert (N < 0).all()  # the sign convention, every posture of the range of motion
    # a bad row is named
    bad = U.copy()
    bad[7, 1] = 3.0
    with pytest.raises(RangeOfMotionError, match="posture 7"):
        kin.joint_angles(bad)
