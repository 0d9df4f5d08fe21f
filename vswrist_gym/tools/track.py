"""`vswrist track TRACK.yaml [--run]`: one command per track, and the track's own results table.

A track file lists, per task, the committed runs of one track (the *stiffness* track, where the posture
reference is the task's and the policy sets only the stiffness, and the *full* track, posture and stiffness):
each run is a grid sweep file (`vswrist sweep`) or a `vswrist compare` output folder with the command that
makes it. With `--run` the runs whose results are missing are produced first, in the file's order
(a sweep stopped half-way is resumed); then the table is written from the results, re-running nothing:

* per run, the learned agent against the best fixed stiffness on the same episodes: the returns' Student-t 95 %
  intervals over seeds and their verdict (**better** only if they do not overlap), and the paired difference;
* the share of the task's headroom that paired difference reaches: headroom = the best schedule's gain over the
  best constant in the probe's headroom table (`docs/figures/headroom.json`, other episodes than the run's, so
  the share is indicative);
* full track, where the run names its posture-only ablation (the same entry with `residual.stiffness_scale: 0`):
  the stiffness contribution, full minus posture-only on the same episodes (`tools.contribution`);
* per target of the track (`counts`), how many tasks meet it.

Track file keys (every other key is an error naming it)::

    track: stiffness | full
    headroom: docs/figures/headroom.json
    out: experiments/tracks/track_stiffness.md          # the table (markdown); a JSON twin is written beside it
    runs:
      - {task: Polish, sweep: experiments/tuned_stiffness/tuned_stiffness.yaml, agent: ppo}
      - {task: Polish, dir: experiments/polish_compare, command: "vswrist compare --task Polish --out experiments/polish_compare",
         agent: sac}
      - {task: Drill, sweep: FILE, agent: ppo, ablation: POSTURE_ONLY_SWEEP}   # full track only
"""

from __future__ import annotations

import argparse
import json
import math
import shlex
import sys
from dataclasses import dataclass
from pathlib import Path

from vswrist_gym.agents.hparams import ALGO_NAMES, TRACKS, ConfigError, read_mapping, track_of

TRACK_KEYS = ("track", "headroom", "out", "runs")
RUN_KEYS = ("task", "sweep", "dir", "command", "agent", "ablation")
# the stiffness track's target: a learned policy's paired gain reaches >= 75 % of the gain of the headroom
# table's best schedule over the best constant (most of what scheduling the stiffness can give)
SHARE_TARGET = 0.75


class TrackError(ConfigError):
    """A track file, or a result it names, that the table cannot be built from; the message names the field."""


@dataclass
class Run:
    task: str            # short name, e.g. Polish
    env_id: str          # the run's id, e.g. VSWrist/Polish-v1
    agent: str           # ppo | sac
    folder: Path         # the compare output folder of this task (summary.json, eval/<agent>/metrics.json)
    source: str          # the sweep file, or the command that makes the folder
    sweep: object | None = None
    ablation: object | None = None   # the posture-only sweep (full track)
    command: str | None = None


def _short(env_id: str) -> str:
    return env_id.split("/")[-1].rsplit("-v", 1)[0]


def _sweep(path, where: str):
    from vswrist_gym.sweep.spec import SweepError, load_sweep

    if not isinstance(path, str):
        raise TrackError(f"'{where}' must be a sweep file path, got {path!r}")
    try:
        sweep = load_sweep(path)
    except SweepError as exc:
        raise TrackError(f"'{where}': {exc}") from None
    if sweep.mode != "grid":
        raise TrackError(f"'{where}': {path} is a hyperparameter search, not a grid with evaluations")
    return sweep


def _sweep_env(sweep, task: str, where: str) -> str:
    found = [e for e in sweep.env_ids if _short(e) == task]
    if not found:
        raise TrackError(f"'{where}': {sweep.path} does not run {task} (it runs "
                         f"{', '.join(_short(e) for e in sweep.env_ids)})")
    return found[0]


def load_track(path: str | Path) -> tuple[dict, list[Run]]:
    """Read and check a track file; errors name the file and the key (TrackError)."""
    path = Path(path)
    try:
        return _load(path)
    except TrackError as exc:
        raise TrackError(f"track file {path}: {exc}") from None


