"""The paper's unknown motor dynamics identified from its four section-5 RMS numbers.

``python -m vswrist_gym.identify [--out DIR] [--quick]`` (or ``vswrist reproduce --identify --out DIR``)
fits the parameters the paper leaves open and the preset chose (motor low-pass time constant, speed limit,
position-loop gain, leg joint damping) to the paper's RMS posture errors and elastic torques of the LS and HS
trials, under the load the paper's numbers imply (``paper_trial.implied_load_scenario``: 0.015 N m about the
centre). Everything the paper gives stays as given.

* Residuals: log(ours / paper) for the four numbers, equal weights (the target "within 1.5x" is symmetric in
  the log), plus a weak pull towards the base preset's values (``PRIOR_WEIGHT``) that decides only directions
  the numbers do not see.
* Solver: Levenberg-Marquardt in normalised log coordinates z in [0, 1] per unknown (log p between its
  bounds), forward-difference Jacobian, bounds by projection (a coordinate at a bound that the gradient pushes
  outward is held there). scipy is not installed in this environment, so this is written here.
* Several starts: converging to one set (up to the flat directions) says the minimum is unique.
* "Fits equally": every one of the four numbers within the paper's printed precision (half a unit of its last
  digit: 0.005 rad, 0.0005 rad, 0.005 N m, 0.005 N m) of the best fit's. Among the sets that fit equally the
  identification picks the one closest to the base preset: from the best fit each unknown, the least
  influential first, moves back towards its base value as far as the four numbers stay within that precision.
* Sensitivities: central differences of log(number) over log(parameter) at the chosen set (elasticities: the
  % change of each number per % change of the parameter), and in SI units per unit of the parameter.
* The position loop's damping gain kd follows kp at the base preset's damping ratio (kd ~ sqrt(kp)).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import dataclass
from decimal import Decimal
from pathlib import Path

import numpy as np

from .params import WristParams, load_params
from .paper_trial import (HS_PER_LEG, IMPLIED_LOAD_TORQUE, PAPER, implied_load_scenario, implied_load_setup,
                          per_leg_to_lambda, trial)

KEYS = ("rms_error_ls", "rms_error_hs", "rms_torque_ls", "rms_torque_hs")
UNITS = {"rms_error_ls": "rad", "rms_error_hs": "rad", "rms_torque_ls": "N m", "rms_torque_hs": "N m"}
PRIOR_WEIGHT = 1e-2          # on (z - z_base)^2 against the squared log residuals of order 0.01-0.3
IDENTIFIED_PRESET = "paper_identified"
TARGET_FACTOR, TARGET_RATIO = 1.5, 15.0


@dataclass(frozen=True)
class Unknown:
    """One parameter the paper does not give, with its physically plausible bounds and why."""

    section: str
    key: str
    lo: float
    hi: float
    why: str

    @property
    def name(self) -> str:
        return f"{self.section}.{self.key}"


UNKNOWNS = (
    Unknown("motor", "time_constant", 0.002, 0.1,
            "2 ms (an 80 Hz servo, the fast end of geared DC motors; 2 physics substeps) to 100 ms (1.6 Hz)"),
    Unknown("motor", "speed_limit", 2.0, 20.0,
            "2 rad/s (19 rpm) to 20 rad/s (190 rpm) at the output of a geared DC motor"),
    Unknown("motor", "kp", 1000.0, 30000.0,
            "1e3 N m/rad (200x the HS spring stiffness of 5.4 N m/rad per leg: series compliance < 0.5 %) to "
            "3e4 N m/rad (3x the stiff-servo choice; a gearbox of this size is not stiffer)"),
    Unknown("damping", "leg_joint", 1e-4, 0.05,
            "1e-4 (bare ball bearings) to 0.05 N m s/rad (10x today's; heavily damped joints)"),
)


def paper_precision(value: float) -> float:
    """Half a unit of the last printed digit of one of the paper's numbers (0.15 -> 0.005)."""
    exponent = Decimal(repr(value)).normalize().as_tuple().exponent
    return 0.5 * 10.0 ** int(exponent)


