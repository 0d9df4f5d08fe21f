"""The paper's controller (section 4): exact inverse kinematics for the posture, internal torque for the stiffness.

Given a posture reference u_r = (RUD, FE) and the PS reference, the controller commands the four motors

    theta_k = q1_k(u_r) + delta0 asinh(tau_k / 2K),   tau = lam N(u_r)  (+ tau_g with gravity compensation)
    theta_PS = PS reference

so that at u_r each sinh spring exerts exactly tau_k on its leg: the internal torque lam N lies in
ker(J_a^T), loads the springs without moving the coupler, and sets the stiffness. The internal torque is
either commanded directly (``lam``) or found by the paper's Levenberg-Marquardt dynamics
d(lam)/dt = -alpha H/(H^2 + nu) G that drive the coupler compliance towards a reference c_r
(G = ||C(lam) - c_r||_F, H = dG/dlam).

Speed: the posture path is closed-form scalar math. q1 of each leg depends only on the coupler centre
O_c(u) = r m/|m|, m = x_b + x_c(u), through q1 = atan2(a x0 + b y0, b x0 - a y0) in the leg's frame S_0
(``WristKinematics.leg_inverse``); J_a = (dq1/dO_c)(dO_c/du) follows from the gradient of that atan2, and N
is the normalised cross product of the J_a columns (sign as ``WristKinematics.internal_torque_basis``).
It is an independent derivation of what ``kinematics`` computes with least squares, and is tested against it.
"""

from __future__ import annotations

import math

import numpy as np

from .params import WristParams, load_params
from .stiffness import SpringLaw, max_leg_torque, spring_deflection, spring_stiffness_at_torque

_HESSIAN_STEP = 1e-5  # rad; central differences of the closed-form J_a (error ~1e-10 relative)


def _finite_vector(name: str, value, n: int) -> tuple[float, ...]:
    """Validate a reference: ``n`` finite numbers, else a ValueError that names the argument."""
    if type(value) is np.ndarray and value.shape == (n,) and value.dtype == np.float64:
        # hot path (the environments pass float64 arrays): no conversions; x - x is 0 only for finite x
        out = tuple(value.tolist())
        if all(x - x == 0.0 for x in out):
            return out
    try:
        arr = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be {n} finite numbers, got {value!r}") from exc
    if arr.shape != (n,):
        raise ValueError(f"{name} must have {n} elements, got shape {np.shape(value)}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {arr.tolist()}")
    return tuple(float(x) for x in arr)


def _coupler_terms(ay, az, r, cos, sin, sqrt):
    """The coupler centre O_c = r m/|m| (m = x_b + x_c(u)) at u = (RUD, FE) = (ay, az), its derivatives dO_c/du
    and the coupler axis' dx_c/du (each 2 columns of 3). Element-wise: ``math`` functions on floats (one
    posture), NumPy's on (N,) arrays (a batch), the same operations either way."""
    cy, sy, cz, sz = cos(ay), sin(ay), cos(az), sin(az)
    mx, my, mz = 1.0 + cz * cy, sz * cy, -sy
    nm = sqrt(mx * mx + my * my + mz * mz)
    nx, ny, nz = mx / nm, my / nm, mz / nm
    px, py, pz = r * nx, r * ny, r * nz
    ax_, ay_, az_ = -cz * sy, -sz * sy, -cy          # dx_c/d(RUD)
    bx_, by_, bz_ = -sz * cy, cz * cy, 0.0           # dx_c/d(FE)
    f = r / nm
    proj = nx * ax_ + ny * ay_ + nz * az_
    d0x, d0y, d0z = f * (ax_ - nx * proj), f * (ay_ - ny * proj), f * (az_ - nz * proj)
    proj = nx * bx_ + ny * by_ + nz * bz_
    d1x, d1y, d1z = f * (bx_ - nx * proj), f * (by_ - ny * proj), f * (bz_ - nz * proj)
    return (px, py, pz), ((d0x, d0y, d0z), (d1x, d1y, d1z)), ((ax_, ay_, az_), (bx_, by_, bz_))


