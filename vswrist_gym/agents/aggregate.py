"""Scores aggregated across tasks, with the statistics of rliable (Agarwal et al., NeurIPS 2021).

Per-task Student-t intervals (`vswrist compare`) answer "does this agent beat the best constant stiffness on this
task?". Across tasks the field reports the interquartile mean (IQM) of normalised scores with stratified-bootstrap
intervals, the probability of improvement and performance profiles; this module computes those from the
`summary.json` files that `vswrist compare` writes, re-running nothing.

Normalised score, per task and seed: 0 is the best fixed stiffness of the same compare run (on the same
evaluation episodes, so the difference is paired), 1 is the headroom table's best schedule, i.e.

    score = (return_agent - return_best_constant) / headroom

where `headroom` is the paired difference in return of the task's best hand-written rule or optimised schedule
over the best constant (the probe's headroom table). A score above 1 beats the best schedule found by hand.

    vswrist aggregate --run PPO=DIR:PPO --run SAC=DIR2:SAC --headroom docs/figures/headroom.json --out OUT

where DIR and DIR2 are `vswrist compare --out` (or `vswrist sweep` grid) output folders.
"""

from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from vswrist_gym.agents.progress import bar

logger = logging.getLogger(__name__)

INSTALL_HINT = 'rliable is not installed: pip install -e ".[stats]"'


class AggregateError(ValueError):
    """A results or headroom file that cannot be aggregated; the message names the file and the field."""


def _rliable():
    try:
        from rliable import library, metrics, plot_utils
    except ImportError as exc:  # optional extra: say what to install in one line
        raise AggregateError(INSTALL_HINT) from exc
    return library, metrics, plot_utils


def _short(task: str) -> str:
    """'VSWrist/Polish-v1' -> 'Polish'; short names pass through."""
    return task.split("/")[-1].split("-v")[0]


def load_headroom(path: str | Path) -> dict[str, float]:
    """Task -> headroom (the best schedule's paired return gain over the best constant, > 0)."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise AggregateError(f"{path}: cannot read the headroom file ({exc})") from exc
    tasks = data.get("tasks", data) if isinstance(data, dict) else None
    if not isinstance(tasks, dict):
        raise AggregateError(f"{path}: expected a mapping task -> {{'headroom': float}}")
    out = {}
    for task, entry in tasks.items():
        value = entry.get("headroom") if isinstance(entry, dict) else entry
        if not isinstance(value, (int, float)) or not np.isfinite(value) or value <= 0:
            raise AggregateError(f"{path}: tasks.{task}.headroom must be a finite number > 0, got {value!r}")
        out[_short(task)] = float(value)
    return out


def load_summaries(result_dir: str | Path) -> dict[str, dict]:
    """Task -> summary.json of one `vswrist compare` output (a directory of task sub-directories, or one task)."""
    result_dir = Path(result_dir)
    files = [result_dir / "summary.json"] if (result_dir / "summary.json").is_file() \
        else sorted(result_dir.glob("*/summary.json"))
    if not files:
        raise AggregateError(f"{result_dir}: no summary.json (expected the output of `vswrist compare`)")
    single = len(files) == 1 and files[0].parent == result_dir
    out = {}
    for f in files:
        try:
            s = json.loads(f.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise AggregateError(f"{f}: cannot read ({exc})") from exc
        if "task" not in s or "rows" not in s:
            raise AggregateError(f"{f}: not a compare summary (needs 'task' and 'rows')")
        # in a folder of task folders only <Task>/summary.json counts: another run of the same task beside them
        # (a folder such as main_job/ of a second Polish run) must not replace it
        if single or f.parent.name == _short(s["task"]):
            out[_short(s["task"])] = s
    return out


def _best_constant(rows: Mapping[str, dict]) -> str:
    baselines = [k for k in rows if k.startswith("analytic")]
    if not baselines:
        raise AggregateError("the summary has no fixed-stiffness baseline rows ('analytic:...')")
    return max(baselines, key=lambda k: rows[k]["return"]["mean"])


def normalised(summary: dict, agent: str, headroom: float) -> dict[int, float]:
    """Seed -> normalised score of `agent`, paired seed by seed with the best constant of the same run."""
    rows = summary["rows"]
    if agent not in rows:
        raise AggregateError(f"{summary['task']}: no agent {agent!r} (has {sorted(rows)})")
    best = rows[_best_constant(rows)]["return"]
    ret = rows[agent]["return"]
    base = dict(zip(best["seeds"], best["per_seed"]))
    missing = [s for s in ret["seeds"] if s not in base]
    if missing:
        raise AggregateError(f"{summary['task']}: seeds {missing} of {agent} have no baseline on the same episodes")
    return {s: (r - base[s]) / headroom for s, r in zip(ret["seeds"], ret["per_seed"])}


def score_matrix(summaries: Mapping[str, dict], agent: str, headroom: Mapping[str, float],
                 tasks: Sequence[str]) -> np.ndarray:
    """(runs, tasks) normalised scores, rliable's layout; runs are the seeds every task shares."""
    per_task = []
    for task in tasks:
        if task not in summaries:
            raise AggregateError(f"{agent}: no results for task {task}")
        if task not in headroom:
            raise AggregateError(f"headroom file has no entry for task {task}")
        per_task.append(normalised(summaries[task], agent, headroom[task]))
    seeds = sorted(set.intersection(*(set(p) for p in per_task)))
    if len(seeds) < 2:
        raise AggregateError(f"{agent}: fewer than two seeds common to all tasks; nothing to bootstrap")
    return np.array([[p[s] for p in per_task] for s in seeds])