def with_values(base: WristParams, values: dict[str, float]) -> WristParams:
    """``base`` with some unknowns changed (``{"motor.kp": 3e4, ...}``); kd follows kp at base's damping ratio."""
    sections: dict[str, dict] = {}
    for name, value in values.items():
        section, key = name.split(".")
        sections.setdefault(section, {})[key] = float(value)
    if "kp" in sections.get("motor", {}):
        sections["motor"]["kd"] = base.motor.kd * math.sqrt(sections["motor"]["kp"] / base.motor.kp)
    return base.replace(**sections)


def four_numbers(params: WristParams, duration: float = 4.0) -> np.ndarray:
    """The paper's four RMS numbers (``KEYS``) of ``params`` under the implied load."""
    res, _ = implied_load_scenario(params, duration)
    return np.array([res[k] for k in KEYS])


class Problem:
    """The fit's model: normalised coordinates z in [0, 1]^n <-> parameter values, and the four numbers."""

    def __init__(self, base: WristParams, unknowns=UNKNOWNS, duration: float = 4.0, target=None):
        self.base, self.unknowns, self.duration = base, tuple(unknowns), float(duration)
        self.target = np.array([PAPER[k] for k in KEYS] if target is None else target, dtype=float)
        if self.target.shape != (4,) or not np.all(self.target > 0):
            raise ValueError(f"target must be 4 positive numbers ({', '.join(KEYS)}), got {target!r}")
        for u in self.unknowns:
            if not 0 < u.lo < u.hi:
                raise ValueError(f"bounds of {u.name} must satisfy 0 < lo < hi, got [{u.lo}, {u.hi}]")
        self.log_lo = np.log([u.lo for u in self.unknowns])
        self.log_span = np.log([u.hi for u in self.unknowns]) - self.log_lo
        self.evaluations = 0
        self._cache: dict[tuple, np.ndarray] = {}

    def values(self, z) -> dict[str, float]:
        p = np.exp(self.log_lo + np.clip(z, 0.0, 1.0) * self.log_span)
        return {u.name: float(v) for u, v in zip(self.unknowns, p)}

    def z_of(self, values: dict[str, float]) -> np.ndarray:
        return np.array([(math.log(values[u.name]) - lo) / span
                         for u, lo, span in zip(self.unknowns, self.log_lo, self.log_span)])

    def base_z(self) -> np.ndarray:
        """The base preset's values in z, clipped into the bounds."""
        return np.clip(self.z_of({u.name: getattr(getattr(self.base, u.section), u.key) for u in self.unknowns}),
                       0.0, 1.0)

    def numbers(self, z) -> np.ndarray:
        key = tuple(np.round(np.clip(z, 0.0, 1.0), 12))
        if key not in self._cache:
            self._cache[key] = four_numbers(with_values(self.base, self.values(z)), self.duration)
            self.evaluations += 1
        return self._cache[key]

    def residuals(self, z) -> np.ndarray:
        return np.log(self.numbers(z) / self.target)


def fit(problem: Problem, z0, prior_weight: float = PRIOR_WEIGHT, max_iter: int = 30, h: float = 0.02) -> dict:
    """Bounded Levenberg-Marquardt on 0.5 |r(z)|^2 + 0.5 w |z - z_base|^2 from z0; returns the best z."""
    zb = problem.base_z()
    sw = math.sqrt(prior_weight)

    def full(z):
        return np.concatenate([problem.residuals(z), sw * (z - zb)])

    z = np.clip(np.asarray(z0, dtype=float), 0.0, 1.0)
    r = full(z)
    cost, mu, n = 0.5 * r @ r, 1e-2, len(z)
    for it in range(max_iter):
        J = np.empty((len(r), n))
        for j in range(n):
            step = h if z[j] + h <= 1.0 else -h
            dz = np.zeros(n)
            dz[j] = step
            J[:, j] = (full(z + dz) - r) / step
        g = J.T @ r
        free = ~(((z <= 0.0) & (g > 0)) | ((z >= 1.0) & (g < 0)))
        improved = False
        for _ in range(8):
            A = J[:, free].T @ J[:, free]
            delta = np.zeros(n)
            delta[free] = np.linalg.solve(A + mu * (np.diag(np.diag(A)) + np.eye(A.shape[0])), -g[free])
            z_new = np.clip(z + delta, 0.0, 1.0)
            r_new = full(z_new)
            cost_new = 0.5 * r_new @ r_new
            if cost_new < cost:
                improved = True
                step_size = float(np.abs(z_new - z).max())
                z, r, rel, cost = z_new, r_new, (cost - cost_new) / max(cost, 1e-300), cost_new
                mu = max(mu / 3.0, 1e-6)
                break
            mu *= 4.0
        if not improved or step_size < 1e-3 or rel < 1e-4:
            break
    return {"z": z, "cost": float(cost), "iterations": it + 1}


