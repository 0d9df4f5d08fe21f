"""Exact kinematics of the VS-Wrist parallel mechanism (NumPy only).

Frames and conventions (paper section 3, domain notes):

* Base frame S_b: X_b along the forearm (the pronation/supination axis); legs A, B, C (index 0, 1, 2)
  have their first joint axes rotated about X_b by eta = 0, 2pi/3, 4pi/3.
* Each leg is a standard Denavit-Hartenberg chain, ``T = Rz(theta) Tz(d) Rx(alpha) Tx(a)`` per row:
  ``T_b^c = Rx(eta) [Rz(q1) Rx(pi/2)] [Rz(q2) Tz(d) Rx(-alpha)] [Rz(q3) Tz(-d) Rx(pi/2)] [Rz(q4) Rx(pi - eta)]``.
* Posture ``u = (alpha_y, alpha_z)`` = (radial/ulnar deviation, flexion/extension), the Y and Z angles of
  the ZYX Euler decomposition ``R = Rz(alpha_z) Ry(alpha_y) Rx(alpha_x)`` of the coupler rotation. The
  third angle alpha_x is not free: the coupler rotation is a rotation about an axis perpendicular to X_b
  (no twist), which fixes ``alpha_x = atan2(sin az sin ay, cos ay + cos az)``.
* The coupler centre O_c lies on a sphere of radius ``r = 2 d sin(alpha / 2)`` about O_b, along the
  bisector of X_b and the coupler's X axis: ``O_c = r (x_b + x_c) / |x_b + x_c|``.
* End effector: ``T_b^e = T_b^c Rx(theta_PS)``.

All lengths in metres, angles in radians.
"""

from __future__ import annotations

import numpy as np

from .params import WristParams, load_params

LEG_NAMES = ("A", "B", "C")


class RangeOfMotionError(ValueError):
    """A posture outside the device's range of motion was given without ``allow_outside=True``."""


# Every function below takes leading batch axes (angles of shape S give matrices of shape S + (3, 3)), so that
# many postures (the worlds of a batch that reset together) cost one pass of NumPy calls; a single posture is the
# batch of shape (). Stacked matmul and solve run the same BLAS/LAPACK call per matrix as a single one, so each
# posture's numbers do not depend on the batch it came in (``tests/test_kinematics.py`` checks).
def _rot(a, i: int, j: int, sign: float) -> np.ndarray:
    """Rotation of angle(s) a in the (i, j) plane: R[i, i] = R[j, j] = cos a, R[j, i] = sign sin a."""
    if isinstance(a, (float, int, np.floating)) or (isinstance(a, np.ndarray) and a.ndim == 0):
        # one angle (most calls): a literal, three times faster than the fills below
        c, s = float(np.cos(a)), float(np.sin(a))
        R = [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]
        R[3 - i - j][3 - i - j] = 1.0
        R[i][i] = R[j][j] = c
        R[j][i] = sign * s
        R[i][j] = -sign * s
        return np.array(R)
    a = np.asarray(a, dtype=float)
    c, s = np.cos(a), np.sin(a)
    R = np.zeros(a.shape + (3, 3))
    R[..., 3 - i - j, 3 - i - j] = 1.0
    R[..., i, i] = c
    R[..., j, j] = c
    R[..., j, i] = sign * s
    R[..., i, j] = -sign * s
    return R


def rot_x(a) -> np.ndarray:
    return _rot(a, 1, 2, 1.0)


def rot_y(a) -> np.ndarray:
    return _rot(a, 2, 0, 1.0)


def rot_z(a) -> np.ndarray:
    return _rot(a, 0, 1, 1.0)


def _mv(A: np.ndarray, x: np.ndarray) -> np.ndarray:
    """A @ x of stacked matrices (..., n, m) and vectors (..., m) (the same numbers as one by one)."""
    if A.ndim == 2 and x.ndim == 1:
        return A @ x
    return np.matmul(A, x[..., None])[..., 0]


def dh(theta, d: float, alpha: float, a: float = 0.0) -> np.ndarray:
    """Standard DH transform Rz(theta) Tz(d) Rx(alpha) Tx(a), 4x4 (per theta)."""
    Rz = rot_z(theta)
    return homogeneous(Rz @ rot_x(alpha), _mv(Rz, np.array([a, 0.0, d])))