def probability_of_improvement(scores_x: np.ndarray, scores_y: np.ndarray) -> float:
    """rliable's ``metrics.probability_of_improvement``, P(X_m > Y_m) averaged over tasks m, with its Mann-Whitney U
    statistic counted over the pairs of runs (ties count a half) instead of computed from ranks by SciPy. The count
    and the ranks give the same U, exactly (half-integers), so the bootstrap intervals are rliable's to the bit
    (tests/test_aggregate.py), at about a hundredth of the cost: a leaderboard of seven runs bootstraps 42 pairs."""
    n_x, n_y = scores_x.shape[0], scores_y.shape[0]
    probs = []
    for task in range(scores_x.shape[1]):
        x, y = scores_x[:, task], scores_y[:, task]
        if np.array_equal(x, y):
            probs.append(0.5)
            continue
        u = np.count_nonzero(x[:, None] > y[None, :]) + 0.5 * np.count_nonzero(x[:, None] == y[None, :])
        probs.append(u / (n_x * n_y))
    return np.mean(probs)


def aggregate(scores: Mapping[str, np.ndarray], reps: int = 2000, seed: int = 0, step=None) -> dict:
    """Point estimates and stratified-bootstrap 95 % intervals of IQM, median, mean and optimality gap, and the
    probability of improvement of every ordered pair of runs. ``step()``, if given, is called after each
    bootstrap (the intervals, then each pair): 1 + n (n - 1) calls for n runs."""
    step = step or (lambda: None)
    library, metrics, _ = _rliable()

    def fn(x):
        return np.array([metrics.aggregate_iqm(x), metrics.aggregate_median(x), metrics.aggregate_mean(x),
                         metrics.aggregate_optimality_gap(x, 1.0)])

    np.random.seed(seed)  # rliable's bootstrap draws from NumPy's global generator
    point, interval = library.get_interval_estimates(dict(scores), fn, reps=reps)
    step()
    names = ("iqm", "median", "mean", "optimality_gap")
    out = {"metrics": {k: {n: {"estimate": float(point[k][i]), "low": float(interval[k][0, i]),
                                "high": float(interval[k][1, i])} for i, n in enumerate(names)}
                       for k in scores},
           "probability_of_improvement": {}}
    keys = list(scores)
    for a in keys:
        for b in keys:
            if a == b:
                continue
            np.random.seed(seed)
            p, ci = library.get_interval_estimates(
                {f"{a},{b}": (scores[a], scores[b])}, probability_of_improvement, reps=reps)
            out["probability_of_improvement"][f"{a} > {b}"] = {
                "estimate": float(np.squeeze(p[f"{a},{b}"])), "low": float(np.squeeze(ci[f"{a},{b}"])[0]),
                "high": float(np.squeeze(ci[f"{a},{b}"])[1])}
            step()
    return out