def _load(path: Path) -> tuple[dict, list[Run]]:
    from vswrist_gym.agents.train import task_id

    doc = read_mapping(path, TrackError, TRACK_KEYS, TRACK_KEYS, "track, headroom, out, runs")
    track = doc["track"]
    if track not in TRACKS:
        raise TrackError(f"'track' must be one of {', '.join(TRACKS)}, got {track!r}")
    for key in ("headroom", "out"):
        if not isinstance(doc[key], str):
            raise TrackError(f"'{key}' must be a file path, got {doc[key]!r}")
    if not isinstance(doc["runs"], list) or not doc["runs"]:
        raise TrackError("'runs' must be a non-empty list of {task, sweep or dir, agent}")
    runs = []
    for i, r in enumerate(doc["runs"]):
        where = f"runs[{i}]"
        if not isinstance(r, dict):
            raise TrackError(f"'{where}' must be a mapping (task, sweep or dir, agent), got {r!r}")
        bad = [k for k in r if k not in RUN_KEYS]
        if bad:
            raise TrackError(f"unknown key '{where}.{bad[0]}'; allowed: {', '.join(RUN_KEYS)}")
        if not isinstance(r.get("task"), str):
            raise TrackError(f"'{where}.task' must be a task name, got {r.get('task')!r}")
        try:
            task = _short(task_id(r["task"]))
        except ConfigError as exc:
            raise TrackError(f"'{where}.task': {exc}") from None
        agent = r.get("agent")
        if agent not in ALGO_NAMES:
            raise TrackError(f"'{where}.agent' must be one of {', '.join(ALGO_NAMES)}, got {agent!r}")
        if ("sweep" in r) == ("dir" in r):
            raise TrackError(f"'{where}' needs exactly one of 'sweep' (a grid sweep file) and 'dir' (a vswrist "
                             f"compare output folder, with 'command')")
        if "sweep" in r:
            if "command" in r:
                raise TrackError(f"'{where}.command' goes with 'dir'; a sweep is run by `vswrist sweep`")
            sweep = _sweep(r["sweep"], f"{where}.sweep")
            env_id = _sweep_env(sweep, task, f"{where}.sweep")
            if agent not in sweep.algos:
                raise TrackError(f"'{where}.agent': {sweep.path} trains {', '.join(sweep.algos) or 'no agent'}, "
                                 f"not {agent}")
            entry_track = track_of(sweep.entries[(agent, env_id)].get("env_kwargs", {}))
            if entry_track != track:
                raise TrackError(f"'{where}.sweep': {sweep.path} trains {agent} on {task} on the {entry_track} "
                                 f"track, not the {track} track")
            run = Run(task, env_id, agent, sweep.out / _short(env_id), str(sweep.path), sweep=sweep)
        else:
            if not isinstance(r["dir"], str) or not isinstance(r.get("command"), str):
                raise TrackError(f"'{where}': 'dir' (a folder path) and 'command' (the vswrist compare command "
                                 f"that writes it) must both be strings")
            run = Run(task, "", agent, Path(r["dir"]), r["command"], command=r["command"])
        if "ablation" in r:
            if track != "full":
                raise TrackError(f"'{where}.ablation': the posture-only ablation belongs to the full track")
            if run.sweep is None:
                raise TrackError(f"'{where}.ablation' pairs with a 'sweep' run (the same seeds and episodes)")
            abl = _sweep(r["ablation"], f"{where}.ablation")
            abl_env = _sweep_env(abl, task, f"{where}.ablation")
            residual = (abl.entries.get((agent, abl_env), {}).get("env_kwargs", {}) or {}).get("residual") or {}
            if agent not in abl.algos or float(residual.get("stiffness_scale", 1.0)) != 0.0:
                raise TrackError(f"'{where}.ablation': {abl.path} must train {agent} on {task} with "
                                 f"residual.stiffness_scale 0 (the posture-only ablation)")
            if (abl.seeds, abl.episodes) != (run.sweep.seeds, run.sweep.episodes):
                raise TrackError(f"'{where}.ablation': {abl.path} evaluates seeds {abl.seeds} x {abl.episodes} "
                                 f"episodes, the run {run.sweep.seeds} x {run.sweep.episodes}: not the same episodes")
            run.ablation = abl
        runs.append(run)
    return doc, runs


# ---------------------------------------------------------------------------------------------- producing runs
def _summary_path(folder: Path) -> Path:
    return folder / "summary.json"


