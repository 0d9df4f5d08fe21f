"""How many evaluation episodes the issue's "non-overlapping 95 % intervals" verdict needs, per task.

    python experiments/separability/separability.py [--seeds 5] [--json PATH]

The results protocol evaluates seed s on its own episodes (reset seeds 1,000,000 + 1000 s + i), so even a
deterministic agent's per-seed mean return varies from seed to seed with the episodes drawn: by sd / sqrt(M)
for M episodes per seed, sd being the spread of one episode's return over the task's randomisation. Two
Student-t intervals over n seeds then stop overlapping only when the gain exceeds about

    g_min = 2 t(0.975, n - 1) sd / sqrt(n M)

(both agents with the same episode spread and no seed-to-seed spread of their own: a lower bound for a learned
agent, whose training seeds add spread). This script reads, from the committed evaluations, each task's best
constant stiffness and the returns of its episodes (sd over all of them), and the headroom table
(docs/figures/headroom.json: the best schedule's paired gain over the best constant on held-out episodes), and
prints g_min at the committed episode count and the episodes per seed at which g_min falls to the whole headroom
and to 75 % of it. A task whose full headroom is below g_min at the committed count cannot separate there, however
good the policy; it can with the printed number of episodes, if the policy reaches that gain.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
from pathlib import Path

from scipy import stats

ROOT = Path(__file__).resolve().parent
# the largest committed stiffness-track evaluation of each task (the analytic baselines are the same agents on
# either track: the residual mode's zero action is the task's own reference at a constant stiffness)
SOURCES = {
    "Polish": "long_stiffness/Polish",      # VSWrist/Polish-v0
    "Impact": "long_stiffness/Impact",
    "Insertion": "long_stiffness/Insertion",
    "Drill": "ablation_stiffness/Drill",
    "LoadHold": "long200/LoadHold",          # full track's table, 200 episodes per seed: the same baselines
    "Hammer": "hammer_stiffness/Hammer",
}


def baseline_returns(folder: Path) -> tuple[str, dict[int, list[float]]]:
    """(best constant's name, its returns per seed) from ``<folder>/eval/analytic_*/metrics.csv``."""
    best, best_mean, best_rows = "", -math.inf, {}
    for f in sorted((folder / "eval").glob("analytic_*/metrics.csv")):
        per_seed: dict[int, list[float]] = {}
        with f.open() as fh:
            for r in csv.DictReader(fh):
                per_seed.setdefault(int(r["seed"]), []).append(float(r["return"]))
        allr = [x for v in per_seed.values() for x in v]
        mean = sum(allr) / len(allr)
        if mean > best_mean:
            best, best_mean, best_rows = f.parent.name, mean, per_seed
    if not best:
        raise SystemExit(f"no analytic evaluations under {folder / 'eval'}")
    return best, best_rows


def sd(xs: list[float]) -> float:
    m = sum(xs) / len(xs)
    return math.sqrt(sum((x - m) ** 2 for x in xs) / (len(xs) - 1))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=5, help="seeds n of the verdict (default 5)")
    ap.add_argument("--json", metavar="PATH", help="also write the table as JSON")
    args = ap.parse_args(argv)
    if args.seeds < 2:
        raise SystemExit("--seeds must be >= 2 (a Student-t interval needs two seeds)")
    headroom = json.loads((ROOT.parent / "docs" / "figures" / "headroom.json").read_text())["tasks"]
    n = args.seeds
    t = float(stats.t.ppf(0.975, n - 1))
    rows = []
    print(f"n = {n} seeds, t(0.975, {n - 1}) = {t:.3f}; returns per episode\n")
    print(f"{'task':<10}{'source':<26}{'best const':>11}{'M':>5}{'episode sd':>11}{'seed-mean sd':>13}"
          f"{'g_min(M)':>10}{'headroom':>10}{'M for 100 %':>12}{'M for 75 %':>11}")
    for task, src in SOURCES.items():
        name, per_seed = baseline_returns(ROOT / src)
        allr = [x for v in per_seed.values() for x in v]
        m = min(len(v) for v in per_seed.values())
        s_ep = sd(allr)
        means = [sum(v) / len(v) for v in per_seed.values()]
        s_mean = sd(means) if len(means) > 1 else float("nan")
        g_min = 2.0 * t * s_ep / math.sqrt(n * m)
        h = float(headroom[task]["headroom"])
        need = {f: math.ceil((2.0 * t * s_ep / (f * h)) ** 2 / n) for f in (1.0, 0.75)}
        rows.append({"task": task, "source": src, "best_constant": name, "episodes_per_seed": m,
                     "episode_sd": s_ep, "seed_mean_sd": s_mean, "g_min": g_min, "headroom": h,
                     "episodes_for_headroom": need[1.0], "episodes_for_75pct": need[0.75]})
        print(f"{task:<10}{src:<26}{name.replace('analytic_', ''):>11}{m:>5}{s_ep:>11.1f}{s_mean:>13.1f}"
              f"{g_min:>10.1f}{h:>10.1f}{need[1.0]:>12}{need[0.75]:>11}")
    print("\nseed-mean sd: the spread of the best constant's per-seed means as committed (expected "
          "~ episode sd / sqrt(M)).\ng_min(M): the smallest gain whose intervals can separate at the committed M; "
          "M for 100 % / 75 %: episodes per seed at which g_min equals the whole headroom / 75 % of it.")
    if args.json:
        Path(args.json).write_text(json.dumps({"seeds": n, "t": t, "rows": rows}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