def elasticities(problem: Problem, z, h: float = 0.05) -> np.ndarray:
    """d log(number) / d log(parameter) (4 x n), central differences in z (one-sided at a bound)."""
    out = np.empty((4, len(problem.unknowns)))
    for j in range(len(problem.unknowns)):
        zp, zm = np.array(z, dtype=float), np.array(z, dtype=float)
        zp[j], zm[j] = min(1.0, z[j] + h), max(0.0, z[j] - h)
        out[:, j] = (np.log(problem.numbers(zp)) - np.log(problem.numbers(zm))) / \
                    ((zp[j] - zm[j]) * problem.log_span[j])
    return out


def closest_equal_fit(problem: Problem, z_best, sensitivity: np.ndarray, bisections: int = 5) -> np.ndarray:
    """From the best fit, each unknown (least influential first) moved back towards its base value as far
    as all four numbers stay within the paper's printed precision of the best fit's."""
    tol = np.array([paper_precision(PAPER[k]) for k in KEYS])
    y_best = problem.numbers(z_best)
    zb = problem.base_z()
    z = np.array(z_best, dtype=float)

    def equal(zc):
        return bool(np.all(np.abs(problem.numbers(zc) - y_best) <= tol))

    for j in np.argsort(np.abs(sensitivity).sum(axis=0)):
        trial = z.copy()
        trial[j] = zb[j]
        if equal(trial):
            z = trial
            continue
        lo, hi = 0.0, 1.0            # fraction of the way back towards the base value
        for _ in range(bisections):
            mid = 0.5 * (lo + hi)
            trial[j] = z[j] + mid * (zb[j] - z[j])
            lo, hi = (mid, hi) if equal(trial) else (lo, mid)
        z[j] = z[j] + lo * (zb[j] - z[j])
    return z


def hs_error_budget(params: WristParams, duration: float = 4.0) -> dict:
    """Where the HS posture error under the implied load comes from: the same trial without the load
    (tracking alone), with the reference held at the centre (the load alone), with ideal motors beyond the
    bounds (time constant = one physics step, kp = 1e5 N m/rad), and with the reference sampled every 1 ms
    instead of every control period."""
    p0, force = implied_load_setup(params)
    lam = per_leg_to_lambda(HS_PER_LEG)

    def hs(p, **kw):
        return trial(p, lam, duration, False, **{"load": force, **kw})["rms_error"]

    ideal = with_values(p0, {"motor.time_constant": p0.simulation.timestep, "motor.kp": 1e5})
    return {"as_identified": hs(p0),
            "tracking_alone_no_load": hs(p0, load=np.zeros(3)),
            "load_alone_reference_held_at_centre": hs(p0, reference_fn=lambda t: (0.0, 0.0, 0.0)),
            "ideal_motors_T_one_step_kp_1e5": hs(ideal),
            "reference_sampled_every_1ms": hs(p0, control_dt=0.001)}


def round_sig(x: float, digits: int = 2) -> float:
    return float(f"{x:.{digits}g}")