def profile_plot(scores: Mapping[str, np.ndarray], path: Path, reps: int = 2000, seed: int = 0) -> None:
    """Performance profiles: the fraction of (task, seed) runs whose normalised score exceeds tau."""
    library, _, plot_utils = _rliable()
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    lo = min(float(np.min(s)) for s in scores.values())
    hi = max(float(np.max(s)) for s in scores.values())
    taus = np.linspace(min(lo, 0.0) - 0.05, max(hi, 1.0) + 0.05, 101)
    np.random.seed(seed)
    prof, prof_ci = library.create_performance_profile(dict(scores), taus, reps=reps)
    fig, ax = plt.subplots(figsize=(7, 4.5))
    plot_utils.plot_performance_profiles(prof, taus, performance_profile_cis=prof_ci, ax=ax,
                                         xlabel=r"normalised score $\tau$")
    lines = ax.get_lines()[:len(scores)]  # one profile line per run, in the order of `scores`; the bands are patches
    ax.legend(lines, list(scores), loc="upper right", fontsize=9)
    ax.axvline(0.0, color="0.6", lw=0.8)
    ax.axvline(1.0, color="0.6", lw=0.8, ls="--")
    ax.set_title("0: best constant stiffness; 1: best schedule of the headroom table", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def markdown(result: dict, tasks: Sequence[str], runs: Mapping[str, np.ndarray]) -> str:
    lines = [f"Tasks: {', '.join(tasks)}. Normalised score: 0 = best constant stiffness, 1 = best schedule of the "
             "headroom table. 95 % stratified-bootstrap intervals (rliable).", "",
             "| run | seeds | IQM | median | mean | optimality gap |", "|---|---|---|---|---|---|"]
    for k, m in result["metrics"].items():
        cells = [f"{m[n]['estimate']:+.2f} [{m[n]['low']:+.2f}, {m[n]['high']:+.2f}]"
                 for n in ("iqm", "median", "mean", "optimality_gap")]
        lines.append(f"| {k} | {runs[k].shape[0]} | " + " | ".join(cells) + " |")
    if result["probability_of_improvement"]:
        lines += ["", "| probability of improvement | estimate [95 % CI] |", "|---|---|"]
        for k, v in result["probability_of_improvement"].items():
            lines.append(f"| P({k}) | {v['estimate']:.2f} [{v['low']:.2f}, {v['high']:.2f}] |")
    return "\n".join(lines) + "\n"


def _parse_run(text: str) -> tuple[str, Path, str]:
    try:
        label, rest = text.split("=", 1)
        directory, agent = rest.rsplit(":", 1)
    except ValueError:
        raise AggregateError(f"--run {text!r}: expected LABEL=RESULTS_DIR:AGENT, e.g. PPO=runs/compare:PPO") from None
    if not label or not directory or not agent:
        raise AggregateError(f"--run {text!r}: expected LABEL=RESULTS_DIR:AGENT, e.g. PPO=runs/compare:PPO")
    return label, Path(directory), agent


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="vswrist aggregate", description=__doc__.split("\n\n")[0])
    p.add_argument("--run", action="append", required=True, metavar="LABEL=DIR:AGENT",
                   help="a compare output directory and the agent row in it (repeatable)")
    p.add_argument("--headroom", required=True, help="headroom JSON: task -> {'headroom': paired gain > 0}")
    p.add_argument("--tasks", nargs="+", help="tasks to aggregate (default: those every run has)")
    p.add_argument("--reps", type=int, default=2000, help="bootstrap replications (default 2000)")
    p.add_argument("--out", required=True, help="output directory: aggregate.json, aggregate.md, profiles.png")
    args = p.parse_args(argv)
    try:
        if args.reps < 100:
            raise AggregateError(f"--reps must be >= 100, got {args.reps}")
        headroom = load_headroom(args.headroom)
        runs = [_parse_run(r) for r in args.run]
        loaded = {label: (load_summaries(d), agent) for label, d, agent in runs}
        tasks = args.tasks or sorted(set.intersection(*(set(s) for s, _ in loaded.values())) & set(headroom))
        tasks = [_short(t) for t in tasks]
        if not tasks:
            raise AggregateError("no task is common to every run and the headroom file")
        scores = {label: score_matrix(s, agent, headroom, tasks) for label, (s, agent) in loaded.items()}
        _rliable()
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        # the bootstraps: the intervals, one per ordered pair of runs, the performance profiles
        with bar(total=2 + len(scores) * (len(scores) - 1), desc="bootstraps", unit="bootstrap") as shown:
            result = aggregate(scores, reps=args.reps, step=shown.update)
            result["tasks"] = tasks
            result["runs"] = {label: {"dir": str(d), "agent": a} for label, d, a in runs}
            (out / "aggregate.json").write_text(json.dumps(result, indent=1) + "\n")
            (out / "aggregate.md").write_text(markdown(result, tasks, scores))
            profile_plot(scores, out / "profiles.png", reps=args.reps)
            shown.update()
    except AggregateError as exc:
        p.exit(2, f"vswrist aggregate: error: {exc}\n")
    logger.info(f"wrote {out / 'aggregate.json'}, aggregate.md and profiles.png")
    print((out / "aggregate.md").read_text(), end="")
    return 0


if __name__ == "__main__":
    from vswrist_gym.agents.output import run_tool

    raise SystemExit(run_tool(main))
