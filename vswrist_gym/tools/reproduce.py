"""``vswrist reproduce --out DIR``: the paper's section 5 (figure 3a/3b/3c and the RMS numbers) regenerated.

* Fig. 3a: coupler compliance ellipses at the central posture for four stiffness levels (complete static
  stiffness, and the paper's J_a^T Sigma_s J_a dashed). Human wrist compliance C_h (Pando et al. 2014) is
  not shown: no published numeric matrix was found offline, and the figure says so.
* Fig. 3b: the elastic (spring) torque of each leg at those four levels, with the coupler stiffness.
* Fig. 3c: posture tracking at low (LS) and high (HS) stiffness with a 1.5 kg load at the hand centre from
  t = 0.5 s, in the MuJoCo simulator, under the paper's controller (``AnalyticController``).
* ``DIR/results.json``: per preset the RMS posture error and RMS elastic torque of both trials beside the
  paper's numbers, the HS/LS ratios and the criteria, and every choice the paper leaves open (``choices``).
  For the presets with the `paper` springs (``paper``, ``paper_identified``: the motor dynamics identified by
  ``vswrist_gym.identify``) also the trials under the load the paper's numbers imply
  (``<preset>_implied_load``) and with the forearm vertical (``forearm_vertical``), and
  ``fig_rms_against_paper.png`` sets the four numbers of every run over the paper's.
* ``--identify``: the identification itself (``vswrist_gym.identify``), into ``DIR/identify.json``.

Choices the paper leaves open (also in ``results.json`` and docs/reproduce.md):

* LS and HS: the internal torques whose per-leg elastic torque at rest is the paper's RMS elastic torque,
  0.07 N m and 1.72 N m (lam = sqrt(3) x that at the central posture, where N = -(1, 1, 1)/sqrt(3)).
* Four stiffness levels of Fig. 3a/3b: per-leg elastic torques 0.07, 0.3, 0.8, 1.72 N m.
* Gravity: the preset's ``environment.gravity`` (both presets: -Z_b, forearm horizontal), acting on the whole
  device; the 1.5 kg load is its weight, 1.5 kg x gravity, applied at the hand point (``sim.apply_wrench``).
  The controller's gravity feed-forward holds the hand's own (known) weight; the load is an unknown
  disturbance to it (``--no-gravity-compensation`` runs the paper's controller without it).
* Trajectory: RUD(t) = 0.15 sin(2 pi t / 2 s), FE(t) = 0.3 sin(2 pi t / 4 s), PS = 0, for 4 s (1.5 s with
  ``--quick``); control period 0.01 s.
* RMS posture error: over the control samples of the whole trial, of the norm of the (RUD, FE) error against
  the reference at the same instant. RMS elastic torque: over the samples and the three legs.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import platform
import time
from pathlib import Path

import numpy as np

from ..control import AnalyticController
from ..params import DEVICE_PRESETS, IDENTIFIED_PRESETS, PRESETS, load_params
from ..paper_trial import (CONTROL_DT, HS_PER_LEG, IMPLIED_LOAD_TORQUE, LOAD_MASS, LOAD_TIME,  # noqa: F401
                           LS_PER_LEG, PAPER, implied_load_scenario, implied_load_setup, per_leg_to_lambda,
                           reference, trial)
from ..stiffness import coupler_stiffness, spring_torque

logger = logging.getLogger(__name__)

NUMBER_KEYS = tuple(PAPER)
LEVELS_PER_LEG = (0.07, 0.3, 0.8, 1.72)        # N m, per-leg elastic torque of the four levels
CRITERION_RATIO = 10.0


def _preset_results(params, duration: float, gravity_compensation: bool) -> tuple[dict, dict]:
    ls = trial(params, per_leg_to_lambda(LS_PER_LEG), duration, gravity_compensation)
    hs = trial(params, per_leg_to_lambda(HS_PER_LEG), duration, gravity_compensation)
    u0 = np.zeros(2)
    k_ls = np.linalg.eigvalsh(coupler_stiffness(u0, ls["lam"], params))
    k_hs = np.linalg.eigvalsh(coupler_stiffness(u0, hs["lam"], params))
    hand_lever = params.inertia.hand_offset + params.geometry.d * math.sin(params.geometry.alpha / 2.0)
    out = {
        "rms_error_ls": ls["rms_error"], "rms_error_hs": hs["rms_error"],
        "rms_torque_ls": ls["rms_torque"], "rms_torque_hs": hs["rms_torque"],
        "error_ratio_ls_over_hs": ls["rms_error"] / hs["rms_error"],
        "torque_ratio_hs_over_ls": hs["rms_torque"] / ls["rms_torque"],
        "max_error_ls": ls["max_error"], "max_error_hs": hs["max_error"],
        "lambda_ls": ls["lam"], "lambda_hs": hs["lam"],
        "stiffness_eig_ls": k_ls.tolist(), "stiffness_eig_hs": k_hs.tolist(),
        "status_ls": ls["status"], "status_hs": hs["status"],
        # the load torque the paper's own numbers imply: stiffness x the paper's RMS error, in each trial
        "paper_implied_load_torque_ls": float(k_ls.mean() * PAPER["rms_error_ls"]),
        "paper_implied_load_torque_hs": float(k_hs.mean() * PAPER["rms_error_hs"]),
        "load_torque_at_centre": float(LOAD_MASS * np.linalg.norm(params.environment.gravity) * hand_lever),
    }
    return out, {"ls": ls, "hs": hs}


def forearm_vertical_scenario(params, duration: float, gravity_compensation: bool = True) -> dict:
    """The other orientation the paper may have meant: forearm vertical, so gravity and the 1.5 kg load act
    along the hand axis (X_b) at the central posture. ``hand_down``: gravity along +X_b (the hand hangs below
    the wrist, the load pulls the posture back to the centre); ``hand_up``: along -X_b (an inverted pendulum)."""
    out = {}
    for sense, sign in (("hand_down", 1.0), ("hand_up", -1.0)):
        g = float(np.linalg.norm(params.environment.gravity))
        p = params.replace(environment={"gravity": [sign * g, 0.0, 0.0]})
        ls = trial(p, per_leg_to_lambda(LS_PER_LEG), duration, gravity_compensation)
        hs = trial(p, per_leg_to_lambda(HS_PER_LEG), duration, gravity_compensation)
        out[sense] = {"gravity": [sign * g, 0.0, 0.0],
                      "rms_error_ls": ls["rms_error"], "rms_error_hs": hs["rms_error"],
                      "rms_torque_ls": ls["rms_torque"], "rms_torque_hs": hs["rms_torque"],
                      "error_ratio_ls_over_hs": ls["rms_error"] / hs["rms_error"],
                      "torque_ratio_hs_over_ls": hs["rms_torque"] / ls["rms_torque"],
                      "max_error_ls": ls["max_error"], "max_error_hs": hs["max_error"],
                      "status_ls": ls["status"], "status_hs": hs["status"]}
    return out


def figure_3ab(params, out_dir: Path) -> tuple[Path, Path]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    u0 = np.zeros(2)
    ctrl = AnalyticController(params)
    ctrl_paper = AnalyticController(params, include_load_term=False)
    phi = np.linspace(0, 2 * np.pi, 200)
    circle = np.vstack([np.cos(phi), np.sin(phi)])
    colors = plt.cm.viridis(np.linspace(0.0, 0.85, len(LEVELS_PER_LEG)))
    fig, ax = plt.subplots(figsize=(4.8, 4.8))
    torques, stiff = [], []
    for c, per_leg in zip(colors, LEVELS_PER_LEG):
        lam = per_leg_to_lambda(per_leg)
        ctrl.reset((0, 0, 0), lam=lam)
        ctrl_paper.reset((0, 0, 0), lam=lam)
        C = ctrl.compliance()
        for Cx, ls_, lab in ((C, "-", f"{per_leg:g} N m/leg: C = {np.linalg.eigvalsh(C).mean():.3g} rad/(N m)"),
                             (ctrl_paper.compliance(), "--", None)):
            e = Cx @ circle
            ax.plot(e[1], e[0], ls_, color=c, label=lab)           # x: FE, y: RUD
        theta = ctrl.step((0, 0, 0), lam=lam)
        q1, _, _ = ctrl.kinematics_at(u0)
        delta = q1 - theta[:3]
        torques.append(spring_torque(delta, params))
        stiff.append(np.linalg.eigvalsh(ctrl.stiffness()).mean())
    ax.set_aspect("equal")
    ax.set_xlabel("FE, rad/(N m)")
    ax.set_ylabel("RUD, rad/(N m)")
    ax.set_title(f"Fig. 3a: coupler compliance, central posture ({params.name})", fontsize=9)
    fig.text(0.01, 0.01, "solid: complete stiffness (with load term); dashed: paper's J_a^T Sigma_s J_a.\n"
             "Human C_h (Pando et al. 2014): no numeric values found offline, not shown.", fontsize=7, va="bottom")
    ax.legend(fontsize=6.5, loc="upper right", title="elastic torque per leg", title_fontsize=6.5)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    pa = out_dir / f"fig3a_compliance_{params.name}.png"
    fig.savefig(pa, dpi=100)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(5.0, 3.4))
    torques = np.array(torques)
    x = np.arange(len(LEVELS_PER_LEG))
    for k, name in enumerate("ABC"):
        ax.bar(x + (k - 1) * 0.25, torques[:, k], width=0.25, label=f"leg {name}")
    ax.set_xticks(x, [f"{s:.3g} N m/rad" for s in stiff], fontsize=7)
    ax.set_xlabel("coupler stiffness (mean eigenvalue), central posture")
    ax.set_ylabel("elastic torque tau_s, N m")
    ax.set_title(f"Fig. 3b: elastic torque of the four levels ({params.name})", fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    pb = out_dir / f"fig3b_elastic_torque_{params.name}.png"
    fig.savefig(pb, dpi=100)
    plt.close(fig)
    return pa, pb


def figure_3c(params, runs: dict, res: dict, out_dir: Path, tag: str = "load", note: str = "1.5 kg load") -> Path:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.0, 3.6))
    ls, hs = runs["ls"], runs["hs"]
    for j, name, color in ((1, "FE", "tab:blue"), (0, "RUD", "tab:red")):
        ax.plot(ls["t"], ls["ref"][:, j], "-", color=color, lw=1.0, label=f"{name} reference")
        ax.plot(ls["t"], ls["posture"][:, j], "--", color=color, lw=1.2, label=f"{name} LS")
        ax.plot(hs["t"], hs["posture"][:, j], "-", marker="D", markersize=3, markevery=10, color=color, lw=0.6,
                label=f"{name} HS")
    ax.axvline(LOAD_TIME, color="k", lw=0.6, ls=":")
    ax.text(LOAD_TIME, ax.get_ylim()[1], " " + note, fontsize=7, va="top")
    ax.set_xlabel("time, s")
    ax.set_ylabel("posture, rad")
    ax.set_title(f"Fig. 3c ({params.name}): RMS error LS {res['rms_error_ls']:.3g} rad, "
                 f"HS {res['rms_error_hs']:.3g} rad;"
                 f" RMS torque LS {res['rms_torque_ls']:.3g}, HS {res['rms_torque_hs']:.3g} N m", fontsize=7.5)
    ax.legend(fontsize=6.5, ncol=2, loc="lower left")
    fig.tight_layout()
    path = out_dir / f"fig3c_{tag}_{params.name}.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def run(out: str | Path, quick: bool = False, presets=DEVICE_PRESETS + IDENTIFIED_PRESETS,
        gravity_compensation: bool = True) -> dict:
    """Regenerate figures and ``results.json`` into ``out``; returns the results."""
    out_dir = Path(out)
    out_dir.mkdir(parents=True, exist_ok=True)
    duration = 1.5 if quick else 4.0
    results: dict = {
        "paper_reported": PAPER,
        "choices": {
            "ls": f"internal torque with per-leg elastic torque {LS_PER_LEG} N m at rest "
                  f"(lam = {per_leg_to_lambda(LS_PER_LEG):.4f} N m)",
            "hs": f"internal torque with per-leg elastic torque {HS_PER_LEG} N m at rest "
                  f"(lam = {per_leg_to_lambda(HS_PER_LEG):.4f} N m)",
            "stiffness_levels_per_leg_N_m": list(LEVELS_PER_LEG),
            "gravity": "each preset's environment.gravity, on the whole device",
            "load": f"{LOAD_MASS} kg x gravity as a force at the hand point from t = {LOAD_TIME} s (sim.apply_wrench)",
            "gravity_compensation": ("controller feed-forward of the hand and coupler weight (the load is not "
                                     "compensated)") if gravity_compensation else "off (the paper's controller)",
            "trajectory": "RUD = 0.15 sin(2 pi t / 2 s), FE = 0.3 sin(2 pi t / 4 s), PS = 0 (rad)",
            "duration_s": duration, "control_dt_s": CONTROL_DT,
            "rms_error": "RMS over control samples of |(RUD, FE) - reference| (rad)",
            "rms_torque": "RMS over control samples and the three legs of the spring torque (N m)",
            "human_compliance": "Pando et al. 2014 values not found offline; not shown",
        },
        "quick": quick,
        "machine": f"{platform.node()} ({platform.machine()}), {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}",
    }
    figures = []
    implied_presets = []
    from vswrist_gym.agents.progress import bar

    paper_springs = load_params("paper").spring
    # one step per preset, then one per preset with the paper's springs (its implied-load scenarios)
    shown = bar(total=len(presets) + sum(load_params(n).spring == paper_springs for n in presets),
                desc="reproduce: presets", unit="preset")
    for name in presets:
        params = load_params(name)
        res, runs = _preset_results(params, duration, gravity_compensation)
        results[name] = res
        if name not in IDENTIFIED_PRESETS:      # same springs and kinematics as `paper`: the same 3a/3b
            figures += [str(p) for p in figure_3ab(params, out_dir)]
        figures.append(str(figure_3c(params, runs, res, out_dir)))
        if params.spring == paper_springs:  # the implied load is derived from these springs
            implied_presets.append(name)
        shown.update()
    for name in implied_presets:
        params = load_params(name)
        implied, runs = implied_load_scenario(params, duration)
        implied["passed"] = bool(implied["error_ratio_ls_over_hs"] >= CRITERION_RATIO
                                 and implied["torque_ratio_hs_over_ls"] >= CRITERION_RATIO)
        results[f"{name}_implied_load"] = implied
        figures.append(str(figure_3c(params, runs, implied, out_dir, "implied_load",
                                     f"{IMPLIED_LOAD_TORQUE} N m load, gravity off")))
        results.setdefault("forearm_vertical", {})[name] = forearm_vertical_scenario(params, duration,
                                                                                     gravity_compensation)
        shown.update()
    shown.close()
    default = results.get("paper")
    if default is not None:
        results["criteria"] = {
            "error_ratio_ls_over_hs": default["error_ratio_ls_over_hs"],
            "torque_ratio_hs_over_ls": default["torque_ratio_hs_over_ls"],
            "required_min": CRITERION_RATIO,
            "passed": bool(default["error_ratio_ls_over_hs"] >= CRITERION_RATIO
                           and default["torque_ratio_hs_over_ls"] >= CRITERION_RATIO),
        }
    if implied_presets:
        figures.append(str(figure_comparison(results, presets, implied_presets, out_dir)))
    results["figures"] = [Path(f).name for f in figures]
    (out_dir / "results.json").write_text(json.dumps(results, indent=2))
    return results


def figure_comparison(results: dict, presets, implied_presets, out_dir: Path) -> Path:
    """The four RMS numbers over the paper's, per preset, for both load readings (log scale, 1.5x band)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(8.4, 3.4), sharey=True)
    x = np.arange(len(NUMBER_KEYS))
    for ax, (title, keys) in zip(axes, ((f"{LOAD_MASS} kg load (the paper's text)", list(presets)),
                                        (f"{IMPLIED_LOAD_TORQUE} N m load (the paper's numbers imply)",
                                         [f"{n}_implied_load" for n in implied_presets]))):
        width = 0.8 / max(len(keys), 1)
        for i, key in enumerate(keys):
            name = key.replace("_implied_load", "")
            ratio = [results[key][k] / PAPER[k] for k in NUMBER_KEYS]
            ax.bar(x + (i - (len(keys) - 1) / 2) * width, ratio, width=width, label=name,
                   color=plt.cm.tab10(list(presets).index(name)))
        ax.axhspan(1 / 1.5, 1.5, color="0.85", zorder=0, label="within 1.5x")
        ax.axhline(1.0, color="k", lw=0.6)
        ax.set_yscale("log")
        ax.set_xticks(x, ["error LS", "error HS", "torque LS", "torque HS"], fontsize=7.5)
        ax.set_title(title, fontsize=8.5)
        ax.legend(fontsize=6.5)
    axes[0].set_ylabel("ours / paper's RMS number")
    fig.tight_layout()
    path = out_dir / "fig_rms_against_paper.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def _table(results: dict, columns, headers=None) -> str:
    """The paper's four numbers and ratios beside ours, one column per ``results`` entry."""
    headers = list(columns) if headers is None else headers
    rows = ["| quantity | paper (reported) | " + " | ".join(f"ours: {h}" for h in headers) + " |",
            "|---|---|" + "---|" * len(columns)]
    for key in NUMBER_KEYS:
        unit = "rad" if "error" in key else "N m"
        ours = " | ".join(f"{results[p][key]:.3g}" for p in columns)
        rows.append(f"| {key} ({unit}) | {PAPER[key]:g} | {ours} |")
    for key, paper in (("error_ratio_ls_over_hs", PAPER["rms_error_ls"] / PAPER["rms_error_hs"]),
                       ("torque_ratio_hs_over_ls", PAPER["rms_torque_hs"] / PAPER["rms_torque_ls"])):
        rows.append(f"| {key} | {paper:.3g} | " + " | ".join(f"{results[p][key]:.3g}" for p in columns) + " |")
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="vswrist reproduce", description=__doc__.split("\n")[0])
    parser.add_argument("--out", required=True, help="output directory for the figures and results.json")
    parser.add_argument("--quick", action="store_true", help="reduced run (1.5 s trials) for the test suite")
    parser.add_argument("--presets", nargs="+", default=list(DEVICE_PRESETS + IDENTIFIED_PRESETS),
                        choices=list(PRESETS))
    parser.add_argument("--no-gravity-compensation", action="store_true",
                        help="run the paper's controller without the hand-weight feed-forward")
    parser.add_argument("--identify", action="store_true",
                        help="instead: identify the unknown motor dynamics from the paper's four numbers "
                             "(vswrist_gym.identify; minutes) and write identify.json")
    args = parser.parse_args(argv)
    if args.identify:
        from .. import identify
        return identify.main(["--out", args.out] + (["--quick"] if args.quick else []))
    results = run(args.out, quick=args.quick, presets=args.presets,
                  gravity_compensation=not args.no_gravity_compensation)
    print(f"{LOAD_MASS} kg load at the hand (the paper's text):")
    print(_table(results, args.presets))
    if "criteria" in results:
        c = results["criteria"]
        print(f"criteria (default preset, ratios >= {c['required_min']:g}): "
              f"error ratio {c['error_ratio_ls_over_hs']:.3g}, "
              f"torque ratio {c['torque_ratio_hs_over_ls']:.3g} -> {'PASS' if c['passed'] else 'FAIL'}")
    implied = [k for k in results if k.endswith("_implied_load")]
    if implied:
        print(f"\nthe load the paper's numbers imply ({results[implied[0]]['description']}):")
        print(_table(results, implied, [k.replace("_implied_load", "") for k in implied]))
        print("ratios >= " + f"{CRITERION_RATIO:g}: " + ", ".join(
            f"{k.replace('_implied_load', '')} {'PASS' if results[k]['passed'] else 'FAIL'}" for k in implied))
    for name, senses in results.get("forearm_vertical", {}).items():
        for sense, d in senses.items():
            print(f"forearm vertical ({sense}), {LOAD_MASS} kg along the hand axis, {name}: RMS error LS "
                  f"{d['rms_error_ls']:.3g} / HS {d['rms_error_hs']:.3g} rad, RMS torque LS {d['rms_torque_ls']:.3g} / "
                  f"HS {d['rms_torque_hs']:.3g} N m (ratios {d['error_ratio_ls_over_hs']:.3g} / "
                  f"{d['torque_ratio_hs_over_ls']:.3g})")
    logger.info(f"wrote the figures and results.json in {args.out}")
    return 0


if __name__ == "__main__":
    from vswrist_gym.cli import run_tool

    raise SystemExit(run_tool(main))