def identify(preset: str | WristParams = "paper", duration: float = 4.0, starts=None, target=None,
             unknowns=UNKNOWNS, log=print) -> dict:
    """The whole identification; returns a JSON-ready dictionary (see the module docstring)."""
    base = load_params(preset)
    if target is None and base.spring != load_params("paper").spring:
        raise ValueError(f"preset '{base.name}': the implied load (and so the paper's numbers as targets) is "
                         f"derived from the `paper` springs (K = {load_params('paper').spring.K} N m); this preset "
                         f"has K = {base.spring.K} N m")
    problem = Problem(base, unknowns, duration, target)
    t0 = time.perf_counter()
    zb = problem.base_z()
    if starts is None:
        starts = [zb, np.full(len(zb), 0.25), np.full(len(zb), 0.75)]
    fits = []
    for z0 in starts:
        f = fit(problem, z0)
        fits.append({"start": problem.values(z0), "values": problem.values(f["z"]), "cost": f["cost"],
                     "numbers": dict(zip(KEYS, problem.numbers(f["z"]).tolist())), "z": f["z"]})
        log(f"  fit from {_fmt_values(problem.values(z0))}: {_fmt_values(problem.values(f['z']))}, "
            f"cost {f['cost']:.4g} ({f['iterations']} iterations)")
    best = min(fits, key=lambda f: f["cost"])
    sens_best = elasticities(problem, best["z"])
    z_pick = closest_equal_fit(problem, best["z"], sens_best)
    picked = {u.name: round_sig(v) for u, v in zip(unknowns, problem.values(z_pick).values())}
    y_pick = four_numbers(with_values(base, picked), duration)
    sens = elasticities(problem, problem.z_of(picked))
    p_pick = np.array([picked[u.name] for u in unknowns])
    absolute = sens * y_pick[:, None] / p_pick[None, :]
    y_base = four_numbers(base, duration)
    tol = {k: paper_precision(PAPER[k]) for k in KEYS}
    equal_sets = [f for f in fits if all(abs(f["numbers"][k] - best["numbers"][k]) <= tol[k] for k in KEYS)]
    at_bound = [u.name for u, z in zip(unknowns, problem.z_of(picked)) if z <= 1e-9 or z >= 1 - 1e-9]
    ratios = {"error_ratio_ls_over_hs": float(y_pick[0] / y_pick[1]),
              "torque_ratio_hs_over_ls": float(y_pick[3] / y_pick[2])}
    factors = {k: float(max(y / PAPER[k], PAPER[k] / y)) for k, y in zip(KEYS, y_pick)}
    met = all(f <= TARGET_FACTOR for f in factors.values()) and min(ratios.values()) >= TARGET_RATIO
    return {
        "preset": base.name, "duration_s": duration,
        "load": f"the implied load ({IMPLIED_LOAD_TORQUE} N m about the centre, gravity off)",
        "paper": {k: PAPER[k] for k in KEYS}, "paper_precision": tol,
        "unknowns": [{"name": u.name, "lo": u.lo, "hi": u.hi, "base": getattr(getattr(base, u.section), u.key),
                      "why_bounds": u.why} for u in unknowns],
        "kd_rule": "kd = base kd x sqrt(kp / base kp) (the base preset's damping ratio of the position loop)",
        "fits": [{k: v for k, v in f.items() if k != "z"} for f in fits],
        "best": {"values": best["values"], "numbers": best["numbers"], "cost": best["cost"]},
        "starts_agreeing_within_precision": len(equal_sets),
        "identified": {"values": picked, "numbers": dict(zip(KEYS, y_pick.tolist())),
                       "residuals_log": dict(zip(KEYS, np.log(y_pick / problem.target).tolist())),
                       "factor_from_paper": factors, **ratios, "at_bound": at_bound,
                       "kd": with_values(base, picked).motor.kd},
        "base_numbers": dict(zip(KEYS, y_base.tolist())),
        "elasticity": {k: dict(zip([u.name for u in unknowns], row.tolist())) for k, row in zip(KEYS, sens)},
        "elasticity_at_base": {k: dict(zip([u.name for u in unknowns], row.tolist()))
                               for k, row in zip(KEYS, elasticities(problem, problem.base_z()))},
        "sensitivity_si": {k: dict(zip([u.name for u in unknowns], row.tolist())) for k, row in zip(KEYS, absolute)},
        "hs_error_budget": hs_error_budget(with_values(base, picked), duration),
        "singular_values_errors": np.linalg.svd(sens[:2], compute_uv=False).tolist(),
        "target": {"factor": TARGET_FACTOR, "ratio": TARGET_RATIO, "met": bool(met)},
        "evaluations": problem.evaluations, "seconds": time.perf_counter() - t0,
    }


def _fmt_values(values: dict[str, float]) -> str:
    return ", ".join(f"{k.split('.')[1]} {v:.3g}" for k, v in values.items())