def homogeneous(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    T = np.zeros(np.broadcast_shapes(R.shape[:-2], p.shape[:-1]) + (4, 4))
    T[..., 3, 3] = 1.0
    T[..., :3, :3] = R
    T[..., :3, 3] = p
    return T


def _wrap(a: np.ndarray | float) -> np.ndarray | float:
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


class WristKinematics:
    """Forward/inverse kinematics and Jacobians of the 2-DoF parallel mechanism plus the PS axis."""

    def __init__(self, params: WristParams | str | None = None):
        self.params = load_params(params)
        g = self.params.geometry
        self.d = g.d
        self.alpha = g.alpha
        self.eta = np.asarray(g.eta, dtype=float)
        self.radius = 2.0 * g.d * np.sin(g.alpha / 2.0)
        rom = self.params.range_of_motion
        self.u_min = np.array([rom.rud_min, rom.fe_min])
        self.u_max = np.array([rom.rud_max, rom.fe_max])

    # ------------------------------------------------------------------ legs
    def leg_frames(self, q: np.ndarray, leg: int) -> list[np.ndarray]:
        """Base-frame transforms of the DH frames S_0, S_1, S_2, S_3, S_c of one leg (5 x 4x4; q (..., 4))."""
        q = np.asarray(q, dtype=float)
        eta = self.eta[leg]
        links = (
            dh(0.0, 0.0, eta),
            dh(q[..., 0], 0.0, np.pi / 2),
            dh(q[..., 1], self.d, -self.alpha),
            dh(q[..., 2], -self.d, np.pi / 2),
            dh(q[..., 3], 0.0, np.pi - eta),
        )
        frames, T = [], np.eye(4)
        for link in links:
            T = T @ link
            frames.append(T)
        return frames

    def leg_forward(self, q: np.ndarray, leg: int) -> np.ndarray:
        """Coupler frame T_b^c (4x4) reached by leg ``leg`` (0, 1, 2 = A, B, C) at joints q (4,)."""
        return self.leg_frames(q, leg)[-1]

    def leg_inverse(self, T: np.ndarray, leg: int) -> np.ndarray:
        """Exact joint angles (q1, q2, q3, q4) of one leg that reach the coupler frame T (4x4).

        q2 in [0, pi] is the paper's acos branch (the working mode of the device). q1 is derived from
        the position equations: in S_0, (x0, y0) = Rot(q1) (b, -a) with a = d (1 - cos alpha) and
        b = d sin(alpha) sin(q2), so q1 = atan2(a x0 + b y0, b x0 - a y0). (The paper's printed second
        atan2 argument is |(x0, y0)|^2 instead, which is not exact.) q3 and q4 come from the rotation
        R_2^c = Rz(q3) Rx(pi/2) Rz(q4) Rx(pi - eta); q3 is taken on the branch nearest q2 + pi.
        """
        T = np.asarray(T, dtype=float)
        eta = self.eta[leg]
        q1, q2 = self._leg_q1_q2(T, eta)
        R02 = rot_z(q1) @ rot_x(np.pi / 2) @ rot_z(q2) @ rot_x(-self.alpha)
        M = np.swapaxes(R02, -1, -2) @ rot_x(eta).T @ T[..., :3, :3] @ rot_x(np.pi - eta).T  # = Rz(q3) Rx(pi/2) Rz(q4)
        q3 = np.arctan2(M[..., 0, 2], -M[..., 1, 2])
        q3 = q2 + np.pi + _wrap(q3 - q2 - np.pi)
        q4 = np.arctan2(M[..., 2, 0], M[..., 2, 1])
        return np.stack([q1, q2, q3, q4], axis=-1)

    def _leg_q1_q2(self, T: np.ndarray, eta: float):
        """q1 and q2 of ``leg_inverse`` (the position equations; see there)."""
        p0 = _mv(rot_x(eta).T, T[..., :3, 3])
        sa, ca = np.sin(self.alpha), np.cos(self.alpha)
        c2 = np.clip(-p0[..., 2] / (self.d * sa), -1.0, 1.0)
        q2 = np.arccos(c2)
        a = self.d * (1.0 - ca)
        b = self.d * sa * np.sin(q2)
        x0, y0 = p0[..., 0], p0[..., 1]
        return np.arctan2(a * x0 + b * y0, b * x0 - a * y0), q2

    # --------------------------------------------------------------- posture
    def check_posture(self, u: np.ndarray, allow_outside: bool = False) -> np.ndarray:
        """u as a float array (2,), checked finite and in the range of motion (unless ``allow_outside``); a
        stack of postures (..., 2) is checked row by row, the error naming the first bad row."""
        u = np.asarray(u, dtype=float)
        if u.ndim > 1 and u.shape[-1] == 2:
            for k, row in enumerate(u.reshape(-1, 2)):
                try:
                    self.check_posture(row, allow_outside)
                except ValueError as exc:
                    raise type(exc)(f"posture {k} of {u.shape[:-1]}: {exc}") from None
            return u
        if u.shape != (2,):
            raise ValueError(f"posture u must have shape (2,) = (alpha_y RUD, alpha_z FE) in rad, got {u.shape}")
        if not np.all(np.isfinite(u)):
            raise ValueError(f"posture u must be finite, got {u}")
        if not allow_outside and (np.any(u < self.u_min - 1e-12) or np.any(u > self.u_max + 1e-12)):
            raise RangeOfMotionError(
                f"posture u = (RUD {u[0]:.4f}, FE {u[1]:.4f}) rad is outside the range of motion "
                f"RUD [{self.u_min[0]:.4f}, {self.u_max[0]:.4f}], FE [{self.u_min[1]:.4f}, {self.u_max[1]:.4f}] rad; "
                f"pass allow_outside=True to evaluate it anyway")
        if np.any(np.abs(u) >= np.pi / 2):
            raise RangeOfMotionError(f"posture u = {u} rad: |alpha| must stay below pi/2 (hemisphere)")
        return u

    @staticmethod
    def twist_angle(u: np.ndarray):
        """alpha_x of the ZYX Euler angles: the value that makes the rotation axis perpendicular to X_b."""
        u = np.asarray(u, dtype=float)
        ay, az = u[..., 0], u[..., 1]
        return np.arctan2(np.sin(az) * np.sin(ay), np.cos(ay) + np.cos(az))

    @staticmethod
    def euler_zyx(az: float, ay: float, ax: float) -> np.ndarray:
        return rot_z(az) @ rot_y(ay) @ rot_x(ax)

    def coupler_rotation(self, u: np.ndarray) -> np.ndarray:
        u = np.asarray(u, dtype=float)
        return self.euler_zyx(u[..., 1], u[..., 0], self.twist_angle(u))

    def coupler_pose(self, u: np.ndarray, allow_outside: bool = False) -> np.ndarray:
        """Coupler frame T_b^c (4x4) for posture u = (alpha_y RUD, alpha_z FE): the paper's x = f(u)."""
        u = self.check_posture(u, allow_outside)
        R = self.coupler_rotation(u)
        m = np.array([1.0, 0.0, 0.0]) + R[..., :, 0]
        return homogeneous(R, self.radius * m / np.linalg.norm(m, axis=-1, keepdims=True))

    @staticmethod
    def posture(T: np.ndarray) -> np.ndarray:
        """Posture u = (alpha_y, alpha_z) from a coupler frame (ZYX Euler angles of its rotation)."""
        R = np.asarray(T, dtype=float)[:3, :3]
        ay = np.arcsin(np.clip(-R[2, 0], -1.0, 1.0))
        az = np.arctan2(R[1, 0], R[0, 0])
        return np.array([ay, az])

    def joint_angles(self, u: np.ndarray, allow_outside: bool = False) -> np.ndarray:
        """All 12 leg joint angles Q = [q_A, q_B, q_C] at posture u."""
        T = self.coupler_pose(u, allow_outside)
        return np.concatenate([self.leg_inverse(T, leg) for leg in range(3)], axis=-1)

    def motor_side_angles(self, u: np.ndarray, allow_outside: bool = False) -> np.ndarray:
        """The three legs' first joint angles (q1 of A, B, C: the motor side of the springs) at posture u: the
        same values as ``joint_angles(u)[0::4]`` by the same operations, without solving q3 and q4."""
        T = self.coupler_pose(u, allow_outside)
        return np.stack([self._leg_q1_q2(T, self.eta[leg])[0] for leg in range(3)], axis=-1)

    def end_effector_pose(self, u: np.ndarray, ps: float, allow_outside: bool = False) -> np.ndarray:
        """End-effector frame T_b^e = T_b^c Rx(theta_PS) (4x4)."""
        T = self.coupler_pose(u, allow_outside).copy()
        T[:3, :3] = T[:3, :3] @ rot_x(ps)
        return T

    # ------------------------------------------------------------ Jacobians
    def coupler_twist_jacobian(self, u: np.ndarray) -> np.ndarray:
        """(6, 2) map from du to the coupler twist (omega; v of O_c), base frame, analytic."""
        u = np.asarray(u, dtype=float)
        ay, az = u[..., 0], u[..., 1]
        ax = self.twist_angle(u)
        # alpha_x = atan2(N, D): its partial derivatives
        N, D = np.sin(az) * np.sin(ay), np.cos(ay) + np.cos(az)
        dN = np.stack([np.sin(az) * np.cos(ay), np.cos(az) * np.sin(ay)], axis=-1)
        dD = np.stack([-np.sin(ay), -np.sin(az)], axis=-1)
        dax = (D[..., None] * dN - N[..., None] * dD) / (N * N + D * D)[..., None]
        # angular velocity of Rz(az) Ry(ay) Rx(ax): az' e_z + ay' Rz e_y + ax' Rz Ry e_x
        e_z = np.array([0.0, 0.0, 1.0])
        w_ay = _mv(rot_z(az), np.array([0.0, 1.0, 0.0]))
        w_ax = _mv(rot_z(az) @ rot_y(ay), np.array([1.0, 0.0, 0.0]))
        W = np.stack([w_ay + w_ax * dax[..., 0:1], e_z + w_ax * dax[..., 1:2]], axis=-1)
        # O_c = r m / |m|, m = e_x + R e_x; dm = omega x (R e_x)
        R = self.euler_zyx(az, ay, ax)
        m = np.array([1.0, 0.0, 0.0]) + R[..., :, 0]
        nm = np.linalg.norm(m, axis=-1, keepdims=True)
        n = m / nm
        dm = np.swapaxes(np.cross(np.swapaxes(W, -1, -2), R[..., None, :, 0]), -1, -2)
        V = self.radius * (np.eye(3) - n[..., :, None] * n[..., None, :]) @ dm / nm[..., None]
        return np.concatenate([W, V], axis=-2)

    def leg_geometric_jacobian(self, q: np.ndarray, leg: int) -> np.ndarray:
        """(6, 4) geometric Jacobian of one leg at O_c: columns (z_i; z_i x (O_c - o_i)), base frame."""
        frames = self.leg_frames(q, leg)
        p = frames[-1][..., :3, 3]
        J = np.empty(p.shape[:-1] + (6, 4))
        for i in range(4):
            J[..., :3, i] = frames[i][..., :3, 2]
        O = np.stack([np.broadcast_to(frames[i][..., :3, 3], p.shape) for i in range(4)], axis=-1)
        J[..., 3:, :] = np.cross(J[..., :3, :], p[..., :, None] - O, axis=-2)  # the four columns at once
        return J

    def ik_jacobian(self, u: np.ndarray, allow_outside: bool = False) -> np.ndarray:
        """J_IK (12, 2): dQ = J_IK du, rows leg A q1..q4, leg B, leg C (paper eq. diff_kin).

        Exact up to rounding: each leg's joint rates solve its geometric Jacobian against the coupler
        twist that du produces.
        """
        u = self.check_posture(u, allow_outside)
        X = self.coupler_twist_jacobian(u)
        T = self.coupler_pose(u, allow_outside=True)
        blocks = []
        for leg in range(3):
            Jl = self.leg_geometric_jacobian(self.leg_inverse(T, leg), leg)
            JlT = np.swapaxes(Jl, -1, -2)
            blocks.append(np.linalg.solve(JlT @ Jl, JlT @ X))
        return np.concatenate(blocks, axis=-2)

    def actuated_jacobian(self, u: np.ndarray, allow_outside: bool = False) -> np.ndarray:
        """J_a (3, 2): rows 1, 5, 9 of J_IK, the first (actuated) joint of legs A, B, C."""
        return self.ik_jacobian(u, allow_outside)[..., 0::4, :]

    def internal_torque_basis(self, u: np.ndarray, allow_outside: bool = False) -> np.ndarray:
        """N (3,): unit basis of ker(J_a^T), the actuated torques that load the springs without moving u.

        Sign convention: the components of N are negative (at home N = -(1, 1, 1)/sqrt(3)), so that a
        positive internal torque lambda (spring torques tau_s = lambda N on the legs) stiffens the
        wrist beyond the paper's J_a^T Sigma_s J_a (see ``stiffness.coupler_stiffness``).
        """
        Ja = self.actuated_jacobian(u, allow_outside)
        n = np.cross(Ja[..., :, 0], Ja[..., :, 1])
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        return np.where(n.sum(axis=-1, keepdims=True) > 0, -n, n)

    def actuated_hessian(self, u: np.ndarray, h: float = 1e-5, allow_outside: bool = False) -> np.ndarray:
        """d(J_a)/du (3, 2, 2): [k, i, j] = d^2 q1_k / du_i du_j, by central differences of the exact J_a.

        Truncation error O(h^2) ~ 1e-10 relative; used only for the load term of the static stiffness.
        """
        u = self.check_posture(u, allow_outside)
        H = np.empty((3, 2, 2))
        for j in range(2):
            e = np.zeros(2)
            e[j] = h
            H[:, :, j] = (self.actuated_jacobian(u + e, True) - self.actuated_jacobian(u - e, True)) / (2 * h)
        return 0.5 * (H + H.transpose(0, 2, 1))