def missing(runs: list[Run]) -> list[tuple[str, list[str]]]:
    """(what, argv) of each sweep or command whose results are missing, once each, in the track's order."""
    from vswrist_gym.sweep.cli import RECORD_FILE

    todo, seen = [], set()
    for run in runs:
        sweeps = [(run.sweep, run.folder)] if run.sweep is not None else []
        if run.ablation is not None:
            sweeps.append((run.ablation, run.ablation.out / run.task))
        for sweep, folder in sweeps:
            key = str(sweep.path)
            if key in seen or _summary_path(folder).is_file():
                continue
            seen.add(key)
            resume = ["--resume"] if (sweep.runs_dir / RECORD_FILE).is_file() else []
            todo.append((f"vswrist sweep {key}", ["sweep", key, *resume]))
        if run.command is not None and run.command not in seen and not _summary_path(run.folder).is_file():
            seen.add(run.command)
            argv = shlex.split(run.command)
            if not argv or argv[0] != "vswrist":
                raise TrackError(f"the command of {run.folder} must be a vswrist command, got {run.command!r}")
            todo.append((run.command, argv[1:]))
    return todo


# ---------------------------------------------------------------------------------------------- the table
def _read_summary(run: Run) -> dict:
    path = _summary_path(run.folder)
    try:
        summary = json.loads(path.read_text())
    except FileNotFoundError:
        make = run.command or f"vswrist sweep {run.source}"
        raise TrackError(f"{path} is missing: produce it with `{make}` (or `vswrist track FILE --run`)") from None
    except (OSError, json.JSONDecodeError) as exc:
        raise TrackError(f"{path}: cannot read it ({exc})") from None
    if _short(summary.get("task", "")) != run.task:
        raise TrackError(f"{path} holds {summary.get('task')!r}, not {run.task}")
    if run.agent.upper() not in summary.get("rows", {}):
        raise TrackError(f"{path} has no {run.agent.upper()} row")
    return summary


def row(run: Run, track: str, headroom: dict[str, float]) -> dict:
    """One run's line of the track table (numbers as floats; see the module docstring)."""
    from vswrist_gym.agents.compare import against_baseline, best_baseline
    from vswrist_gym.tools.contribution import contribution

    summary = _read_summary(run)
    if run.command is not None and summary.get("track") not in (None, track):
        raise TrackError(f"{_summary_path(run.folder)} is a {summary['track']}-track run, not {track}")
    rows = summary["rows"]
    name = run.agent.upper()
    best = best_baseline(rows, [k for k in rows if k.startswith("analytic")])
    if best is None:
        raise TrackError(f"{_summary_path(run.folder)} has no fixed-stiffness baseline row")
    diff, verdict = against_baseline(rows, name, best)
    h = headroom.get(run.task)
    out = {
        "task": run.task, "env_id": summary["task"], "agent": name, "source": run.source,
        "steps": (summary.get("timesteps") or {}).get(run.agent),
        "seeds": len(summary["seeds"]), "episodes": summary["episodes_per_seed"],
        "return": rows[name]["return"], "best": best, "best_return": rows[best]["return"],
        "paired": diff, "verdict": verdict,
        "headroom": h, "share": diff["mean"] / h if h else math.nan,
        "training_s": (summary.get("seconds") or {}).get("training"),
    }
    if run.ablation is not None:
        metrics = run.folder / "eval" / run.agent / "metrics.json"
        abl = run.ablation.out / run.task / "eval" / run.agent / "metrics.json"
        if not abl.is_file():
            raise TrackError(f"{abl} is missing: produce it with `vswrist sweep {run.ablation.path}`")
        c = contribution(metrics, abl)
        out["posture_only"] = c["posture_only"]
        out["contribution"] = c["contribution"]
        out["ablation"] = str(run.ablation.path)
    return out


def _ci(c: dict, fmt: str = "{:+.1f}") -> str:
    if math.isnan(c["low"]):
        return fmt.format(c["mean"])
    return f"{fmt.format(c['mean'])} [{fmt.format(c['low'])}, {fmt.format(c['high'])}]"


def _beats(r: dict) -> bool:
    return r["verdict"] == "beats"


def _positive(r: dict) -> bool:
    c = r.get("contribution")
    return c is not None and not math.isnan(c["low"]) and c["low"] > 0