def _leg_terms(P, dOc, ce, se, a, s2, sqrt, maximum):
    """For a leg at angle eta (ce, se = cos, sin eta): the atan2 arguments (Y, X) of its q1 and its row of J_a
    (dq1/dRUD, dq1/dFE), from O_c = P and dO_c/du (see the module docstring). Element-wise like
    ``_coupler_terms``; with (3, 1) arrays ce, se and (N,) arrays it gives the three legs of N postures."""
    px, py, pz = P
    (d0x, d0y, d0z), (d1x, d1y, d1z) = dOc
    y0, z0 = ce * py + se * pz, -se * py + ce * pz
    b = sqrt(maximum(s2 - z0 * z0, 1e-300))
    Y, X = a * px + b * y0, b * px - a * y0
    R2 = X * X + Y * Y
    gx, gy = (X * a - Y * b) / R2, (X * b + Y * a) / R2
    gz = (X * y0 - Y * px) * (-z0 / b) / R2
    return (Y, X, gx * d0x + gy * (ce * d0y + se * d0z) + gz * (-se * d0y + ce * d0z),
            gx * d1x + gy * (ce * d1y + se * d1z) + gz * (-se * d1y + ce * d1z))


class AnalyticController:
    """The paper's posture + stiffness controller: posture reference (RUD, FE, PS) -> four motor references.

    ``params``: preset name, YAML path or ``WristParams`` (default preset). ``dt``: control period (s), the
    integration step of the LM dynamics. ``include_load_term``: stiffness (for the LM dynamics and
    :meth:`stiffness`) is the complete static stiffness with the load term (default) or the paper's
    J_a^T Sigma_s J_a (False). ``gravity_compensation``: add the spring torques tau_g (minimum norm,
    J_a^T tau_g = dV_g/du) that hold the weight of the hand (point mass at ``inertia.hand_offset``) and the
    coupler at the reference posture under ``environment.gravity``; legs and PS unit are ignored (small),
    loads unknown to the controller are not compensated. Off by default, as in the paper. ``payload``: further
    point masses on the PS axis that the compensation holds too, as (mass kg, distance m from the coupler centre
    along the coupler X axis) pairs: parts whose weight the controller knows, e.g. the PS flange and a task's tool
    at its nominal mass (a mass on the PS axis loads RUD/FE the same at every PS angle).

    Posture references outside the range of motion are clipped to it (RUD, FE and PS limits of
    ``range_of_motion``); lam is clipped to :meth:`lambda_range`, so no spring is asked for more than the
    motor torque limit or the deflection limit allows.
    """

    def __init__(self, params: WristParams | str | None = None, dt: float = 0.02, include_load_term: bool = True,
                 gravity_compensation: bool = False, payload=()):
        self.params = p = load_params(params)
        if isinstance(dt, bool) or not isinstance(dt, (int, float)) or not math.isfinite(dt) or dt <= 0:
            raise ValueError(f"dt (control period) must be a finite number of seconds > 0, got {dt!r}")
        self.dt = float(dt)
        self.include_load_term = bool(include_load_term)
        self.gravity_compensation = bool(gravity_compensation)
        g = p.geometry
        sa, ca = math.sin(g.alpha), math.cos(g.alpha)
        self._r = 2.0 * g.d * math.sin(g.alpha / 2.0)           # radius of the sphere of O_c
        self._a = g.d * (1.0 - ca)                                # leg_inverse's a
        self._s = g.d * sa                                        # b = sqrt(s^2 - z0^2) = d sin(alpha) sin(q2)
        self._legs = tuple((math.cos(e), math.sin(e)) for e in g.eta)
        self._legs_ce = np.array([[c] for c, _ in self._legs])
        self._legs_se = np.array([[s] for _, s in self._legs])
        self._K, self._delta0 = p.spring.K, p.spring.delta0
        self._law = SpringLaw(p.spring.K, p.spring.delta0)  # the spring law's constants, looked up once
        self._tau_max = max_leg_torque(p)
        rom = p.range_of_motion
        self._limits = ((rom.rud_min, rom.rud_max), (rom.fe_min, rom.fe_max), (rom.ps_min, rom.ps_max))
        self._alpha, self._nu = p.control.lm_alpha, p.control.lm_nu
        self._masses = (p.inertia.hand_mass, p.inertia.coupler_mass)
        self._hand_offset = p.inertia.hand_offset
        self.payload = tuple((float(m), float(x)) for m, x in payload)
        if not all(math.isfinite(m) and m >= 0.0 and math.isfinite(x) for m, x in self.payload):
            raise ValueError(f"payload must be (mass >= 0 kg, distance m) pairs of finite numbers, got {payload!r}")
        # the weight's generalised load is linear in (total mass, first moment along x_c): the payload adds to both
        # (with no payload these are the hand's and the coupler's terms alone, bit for bit)
        m_hand, m_coupler = self._masses
        self._mo, self._ml = m_hand + m_coupler, m_hand * self._hand_offset
        for m, x in self.payload:
            self._mo, self._ml = self._mo + m, self._ml + m * x
        self._gravity = tuple(p.environment.gravity)
        self._terms_key: tuple[float, float] | None = None
        self._terms = None
        # the command: the last clipped posture reference (RUD, FE, PS; rad) and internal torque (N m), in arrays
        # that an environment may hold for it (``bind``)
        self._ref = np.zeros(3)
        self._lam = np.zeros(1)
        self.reset()

    # ------------------------------------------------------------------ state
    def bind(self, reference: np.ndarray, lam: np.ndarray) -> None:
        """Keep the command in these arrays from now on, carrying the current one into them: ``reference`` (3,)
        the clipped posture reference (RUD, FE, PS; rad), ``lam`` (1,) the internal torque (N m). An environment
        passes its row of the episode state, so that a batch writes every world's command in one array operation
        (``step_batch``) and each world's controller goes on from it."""
        reference[:] = self._ref
        lam[:] = self._lam
        self._ref, self._lam = reference, lam

    @property
    def lam(self) -> float:
        """The internal torque commanded last (N m)."""
        return self._lam.item(0)

    @lam.setter
    def lam(self, value: float) -> None:
        self._lam[0] = value

    @property
    def _u(self) -> tuple[float, float]:
        """The last clipped posture reference (RUD, FE), rad."""
        ref = self._ref
        return ref.item(0), ref.item(1)

    def reset(self, posture=(0.0, 0.0, 0.0), lam: float = 0.0) -> np.ndarray:
        """Start at ``posture`` (RUD, FE, PS) rad with internal torque ``lam`` (N m, clipped); returns theta (4,)."""
        self._ref[:] = 0.0
        self._lam[0] = 0.0
        return self.step(posture, lam=lam)

    def step(self, posture_ref, lam: float | None = None, compliance_ref=None) -> np.ndarray:
        """Motor references theta (4,) rad: PM motors A, B, C and the PS motor, for one control period.

        Exactly one of ``lam`` (internal torque, N m, clipped to the allowed range) or ``compliance_ref``
        (2x2 coupler compliance, rad/(N m), tracked by the LM dynamics integrated over ``dt``); with neither
        the current lam is kept. NaN/inf inputs raise ValueError; postures are clipped to the range of motion.
        """
        ay, az, ps = _finite_vector("posture_ref", posture_ref, 3)
        (rlo, rhi), (flo, fhi), (plo, phi) = self._limits
        ay = rlo if ay < rlo else rhi if ay > rhi else ay
        az = flo if az < flo else fhi if az > fhi else az
        ps = plo if ps < plo else phi if ps > phi else ps
        ref = self._ref
        ref[0], ref[1], ref[2] = ay, az, ps
        q1, Ja, dOc, dxc = self._posture_kinematics(ay, az)
        N = self._basis(Ja)
        hi = self._tau_max / max(abs(N[0]), abs(N[1]), abs(N[2]))
        if lam is not None and compliance_ref is not None:
            raise ValueError("give either lam (internal torque) or compliance_ref (2x2 compliance), not both")
        if lam is not None:
            try:
                lam_f = float(lam)
            except (TypeError, ValueError):
                lam_f = math.nan
            if isinstance(lam, bool) or not math.isfinite(lam_f):
                raise ValueError(f"lam (internal torque, N m) must be a finite number, got {lam!r}")
            lam_ = min(max(lam_f, -hi), hi)
        elif compliance_ref is not None:
            c_ref = np.asarray(_finite_vector("compliance_ref", compliance_ref, 4)).reshape(2, 2)
            lam_ = self._lm_update(c_ref, (-hi, hi))
        else:
            lam_ = min(max(self._lam.item(0), -hi), hi)
        self._lam[0] = lam_
        t0, t1, t2 = lam_ * N[0], lam_ * N[1], lam_ * N[2]
        if self.gravity_compensation:
            g0, g1, g2 = self._min_norm_torques(Ja, self._gravity_from_derivatives(dOc, dxc))
            tmax = self._tau_max
            t0, t1, t2 = min(max(t0 + g0, -tmax), tmax), min(max(t1 + g1, -tmax), tmax), min(max(t2 + g2, -tmax), tmax)
        # the springs exert exactly tau at theta = q1 - delta(tau)
        theta = np.empty(4)
        theta[:3] = q1
        theta[:3] -= spring_deflection(np.array([t0, t1, t2]), self._law)
        theta[3] = ps
        return theta

    # ------------------------------------------------------------ batched
    # ``step`` over arrays of N postures: the kinematics, gravity load and minimum-norm solve are the scalar
    # path's own element-wise functions (``_coupler_terms``, ``_leg_terms``, ``_gravity_from_derivatives``,
    # ``_min_norm``) on arrays, the rest written operation for operation in the scalar code's order (NumPy's
    # +, -, *, /, sqrt, sin and cos round as Python's math does; atan2 is taken from math element by element,
    # since NumPy's arctan2 may differ in the last bit), so a batch of worlds and the single env command the
    # same motor references to the bit (tests/test_control.py, tests/test_batch.py).
    def step_batch(self, posture_ref: np.ndarray, lam: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Motor references of N controllers sharing these parameters, at once: ``posture_ref`` (N, 3) finite
        (RUD, FE, PS) references, ``lam`` (N,) internal torques (N m). Returns (theta (N, 4), the clipped lam
        (N,), the clipped references (N, 3)): the N controllers' commands, which the caller writes where they keep
        them (``bind``); this controller's own is not touched."""
        ref = np.asarray(posture_ref, dtype=float)
        (rlo, rhi), (flo, fhi), (plo, phi) = self._limits
        ay = np.minimum(np.maximum(ref[:, 0], rlo), rhi)
        az = np.minimum(np.maximum(ref[:, 1], flo), fhi)
        ps = np.minimum(np.maximum(ref[:, 2], plo), phi)
        q1, Ja, dOc, dxc = self.posture_kinematics_batch(ay, az, with_q1=True)
        N0, N1, N2 = self.basis_batch(Ja)
        hi = self._tau_max / np.maximum(np.maximum(np.abs(N0), np.abs(N1)), np.abs(N2))
        lam_c = np.minimum(np.maximum(np.asarray(lam, dtype=float), -hi), hi)
        t0, t1, t2 = lam_c * N0, lam_c * N1, lam_c * N2
        if self.gravity_compensation:
            (a0, a1, a2), (b0, b1, b2) = Ja
            g0, g1, g2 = _min_norm(a0, a1, a2, b0, b1, b2, self._gravity_from_derivatives(dOc, dxc))
            tmax = self._tau_max
            t0 = np.minimum(np.maximum(t0 + g0, -tmax), tmax)
            t1 = np.minimum(np.maximum(t1 + g1, -tmax), tmax)
            t2 = np.minimum(np.maximum(t2 + g2, -tmax), tmax)
        theta = np.empty((ref.shape[0], 4))
        theta[:, :3] = q1 - spring_deflection(np.stack([t0, t1, t2], axis=1), self._law)
        theta[:, 3] = ps
        return theta, lam_c, np.stack([ay, az, ps], axis=1)

    def posture_kinematics_batch(self, ay: np.ndarray, az: np.ndarray, with_q1: bool = True):
        """``_posture_kinematics`` over arrays, the three legs stacked along a first axis: (q1 (N, 3) or None,
        J_a as two (3, N) arrays (columns RUD, FE; row k = leg k), dO_c/du and dx_c/du as 2 columns of 3 (N,)
        arrays). The same operations in the same order; atan2 from ``math`` element by element (NumPy's differs
        from it in the last bit), so a batch's world equals the single env."""
        P, dOc, dxc = _coupler_terms(ay, az, self._r, np.cos, np.sin, np.sqrt)
        ce, se = self._legs_ce, self._legs_se  # (3, 1): leg k's cos/sin(eta_k), broadcast over the N postures
        Y, X, J0, J1 = _leg_terms(P, dOc, ce, se, self._a, self._s * self._s, np.sqrt, np.maximum)
        q1 = None
        if with_q1:
            atan2 = math.atan2
            q1 = np.array([atan2(yy, xx) for yy, xx in zip(Y.T.ravel().tolist(), X.T.ravel().tolist())])
            q1 = q1.reshape(-1, 3)
        return q1, (J0, J1), dOc, dxc

    @staticmethod
    def basis_batch(Ja):
        """``_basis`` over arrays (J_a as ``posture_kinematics_batch`` gives it): N as three (N,) arrays."""
        (a0, a1, a2), (b0, b1, b2) = Ja
        n0, n1, n2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
        inv = 1.0 / np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
        inv = np.where(n0 + n1 + n2 > 0, -inv, inv)
        return n0 * inv, n1 * inv, n2 * inv

    @property
    def posture_reference(self) -> np.ndarray:
        """The last (clipped) posture reference (RUD, FE, PS), rad."""
        return self._ref.copy()

    # ------------------------------------------------------- fast kinematics
    def _q1_ja(self, ay: float, az: float):
        """Actuated joint angles q1 (3,) and J_a = dq1/du (3 lists of 2), closed form (see module docstring)."""
        q1, Ja, _, _ = self._posture_kinematics(ay, az)
        return q1, Ja

    def _posture_kinematics(self, ay: float, az: float):
        """(q1, J_a, dO_c/du, dx_c/du): ``_q1_ja`` plus the coupler-centre and coupler-axis derivatives (each
        2 columns of 3), which the gravity compensation reuses rather than recomputing. The hot path of every
        env step: ``math`` on floats, leg by leg; ``posture_kinematics_batch`` runs the same two functions
        (``_coupler_terms``, ``_leg_terms``) on arrays."""
        P, dOc, dxc = _coupler_terms(ay, az, self._r, math.cos, math.sin, math.sqrt)
        a, s2 = self._a, self._s * self._s
        q1, Ja = [], []
        atan2, sqrt = math.atan2, math.sqrt
        for ce, se in self._legs:
            Y, X, J0, J1 = _leg_terms(P, dOc, ce, se, a, s2, sqrt, max)
            q1.append(atan2(Y, X))
            Ja.append([J0, J1])
        return q1, Ja, dOc, dxc

    @staticmethod
    def _basis(Ja) -> tuple[float, float, float]:
        """N: unit vector of ker(J_a^T) with negative components (positive lam stiffens)."""
        (a0, b0), (a1, b1), (a2, b2) = Ja
        n0, n1, n2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
        inv = 1.0 / math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
        if n0 + n1 + n2 > 0:
            inv = -inv
        return n0 * inv, n1 * inv, n2 * inv

    def kinematics_at(self, u) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q1 (3,), J_a (3, 2), N (3,)) at posture u = (RUD, FE), rad, from the closed-form fast path."""
        ay, az = _finite_vector("u", u, 2)
        q1, Ja = self._q1_ja(ay, az)
        return np.array(q1), np.array(Ja), np.array(self._basis(Ja))

    def _posture_terms(self, u: tuple[float, float]):
        """(J_a, N, H_a) at u, cached for the last posture: H_a[k] = d^2 q1_k/du^2 by central differences."""
        if self._terms_key != u:
            _, Ja = self._q1_ja(*u)
            Ja = np.array(Ja)
            h = _HESSIAN_STEP
            Ha = np.empty((3, 2, 2))
            for j in range(2):
                e = [0.0, 0.0]
                e[j] = h
                plus = np.array(self._q1_ja(u[0] + e[0], u[1] + e[1])[1])
                minus = np.array(self._q1_ja(u[0] - e[0], u[1] - e[1])[1])
                Ha[:, :, j] = (plus - minus) / (2 * h)
            Ha = 0.5 * (Ha + Ha.transpose(0, 2, 1))
            N = np.array(self._basis(Ja.tolist()))
            # the LM dynamics keep the original NumPy evaluation of tau_g: near an unreachable compliance
            # reference they are so stiff that a last-bit change in tau_g can select another lam
            tg = self._gravity_torques_reference(u[0], u[1], Ja) if self.gravity_compensation else None
            self._terms_key, self._terms = u, (Ja, N, Ha, tg)
        return self._terms

    # -------------------------------------------------------------- stiffness
    def lambda_range(self, u=None) -> tuple[float, float]:
        """(lo, hi) internal torque, N m, allowed at u (default: last reference) by the motor torque and
        deflection limits: |lam N_k| <= min(motor torque limit, spring torque at the deflection limit)."""
        ay, az = self._u if u is None else _finite_vector("u", u, 2)
        N = self._basis(self._q1_ja(ay, az)[1])
        hi = self._tau_max / max(abs(N[0]), abs(N[1]), abs(N[2]))
        return -hi, hi

    def _stiffness_and_derivative(self, terms, lam: float) -> tuple[np.ndarray, np.ndarray]:
        """Sigma_c(lam) (2, 2) N m/rad and dSigma_c/dlam, for the spring torques tau = lam N (+ tau_g)."""
        Ja, N, Ha, tg = terms
        tau = lam * N if tg is None else np.clip(lam * N + tg, -self._tau_max, self._tau_max)
        x = tau / (2.0 * self._K)
        sigma = spring_stiffness_at_torque(tau, self.params)
        dsigma = (x / np.sqrt(1.0 + x * x)) / self._delta0 * N
        S = Ja.T @ (sigma[:, None] * Ja)
        dS = Ja.T @ (dsigma[:, None] * Ja)
        if self.include_load_term:
            S = S - np.einsum("k,kij->ij", tau, Ha)
            dS = dS - np.einsum("k,kij->ij", N, Ha)
        return 0.5 * (S + S.T), 0.5 * (dS + dS.T)

    def stiffness(self, u=None) -> np.ndarray:
        """Commanded coupler stiffness Sigma_c (2, 2), N m/rad, at u (default: the last reference) and the
        current lam; complete (with load term) unless ``include_load_term=False``."""
        key = self._u if u is None else _finite_vector("u", u, 2)
        return self._stiffness_and_derivative(self._posture_terms(key), self.lam)[0]

    def compliance(self, u=None) -> np.ndarray:
        """Commanded coupler compliance C = Sigma_c^-1 (2, 2), rad/(N m)."""
        return np.linalg.inv(self.stiffness(u))

    def lm_rate(self, lam: float, compliance_ref, u=None) -> float:
        """The paper's d(lam)/dt = -alpha H/(H^2 + nu) G at lam, with G = ||C(lam) - c_r||_F and H = dG/dlam.

        Written as -alpha <E, dC>/(H^2 + nu) with E = C - c_r, since H G = <E, dC/dlam>: no 0/0 at G = 0.
        """
        key = self._u if u is None else _finite_vector("u", u, 2)
        c = np.asarray(compliance_ref, dtype=float)
        return self._lm_rate(float(lam), self._posture_terms(key), (c[0, 0], c[0, 1], c[1, 0], c[1, 1]))

    def _lm_rate(self, lam: float, terms, c_ref: tuple[float, float, float, float]) -> float:
        """``lm_rate`` in scalar arithmetic: C and dC symmetric [[a, b], [b, d]], c_ref row-major (4 values)."""
        Ja, N, Ha, tg = terms
        K2, d0, tmax = 2.0 * self._K, self._delta0, self._tau_max
        a = b = d = da = db = dd = 0.0
        load = self.include_load_term
        for k in range(3):
            nk = N[k]
            tau = lam * nk if tg is None else min(max(lam * nk + tg[k], -tmax), tmax)
            x = tau / K2
            root = math.sqrt(1.0 + x * x)
            sig, dsig = K2 / d0 * root, (x / root) / d0 * nk
            j0, j1 = Ja[k]
            a += sig * j0 * j0
            b += sig * j0 * j1
            d += sig * j1 * j1
            da += dsig * j0 * j0
            db += dsig * j0 * j1
            dd += dsig * j1 * j1
            if load:
                (h00, h01), (_, h11) = Ha[k]
                a -= tau * h00
                b -= tau * h01
                d -= tau * h11
                da -= nk * h00
                db -= nk * h01
                dd -= nk * h11
        inv_det = 1.0 / (a * d - b * b)
        ca, cb, cd = d * inv_det, -b * inv_det, a * inv_det            # C = S^-1
        # dC = -C dS C
        m00, m01 = ca * da + cb * db, ca * db + cb * dd                   # (C dS) row 0
        m10, m11 = cb * da + cd * db, cb * db + cd * dd                   # (C dS) row 1
        dca = -(m00 * ca + m01 * cb)
        dcb = -(m00 * cb + m01 * cd)
        dcd = -(m10 * cb + m11 * cd)
        ea, e01, e10, ed = ca - c_ref[0], cb - c_ref[1], cb - c_ref[2], cd - c_ref[3]
        G = math.sqrt(ea * ea + e01 * e01 + e10 * e10 + ed * ed)
        HG = ea * dca + (e01 + e10) * dcb + ed * dcd
        H = HG / G if G > 0.0 else 0.0
        return -self._alpha * HG / (H * H + self._nu)

    def _lm_update(self, c_ref: np.ndarray, bounds: tuple[float, float]) -> float:
        """Integrate the LM dynamics over one control period from the current lam.

        Linearly implicit Euler, lam += h f / (1 - h f'), with f = d(lam)/dt and f' = df/dlam: one step per
        period where the dynamics contract (f' < 0; near the minimiser of an unreachable reference they are
        very stiff, f' ~ -alpha G G''/nu, and explicit Euler would oscillate), sub-steps with h f' <= 0.5
        where they expand (leaving a maximum of G). lam stays within ``bounds``.
        """
        lo, hi = bounds
        lam = min(max(self.lam, lo), hi)
        terms = self._posture_terms(self._u)
        Ja, N, Ha, tg = terms
        terms = (Ja.tolist(), N.tolist(), Ha.tolist(), None if tg is None else tg.tolist())
        c = (float(c_ref[0, 0]), float(c_ref[0, 1]), float(c_ref[1, 0]), float(c_ref[1, 1]))
        remaining = self.dt
        for _ in range(1000):
            if remaining <= 1e-12 * self.dt:
                break
            rate = self._lm_rate(lam, terms, c)
            eps = 1e-7 * max(1.0, abs(lam))
            slope = (self._lm_rate(lam + eps, terms, c) - rate) / eps
            h = remaining if slope * remaining <= 0.5 else max(0.5 / slope, remaining / 1000.0)
            lam = min(max(lam + h * rate / (1.0 - h * slope), lo), hi)
            remaining -= h
        return lam

    # ---------------------------------------------------------------- gravity
    def gravity_torque(self, u=None) -> np.ndarray:
        """dV_g/du (2,), N m: the generalised gravity load of the hand and coupler at u (default: last reference)."""
        ay, az = self._u if u is None else _finite_vector("u", u, 2)
        return np.array(self._gravity_generalised(ay, az))

    def _gravity_generalised(self, ay: float, az: float) -> tuple[float, float]:
        _, _, dOc, dxc = self._posture_kinematics(ay, az)
        return self._gravity_from_derivatives(dOc, dxc)

    def _gravity_from_derivatives(self, dOc, dxc) -> tuple[float, float]:
        """dV_g/du from dO_c/du and dx_c/du (columns j = RUD, FE), element-wise: floats, or (N,) arrays for a batch.

        V_g = -sum m_i g . p_i with p_hand = O_c + L x_c, p_coupler = O_c (a payload mass m at O_c + x x_c), so
        dV_g/du_j = -g . ((m_hand + m_coupler + sum m) dO_c/du_j + (m_hand L + sum m x) dx_c/du_j)."""
        gx, gy, gz = self._gravity
        mo, ml = self._mo, self._ml
        out = []
        for (ox, oy, oz), (xx, xy, xz) in zip(dOc, dxc):
            out.append(-(gx * (mo * ox + ml * xx) + gy * (mo * oy + ml * xy) + gz * (mo * oz + ml * xz)))
        return out[0], out[1]

    def _gravity_torques_reference(self, ay: float, az: float, Ja) -> np.ndarray:
        """tau_g (3,) by the original NumPy route (outer products, ``np.linalg.solve``): the reference for the
        scalar fast path of ``step`` and what the LM dynamics use (bit-for-bit as before)."""
        cy, sy, cz, sz = math.cos(ay), math.sin(ay), math.cos(az), math.sin(az)
        m = np.array([1.0 + cz * cy, sz * cy, -sy])
        nm = float(np.linalg.norm(m))
        n = m / nm
        dxc = np.array([[-cz * sy, -sz * cy], [-sz * sy, cz * cy], [-cy, 0.0]])  # d x_c / du (3, 2)
        dOc = self._r / nm * (dxc - np.outer(n, n @ dxc))
        g = np.asarray(self._gravity)
        m_hand, m_coupler = self._masses
        dV = -(m_hand * (dOc + self._hand_offset * dxc) + m_coupler * dOc).T @ g
        for m, x in self.payload:
            dV = dV - (m * (dOc + x * dxc)).T @ g
        J = np.asarray(Ja)
        w = np.array([float(dV[0]), float(dV[1])])
        tg = J @ np.linalg.solve(J.T @ J, w)
        return np.array([float(tg[0]), float(tg[1]), float(tg[2])])

    def _gravity_torques(self, ay: float, az: float, Ja) -> tuple[float, float, float]:
        """Minimum-norm spring torques with J_a^T tau_g = dV_g/du (they hold the hand's weight at u)."""
        return self._min_norm_torques(Ja, self._gravity_generalised(ay, az))

    @staticmethod
    def _min_norm_torques(Ja, w) -> tuple[float, float, float]:
        """tau = J_a (J_a^T J_a)^-1 w (3,), the minimum-norm solution of J_a^T tau = w; J_a as 3 rows (leg k:
        dq1_k/dRUD, dq1_k/dFE)."""
        (a0, b0), (a1, b1), (a2, b2) = Ja
        return _min_norm(a0, a1, a2, b0, b1, b2, w)


def _min_norm(a0, a1, a2, b0, b1, b2, w):
    """J_a (J_a^T J_a)^-1 w with J_a's columns (a0, a1, a2) and (b0, b1, b2): a 2x2 solve by Cramer, element-wise,
    so the same arithmetic serves one posture (floats) and a batch ((N,) arrays)."""
    p = a0 * a0 + a1 * a1 + a2 * a2
    q = a0 * b0 + a1 * b1 + a2 * b2
    r = b0 * b0 + b1 * b1 + b2 * b2
    w0, w1 = w
    inv_det = 1.0 / (p * r - q * q)
    x0 = (r * w0 - q * w1) * inv_det
    x1 = (p * w1 - q * w0) * inv_det
    return a0 * x0 + b0 * x1, a1 * x0 + b1 * x1, a2 * x0 + b2 * x1


def benchmark(params: WristParams | str | None = None, steps: int = 20000) -> dict[str, float]:
    """Seconds per controller step (internal-torque and compliance modes) and, as the reference measured in
    the same run, per evaluation of the least-squares path (``kinematics`` J_a and N +
    ``stiffness.motor_references``)."""
    import time

    from .kinematics import WristKinematics
    from .stiffness import coupler_compliance, motor_references

    p = load_params(params)
    ctrl = AnalyticController(p)
    kin = WristKinematics(p)
    rng = np.random.default_rng(0)
    refs = [(float(a), float(b), 0.1) for a, b in rng.uniform(kin.u_min, kin.u_max, size=(64, 2))]
    t0 = time.perf_counter()
    for i in range(steps):
        ctrl.step(refs[i % 64], lam=0.5)
    fast = (time.perf_counter() - t0) / steps
    n_ref = max(steps // 50, 20)
    t0 = time.perf_counter()
    for i in range(n_ref):
        u = np.array(refs[i % 64][:2])
        kin.actuated_jacobian(u)
        motor_references(u, 0.5, p)
    slow = (time.perf_counter() - t0) / n_ref
    c_ref = coupler_compliance(np.zeros(2), 0.3 * ctrl.lambda_range((0.0, 0.0))[1], p)
    n_c = max(steps // 20, 20)
    t0 = time.perf_counter()
    for i in range(n_c):
        ctrl.step(refs[i % 64], compliance_ref=c_ref)
    compliance = (time.perf_counter() - t0) / n_c
    return {"step_lambda_s": fast, "step_compliance_s": compliance, "least_squares_reference_s": slow,
            "speedup": slow / fast}


if __name__ == "__main__":  # python -m vswrist_gym.control: controller cost against the least-squares path
    r = benchmark()
    print(f"AnalyticController.step, internal-torque mode: {r['step_lambda_s'] * 1e6:.1f} us")
    print("AnalyticController.step, compliance mode (posture changes every step): "
          f"{r['step_compliance_s'] * 1e6:.1f} us")
    print(f"reference, least-squares J_a + motor_references: {r['least_squares_reference_s'] * 1e6:.1f} us "
          f"-> fast path {r['speedup']:.0f}x faster")
