"""The stiffness contribution per task: the full track's return minus the posture-only ablation's, on the same
evaluation episodes: what the learned stiffness adds to a policy that also trims the posture.

    python -m vswrist_gym.tools.contribution --full DIR --posture-only DIR
                                             [--agent ppo] [--tasks Polish ...] [--json PATH]

Both folders are `vswrist compare`/`vswrist sweep` outputs (``<DIR>/<Task>/eval/<agent>/metrics.json``), trained
with the same entry and seeds, the ablation with ``residual.stiffness_scale: 0`` (the stiffness held at the
task's best constant command). Episodes are paired by (training seed, reset seed); per seed the mean difference
over its episodes, then the mean and the Student-t 95 % interval over seeds (the seed is the unit of
replication). The contribution is positive where that interval lies above 0.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

TASKS = ("Polish", "Impact", "LoadHold", "Insertion", "Drill")


class ContributionError(ValueError):
    """A metrics file that is missing, unreadable or not paired with its counterpart; names the file."""


def _episodes(path: Path) -> dict[tuple[int, int], float]:
    try:
        doc = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ContributionError(f"{path}: cannot read the metrics ({exc})") from None
    try:
        return {(int(e["seed"]), int(e["reset_seed"])): float(e["return"]) for e in doc["episodes"]}
    except (KeyError, TypeError, ValueError) as exc:
        raise ContributionError(f"{path}: not a `vswrist evaluate` metrics file (episodes[].seed/reset_seed/return: "
                                f"{exc})") from None


def contribution(full: Path, ablation: Path) -> dict:
    """Paired full - posture-only returns of one task (``metrics.json`` paths); see the module docstring."""
    from vswrist_gym.agents.protocol import mean_ci

    a, b = _episodes(full), _episodes(ablation)
    common = sorted(set(a) & set(b))
    if not common:
        raise ContributionError(f"{full} and {ablation} share no (seed, reset seed) episode")
    seeds = sorted({s for s, _ in common})
    per_seed = [float(np.mean([a[k] - b[k] for k in common if k[0] == s])) for s in seeds]
    mean = lambda d, s: float(np.mean([d[k] for k in common if k[0] == s]))  # noqa: E731
    return {"seeds": seeds, "episodes": len(common), "per_seed": per_seed,
            "full": mean_ci([mean(a, s) for s in seeds]), "posture_only": mean_ci([mean(b, s) for s in seeds]),
            "contribution": mean_ci(per_seed)}


def _ci(c: dict) -> str:
    if math.isnan(c["low"]):
        return f"{c['mean']:+.1f}"
    return f"{c['mean']:+.1f} [{c['low']:+.1f}, {c['high']:+.1f}]"


def table(results: dict[str, dict]) -> str:
    lines = ["| task | seeds x episodes | full track | posture only | stiffness contribution (paired) | verdict |",
             "|---|---|---|---|---|---|"]
    for task, r in results.items():
        c = r["contribution"]
        verdict = ("no interval" if math.isnan(c["low"]) else "**positive**" if c["low"] > 0
                   else "negative" if c["high"] < 0 else "not distinguishable from 0")
        lines.append(f"| {task} | {len(r['seeds'])} x {r['episodes'] // len(r['seeds'])} | {r['full']['mean']:.1f} | "
                     f"{r['posture_only']['mean']:.1f} | {_ci(c)} | {verdict} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m vswrist_gym.tools.contribution", description=__doc__.split("\n\n")[0])
    p.add_argument("--full", required=True, help="compare/sweep output of the full track")
    p.add_argument("--posture-only", required=True, help="the posture-only ablation's output")
    p.add_argument("--agent", default="ppo", help="the agent's folder under <Task>/eval (default ppo)")
    p.add_argument("--tasks", nargs="+", default=None, help="short task names (default: every task both hold)")
    p.add_argument("--json", default=None, help="also write the results as JSON")
    args = p.parse_args(argv)
    full, abl = Path(args.full), Path(args.posture_only)
    tasks = args.tasks or [t for t in TASKS if (full / t / "eval" / args.agent / "metrics.json").is_file()
                           and (abl / t / "eval" / args.agent / "metrics.json").is_file()]
    if not tasks:
        p.error(f"no task has {args.agent} metrics in both {full} and {abl}")
    try:
        results = {t: contribution(full / t / "eval" / args.agent / "metrics.json",
                                   abl / t / "eval" / args.agent / "metrics.json") for t in tasks}
    except ContributionError as exc:
        p.error(str(exc))
    print(table(results))
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    from vswrist_gym.cli import run_tool

    raise SystemExit(run_tool(main))
