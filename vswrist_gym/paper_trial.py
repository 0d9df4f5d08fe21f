"""The paper's Fig. 3c trial in the simulator, under the paper's controller: the posture reference, the LS and HS
internal torques, the 1.5 kg load, and the trial's RMS posture error and elastic torque. Both the reproduction
(``tools.reproduce``: figures, ``results.json``) and the identification (``identify``: the motor dynamics that
give the paper's four numbers) run it; the choices the paper leaves open are listed in ``tools.reproduce``."""

from __future__ import annotations

import math

import numpy as np

from .control import AnalyticController

PAPER = {"rms_error_ls": 0.15, "rms_error_hs": 0.007, "rms_torque_ls": 0.07, "rms_torque_hs": 1.72}
LS_PER_LEG, HS_PER_LEG = 0.07, 1.72            # N m
LOAD_MASS, LOAD_TIME = 1.5, 0.5                # kg, s
CONTROL_DT = 0.01                              # s
IMPLIED_LOAD_TORQUE = 0.015                    # N m, see implied_load_scenario


def reference(t: float) -> tuple[float, float, float]:
    """Posture reference (RUD, FE, PS), rad, at time t (s)."""
    return (0.15 * math.sin(2 * math.pi * t / 2.0), 0.3 * math.sin(2 * math.pi * t / 4.0), 0.0)


def per_leg_to_lambda(per_leg: float) -> float:
    """Internal torque (N m) whose per-leg elastic torque at the central posture is ``per_leg``.

    There N = -(1, 1, 1)/sqrt(3), so each leg carries lam/sqrt(3)."""
    return per_leg * math.sqrt(3.0)


def trial(params, lam: float, duration: float, gravity_compensation: bool = True, load=None,
          control_dt: float = CONTROL_DT, reference_fn=None) -> dict:
    """One Fig. 3c trial in the simulator: track ``reference`` at internal torque lam, load from LOAD_TIME.

    ``load``: the force (N, base frame) at the hand point; default LOAD_MASS x ``environment.gravity``.
    ``control_dt`` (s) and ``reference_fn`` (t -> (RUD, FE, PS)) exist for the what-if diagnostics of
    ``vswrist_gym.identify``; the reproduction (``tools.reproduce``) uses CONTROL_DT and ``reference``."""
    from .sim import SimulationError, WristSim  # here: importing this module does not load MuJoCo

    reference_fn = reference if reference_fn is None else reference_fn
    sim = WristSim(params)
    ctrl = AnalyticController(params, dt=control_dt, gravity_compensation=gravity_compensation)
    ref0 = reference_fn(0.0)
    ctrl.reset(ref0, lam=lam)
    sim.reset(u=ref0[:2], ps=ref0[2], lam=ctrl.lam)
    load = LOAD_MASS * np.asarray(params.environment.gravity, dtype=float) if load is None else np.asarray(load)
    n = int(round(duration / control_dt))
    t_log, ref_log, post_log, tau_log = [], [], [], []
    status = "ok"
    try:
        for i in range(n):
            t = i * control_dt
            if abs(t - LOAD_TIME) < 1e-9:
                sim.apply_wrench(load, (0.0, 0.0, 0.0))
            sim.set_motor_references(ctrl.step(reference_fn(t), lam=lam))
            sim.step(control_dt)
            t1 = (i + 1) * control_dt
            post = sim.posture()
            if not np.all(np.isfinite(post)):
                raise SimulationError(f"non-finite posture at t = {t1:.3f} s")
            t_log.append(t1)
            ref_log.append(reference_fn(t1))
            post_log.append(post)
            tau_log.append(sim.spring_torques())
    except SimulationError as exc:
        status = f"simulation stopped: {exc}"
    ref_a, post_a, tau_a = np.array(ref_log), np.array(post_log), np.array(tau_log)
    err = np.linalg.norm(post_a[:, :2] - ref_a[:, :2], axis=1)
    return {"t": np.array(t_log), "ref": ref_a, "posture": post_a, "tau": tau_a, "lam": float(ctrl.lam),
            "rms_error": float(np.sqrt(np.mean(err ** 2))), "rms_torque": float(np.sqrt(np.mean(tau_a ** 2))),
            "max_error": float(err.max()), "status": status}


def implied_load_setup(params) -> tuple:
    """(params with gravity off, force at the hand point) of the implied-load diagnostic: a force along -Z_b
    whose torque about the centre at the central posture is IMPLIED_LOAD_TORQUE."""
    p0 = params.replace(environment={"gravity": [0.0, 0.0, 0.0]})
    lever = params.inertia.hand_offset + params.geometry.d * math.sin(params.geometry.alpha / 2.0)
    return p0, np.array([0.0, 0.0, -IMPLIED_LOAD_TORQUE / lever])


def implied_load_scenario(params, duration: float, **trial_kwargs) -> tuple[dict, dict]:
    """Diagnostic: the paper's numbers imply a load torque of only ~0.015 N m in both trials (stiffness x RMS
    error). Gravity off, a force along -Z_b at the hand point whose torque at the central posture is that
    (force = 0.015 N m / lever): does the controller then show the paper's HS/LS ratios?"""
    p0, force = implied_load_setup(params)
    ls = trial(p0, per_leg_to_lambda(LS_PER_LEG), duration, False, load=force, **trial_kwargs)
    hs = trial(p0, per_leg_to_lambda(HS_PER_LEG), duration, False, load=force, **trial_kwargs)
    return {"description": f"gravity off; {np.linalg.norm(force):.3g} N along -Z_b at the hand point from "
                           f"t = {LOAD_TIME} s ({IMPLIED_LOAD_TORQUE} N m about the centre)",
            "rms_error_ls": ls["rms_error"], "rms_error_hs": hs["rms_error"],
            "rms_torque_ls": ls["rms_torque"], "rms_torque_hs": hs["rms_torque"],
            "error_ratio_ls_over_hs": ls["rms_error"] / hs["rms_error"],
            "torque_ratio_hs_over_ls": hs["rms_torque"] / ls["rms_torque"]}, {"ls": ls, "hs": hs}