def counts(track: str, rows: list[dict]) -> list[tuple[str, int, int, str]]:
    """(target, tasks meeting it, tasks with a run, goal) for the targets of this track."""
    tasks = sorted({r["task"] for r in rows})
    by = lambda test: sorted({r["task"] for r in rows if test(r)})  # noqa: E731
    if track == "stiffness":
        return [("a learned policy beats the best constant (95 % intervals apart)", len(by(_beats)), len(tasks),
                 ">= 4 of 6"),
                (f"paired gain >= {SHARE_TARGET:.0%} of the headroom table's best schedule",
                 len(by(lambda r: r["share"] >= SHARE_TARGET)), len(tasks), ">= 3")]
    return [("SAC beats the best constant (95 % intervals apart)",
             len(by(lambda r: r["agent"] == "SAC" and _beats(r))), len({r["task"] for r in rows if r["agent"] == "SAC"}),
             ">= 3"),
            ("stiffness contribution (full - posture-only, paired) above 0", len(by(_positive)),
             len({r["task"] for r in rows if "contribution" in r}), ">= 3")]


VERDICT_TEXT = {"beats": "**better**", "worse": "worse", "overlap": "overlap", "no CI": "no CI"}


def table(track: str, rows: list[dict]) -> str:
    head = ["task", "run", "agent", "steps/seed", "seeds x episodes", "return", "best constant", "its return",
            "paired difference", "verdict", "share of headroom"]
    if track == "full":
        head += ["posture only", "stiffness contribution"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        steps = f"{r['steps']:,}" if r["steps"] else "?"
        share = "" if math.isnan(r["share"]) else f"{r['share']:.2f}"
        cells = [r["env_id"], f"`{r['source']}`", r["agent"], steps, f"{r['seeds']} x {r['episodes']}",
                 _ci(r["return"]), r["best"], _ci(r["best_return"]), _ci(r["paired"]), VERDICT_TEXT[r["verdict"]],
                 share]
        if track == "full":
            cells += [_ci(r["posture_only"]) if "posture_only" in r else "",
                      _ci(r["contribution"]) if "contribution" in r else ""]
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", "| target | tasks meeting it | tasks with a run | goal |", "|---|---|---|---|"]
    lines += [f"| {t} | {k} | {n} | {goal} |" for t, k, n, goal in counts(track, rows)]
    return "\n".join(lines)


def build(path: str | Path, loaded: tuple[dict, list[Run]] | None = None) -> tuple[dict, list[dict], str]:
    """(track file, table rows, table text); ``loaded``: the file as `load_track` already read it."""
    from vswrist_gym.agents.aggregate import AggregateError, load_headroom

    doc, runs = loaded or load_track(path)
    try:
        headroom = load_headroom(doc["headroom"])
    except AggregateError as exc:
        raise TrackError(f"track file {path}: 'headroom': {exc}") from None
    rows = [row(r, doc["track"], headroom) for r in runs]
    return doc, rows, table(doc["track"], rows)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="vswrist track", description=" ".join(__doc__.split("\n\n")[0].split()))
    p.add_argument("track", metavar="TRACK.yaml", help="track file (vswrist_gym/configs/tracks/stiffness.yaml or "
                                                       "full.yaml)")
    p.add_argument("--run", action="store_true", help="first produce the runs whose results are missing")
    p.add_argument("--dry-run", action="store_true", help="with --run: print the commands it would run, run none")
    args = p.parse_args(argv)
    try:
        loaded = load_track(args.track)
        if args.run:
            from vswrist_gym.cli import main as vswrist

            for what, sub in missing(loaded[1]):
                print(f"vswrist track: {what}", flush=True)
                if not args.dry_run and vswrist(sub) != 0:
                    print(f"vswrist track: error: `{what}` failed; fix it and run again (finished runs are kept)",
                          file=sys.stderr)
                    return 1
            if args.dry_run:
                return 0
        doc, rows, text = build(args.track, loaded)
    except (ConfigError, ValueError) as exc:
        print(f"vswrist track: error: {exc}", file=sys.stderr)
        return 2
    from vswrist_gym.agents.runs import atomic_write_text

    out = Path(doc["out"])
    header = (f"<!-- generated by `vswrist track {args.track}`; do not edit -->\n\n"
              f"**The {doc['track']} track.** Verdict: the learned agent's and the best constant's Student-t 95 % "
              f"intervals over seeds (**better** only if apart); paired difference: per seed on the same episodes. "
              f"Share of headroom: the paired difference over the best schedule's gain in `{doc['headroom']}` "
              f"(the probe's held-out episodes, not the run's: indicative).\n\n")
    atomic_write_text(out, header + text + "\n")
    atomic_write_text(out.with_suffix(".json"), json.dumps({"track": doc["track"], "file": str(args.track),
                                                            "rows": rows}, indent=2, default=str))
    print(text)
    print(f"\nwritten: {out} and {out.with_suffix('.json')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