def report(res: dict) -> str:
    """The identification as text: values, numbers beside the paper's, residuals, sensitivities."""
    names = [u["name"] for u in res["unknowns"]]
    ident = res["identified"]
    lines = [f"identification on `{res['preset']}` under {res['load']}, {res['duration_s']:g} s trials "
             f"({res['evaluations']} simulations, {res['seconds']:.0f} s)", "",
             "| unknown | bounds | base | best fit | identified (closest to base among equal fits) |",
             "|---|---|---|---|---|"]
    for u in res["unknowns"]:
        n = u["name"]
        bound = " (at bound)" if n in ident["at_bound"] else ""
        lines.append(f"| {n} | [{u['lo']:g}, {u['hi']:g}] | {u['base']:g} | {res['best']['values'][n]:.3g} | "
                     f"{ident['values'][n]:g}{bound} |")
    lines += ["", "| number | paper | base | identified | identified / paper | log residual |",
              "|---|---|---|---|---|---|"]
    for k in KEYS:
        y = ident["numbers"][k]
        lines.append(f"| {k} ({UNITS[k]}) | {res['paper'][k]:g} | {res['base_numbers'][k]:.3g} | {y:.3g} | "
                     f"{y / res['paper'][k]:.2f} | {ident['residuals_log'][k]:+.3f} |")
    base_e = res["base_numbers"]["rms_error_ls"] / res["base_numbers"]["rms_error_hs"]
    base_t = res["base_numbers"]["rms_torque_hs"] / res["base_numbers"]["rms_torque_ls"]
    lines.append(f"| error ratio LS/HS | {res['paper']['rms_error_ls'] / res['paper']['rms_error_hs']:.3g} | "
                 f"{base_e:.3g} | {ident['error_ratio_ls_over_hs']:.3g} | | |")
    lines.append(f"| torque ratio HS/LS | {res['paper']['rms_torque_hs'] / res['paper']['rms_torque_ls']:.3g} | "
                 f"{base_t:.3g} | {ident['torque_ratio_hs_over_ls']:.3g} | | |")
    lines += ["", "elasticities d ln(number) / d ln(parameter) at the identified set:", "",
              "| number | " + " | ".join(n.split(".")[1] for n in names) + " |", "|---|" + "---|" * len(names)]
    for k in KEYS:
        lines.append(f"| {k} | " + " | ".join(f"{res['elasticity'][k][n]:+.3f}" for n in names) + " |")
    lines += ["", "the same at the base preset's values:", "",
              "| number | " + " | ".join(n.split(".")[1] for n in names) + " |", "|---|" + "---|" * len(names)]
    for k in KEYS:
        lines.append(f"| {k} | " + " | ".join(f"{res['elasticity_at_base'][k][n]:+.3f}" for n in names) + " |")
    lines += ["", "sensitivities in SI units, d(number) / d(parameter):", "",
              "| number | " + " | ".join(n.split(".")[1] for n in names) + " |", "|---|" + "---|" * len(names)]
    for k in KEYS:
        lines.append(f"| {k} | " + " | ".join(f"{res['sensitivity_si'][k][n]:+.3g}" for n in names) + " |")
    sv = res["singular_values_errors"]
    lines += ["", "HS posture error (rad) at the identified set: " + ", ".join(
        f"{k.replace('_', ' ')} {v:.3g}" for k, v in res["hs_error_budget"].items())]
    lines += ["", f"singular values of the two error rows: {', '.join(f'{s:.3g}' for s in sv)}; "
              f"{res['starts_agreeing_within_precision']} of {len(res['fits'])} starts end within the paper's "
              f"precision of the best fit",
              f"target (each number within {res['target']['factor']:g}x, both ratios >= {res['target']['ratio']:g}): "
              + ("MET" if res["target"]["met"] else "NOT MET")]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m vswrist_gym.identify", description=__doc__.split("\n")[0])
    parser.add_argument("--preset", default="paper", help="base preset (the springs the implied load assumes)")
    parser.add_argument("--out", default=None, help="directory for identify.json (default: print only)")
    parser.add_argument("--quick", action="store_true", help="1.5 s trials instead of 4 s (a rough fit)")
    args = parser.parse_args(argv)
    try:
        res = identify(args.preset, duration=1.5 if args.quick else 4.0)
    except ValueError as exc:          # bad preset (ParamsError is a ValueError): one line, nothing written
        print(f"vswrist identify: {exc}", file=sys.stderr)
        return 2
    print(report(res))
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "identify.json").write_text(json.dumps(res, indent=2))
        print(f"identify.json in {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
