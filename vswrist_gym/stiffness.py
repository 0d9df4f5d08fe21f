"""Sinh springs, static coupler stiffness, internal torques and motor references (NumPy only).

Conventions:

* Spring on leg k: deflection ``delta = q1 - theta`` (link minus motor), torque on the link
  ``tau_s = -2 K sinh(delta / delta0)``, stiffness ``sigma_s = -d tau_s / d delta = (2K/delta0) cosh(delta/delta0)``,
  energy ``2 K delta0 (cosh(delta/delta0) - 1)``. This module is the spring law's one Python home
  (``spring_torque``, its inverse ``spring_deflection``, ``spring_stiffness``, ``spring_energy``): the
  environments, the controller and the reproduction call it; the compiled per-substep kernel
  (``model.native``) is tested against it.
* Internal torque: spring torques ``tau_s = lambda N`` with N = ``WristKinematics.internal_torque_basis``
  (unit norm, J_a^T N = 0, negative components). They balance each other through the mechanism and leave
  the posture unchanged.
* Static coupler stiffness, conjugate to u (N m/rad): the derivative of the external generalised force
  that holds the coupler at u with the motors fixed, ``w(u) = -J_a(u)^T tau_s(q1(u) - theta)``:

      Sigma_c = J_a^T Sigma_s J_a  -  sum_k tau_s,k d^2 q1_k / du^2

  The first term is the paper's formula; the second, the load term, is what the paper omits. With the
  sign of N above, **positive lambda stiffens** (load term positive definite, about +13 % at the
  ``paper`` preset) and negative lambda softens.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from .kinematics import WristKinematics
from .params import WristParams, load_params


class SpringLaw(NamedTuple):
    """The law's two constants, K (N m) and delta0 (rad): floats, or arrays that broadcast against the
    deflections (a batch of worlds whose randomisation gave each its own springs: (N, 1) against (N, 3))."""

    K: float | np.ndarray
    delta0: float | np.ndarray


def _spring(params: WristParams | SpringLaw | str | None):
    if isinstance(params, SpringLaw):
        return params
    return load_params(params).spring


def spring_torque(delta, params: WristParams | str | None = None):
    """Torque of the sinh spring on its link (N m) at deflection delta = q1 - theta (rad)."""
    s = _spring(params)
    return -2.0 * s.K * np.sinh(np.asarray(delta, dtype=float) / s.delta0)


def spring_stiffness(delta, params: WristParams | str | None = None):
    """Spring stiffness sigma_s = -d tau_s / d delta (N m/rad) at deflection delta (rad)."""
    s = _spring(params)
    return 2.0 * s.K / s.delta0 * np.cosh(np.asarray(delta, dtype=float) / s.delta0)


def spring_deflection(tau, params: WristParams | str | None = None):
    """Inverse of ``spring_torque``: the deflection (rad) at which the spring exerts tau (N m)."""
    s = _spring(params)
    return -s.delta0 * np.arcsinh(np.asarray(tau, dtype=float) / (2.0 * s.K))


def spring_energy(delta, params: WristParams | str | None = None):
    """Energy stored in the spring (J) at deflection delta (rad): the integral of -tau_s from 0 to delta,
    2 K delta0 (cosh(delta/delta0) - 1)."""
    s = _spring(params)
    return 2.0 * s.K * s.delta0 * (np.cosh(np.asarray(delta, dtype=float) / s.delta0) - 1.0)


def stored_energy(delta, params: WristParams | str | None = None):
    """Energy stored in the three springs (J) at deflections ``delta`` (..., 3): ``spring_energy`` summed over
    the springs in order (NumPy adds fewer than 8 terms in order), one world's or a batch's rows alike."""
    return np.add.reduce(spring_energy(delta, params), axis=-1)


def spring_stiffness_at_torque(tau, params: WristParams | str | None = None):
    """sigma_s as a function of the spring torque: (2K/delta0) sqrt(1 + (tau/2K)^2) (N m/rad)."""
    s = _spring(params)
    return 2.0 * s.K / s.delta0 * np.sqrt(1.0 + (np.asarray(tau, dtype=float) / (2.0 * s.K)) ** 2)


@dataclass(frozen=True)
class PostureTerms:
    """Everything the stiffness needs that depends on the posture alone (computed once per u)."""

    u: np.ndarray
    q1: np.ndarray          # (3,) actuated joint angles, rad
    Ja: np.ndarray          # (3, 2)
    N: np.ndarray           # (3,)
    Ha: np.ndarray          # (3, 2, 2) d^2 q1_k / du_i du_j


def posture_terms(u, params: WristParams | str | None = None, kin: WristKinematics | None = None,
                  allow_outside: bool = False) -> PostureTerms:
    kin = kin or WristKinematics(params)
    u = kin.check_posture(u, allow_outside)
    q1 = kin.joint_angles(u, allow_outside)[0::4]
    Ja = kin.actuated_jacobian(u, allow_outside)
    N = kin.internal_torque_basis(u, allow_outside)
    Ha = kin.actuated_hessian(u, allow_outside=allow_outside)
    return PostureTerms(u=u, q1=q1, Ja=Ja, N=N, Ha=Ha)


def stiffness_from_terms(terms: PostureTerms, lam: float, params: WristParams | str | None = None,
                         include_load_term: bool = True) -> np.ndarray:
    tau = float(lam) * terms.N
    sigma = spring_stiffness_at_torque(tau, params)
    S = terms.Ja.T @ (sigma[:, None] * terms.Ja)
    if include_load_term:
        S = S - np.einsum("k,kij->ij", tau, terms.Ha)
    return 0.5 * (S + S.T)


def coupler_stiffness(u, lam: float, params: WristParams | str | None = None, include_load_term: bool = True,
                      allow_outside: bool = False) -> np.ndarray:
    """Static coupler stiffness Sigma_c (2, 2), N m/rad, conjugate to u = (RUD, FE), at internal torque lam (N m).

    ``include_load_term=False`` gives the paper's J_a^T Sigma_s J_a.
    """
    return stiffness_from_terms(posture_terms(u, params, allow_outside=allow_outside), lam, params,
                                include_load_term)


def coupler_compliance(u, lam: float, params: WristParams | str | None = None, include_load_term: bool = True,
                       allow_outside: bool = False) -> np.ndarray:
    """Coupler compliance C = Sigma_c^-1 (2, 2), rad/(N m)."""
    return np.linalg.inv(coupler_stiffness(u, lam, params, include_load_term, allow_outside))


def motor_references(u, lam: float, params: WristParams | str | None = None, allow_outside: bool = False,
                     terms: PostureTerms | None = None) -> np.ndarray:
    """PM motor angles theta (3,), rad, that hold posture u with internal torque lam (N m).

    theta = q1(u) + delta0 asinh(lam N / 2K): the springs then exert exactly tau_s = lam N.
    """
    s = _spring(params)
    if terms is None:
        kin = WristKinematics(params)
        u = kin.check_posture(u, allow_outside)
        q1 = kin.joint_angles(u, allow_outside)[0::4]
        N = kin.internal_torque_basis(u, allow_outside)
    else:
        q1, N = terms.q1, terms.N
    return q1 + s.delta0 * np.arcsinh(float(lam) * N / (2.0 * s.K))


def max_leg_torque(params: WristParams | str | None = None) -> float:
    """Largest spring torque per leg (N m): the lesser of the motor torque limit and the spring torque at
    the mechanical deflection limit."""
    p = load_params(params)
    return float(min(p.motor.torque_limit, 2.0 * p.spring.K * np.sinh(p.spring.deflection_limit / p.spring.delta0)))


def lambda_range(u, params: WristParams | str | None = None, margin: float = 0.0, allow_outside: bool = False,
                 terms: PostureTerms | None = None) -> tuple[float, float]:
    """Internal torques (lam_min, lam_max), N m, that the motor torque and deflection limits allow at u.

    ``margin`` in [0, 1) keeps that fraction of the per-leg torque free for external loads.
    """
    if not 0.0 <= margin < 1.0:
        raise ValueError(f"margin must be in [0, 1), got {margin}")
    if terms is None:
        N = WristKinematics(params).internal_torque_basis(u, allow_outside)
    else:
        N = terms.N
    lam = (1.0 - margin) * max_leg_torque(params) / float(np.max(np.abs(N)))
    return -lam, lam


def closest_lambda(u, compliance_ref, params: WristParams | str | None = None, include_load_term: bool = True,
                   lam_bounds: tuple[float, float] | None = None, allow_outside: bool = False,
                   terms: PostureTerms | None = None) -> float:
    """The lam in the allowed range whose compliance is closest (Frobenius) to ``compliance_ref`` (2, 2).

    Robust 1-D minimisation: a dense scan over lam (on an asinh scale, which resolves the exponential
    springs evenly) brackets the global minimum, and golden-section search refines it.
    """
    c_ref = np.asarray(compliance_ref, dtype=float)
    if c_ref.shape != (2, 2) or not np.all(np.isfinite(c_ref)):
        raise ValueError(f"compliance reference must be a finite (2, 2) matrix in rad/(N m), got {c_ref!r}")
    terms = terms or posture_terms(u, params, allow_outside=allow_outside)
    lo, hi = lam_bounds if lam_bounds is not None else lambda_range(u, params, terms=terms)
    s = _spring(params)

    def G(lam: float) -> float:
        C = np.linalg.inv(stiffness_from_terms(terms, lam, params, include_load_term))
        return float(np.linalg.norm(C - c_ref))

    scale = 2.0 * s.K
    grid = scale * np.sinh(np.linspace(np.arcsinh(lo / scale), np.arcsinh(hi / scale), 401))
    values = np.array([G(x) for x in grid])
    i = int(np.argmin(values))
    a, b = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
    invphi = (np.sqrt(5.0) - 1.0) / 2.0
    c, d = b - invphi * (b - a), a + invphi * (b - a)
    gc, gd = G(c), G(d)
    for _ in range(80):
        if gc < gd:
            b, d, gd = d, c, gc
            c = b - invphi * (b - a)
            gc = G(c)
        else:
            a, c, gc = c, d, gd
            d = a + invphi * (b - a)
            gd = G(d)
        if b - a < 1e-12 * max(1.0, abs(a)):
            break
    best = [(values[i], grid[i]), (gc, c), (gd, d)]
    return float(min(best)[1])
