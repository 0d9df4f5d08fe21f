"""The end of a grid sweep: per task, the files `vswrist compare` writes (table.md, summary.json, plots,
eval/<agent>/metrics.*), built from the trials' records with compare's own functions."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

from vswrist_gym.sweep.trial import TRACE_FILE, read_result


def _records(trial: dict) -> list[dict]:
    doc = json.loads((Path(trial["trial_dir"]) / "metrics.json").read_text())
    return [{k: (float("nan") if v is None else v) for k, v in r.items()} for r in doc["episodes"]]


def _trace(trial: dict):
    try:
        return json.loads((Path(trial["trial_dir"]) / TRACE_FILE).read_text())
    except (OSError, ValueError):
        return None


def write_task_summary(sweep, env_id: str, trials: list[dict], wall_s: float, load_start: float,
                       command: str) -> dict:
    """OUT/<Task>/ for one task of the grid; trials without a record (failed) are named in the table, left out."""
    from vswrist_gym.agents.compare import write_outputs
    from vswrist_gym.agents.protocol import summarise, write_metrics

    mine = [t for t in trials if t["env_id"] == env_id]
    task = mine[0]["task"]
    out = Path(sweep.out) / task
    out.mkdir(parents=True, exist_ok=True)
    results = {t["name"]: read_result(t) for t in mine}
    training = {}
    rows, traces, runs, baselines, learned = {}, {}, {}, [], []
    budget, t_train = {}, 0.0
    for algo in sweep.algos:
        done = [t for t in mine if t["kind"] == "learned" and t["algo"] == algo]
        for t in done:
            r = results[t["name"]]
            training[t["name"].split("/", 1)[1]] = r["training"] if r else "FAILED (no trial record; see the log)"
            t_train += r["seconds"] if r else 0.0
        done = [t for t in done if results[t["name"]]]
        if not done:
            continue
        label = algo.upper()
        records = [rec for t in done for rec in _records(t)]
        rows[label] = summarise(records)
        head = {"task": env_id, "agent": label, "seeds": [t["seed"] for t in done],
                "episodes_per_seed": sweep.episodes}
        write_metrics(out / "eval" / algo, head, records, rows[label])
        runs[algo] = [Path(t["run_dir"]) for t in done]
        budget[algo] = done[0]["timesteps"]
        learned.append(label)
        trace_owner = [t for t in done if t["seed"] == t["trace_at"][0]]
        if trace_owner:
            traces[label] = _trace(trace_owner[0])
    for t in mine:
        if t["kind"] != "analytic" or not results[t["name"]]:
            continue
        records = _records(t)
        label = results[t["name"]]["agent"]
        rows[label] = summarise(records)
        write_metrics(out / "eval" / f"analytic_{t['stiffness']:+.2f}",
                      {"task": env_id, "agent": label, "seeds": t["eval_seeds"], "episodes_per_seed": sweep.episodes},
                      records, rows[label])
        traces[label] = _trace(t)
        baselines.append(label)
    from vswrist_gym.agents.hparams import track_of
    from vswrist_gym.agents.runs import read_config

    track = "/".join(sorted({track_of(read_config(d)[0].env_kwargs) for dirs in runs.values() for d in dirs})) or None
    return write_outputs(out, env_id, rows, runs, traces, learned, baselines, list(sweep.seeds), sweep.episodes,
                         sweep.stiffness, budget, training, t_train, wall_s, load_start, command,
                         (sweep.seeds[0], 0), track=track)


def write_summaries(sweep, trials: list[dict], wall_s: float, load_start: float | None = None,
                    command: str = "", log=print) -> list[Path]:
    load_start = os.getloadavg()[0] if load_start is None else load_start
    written = []
    for env_id in sweep.env_ids:
        doc = write_task_summary(sweep, env_id, trials, wall_s, load_start, command)
        log(f"{env_id}: {doc['out'] / 'table.md'}")
        for k, v in doc["verdicts"].items():
            log(f"  {k}: {v}")
        written.append(doc["out"])
    return written


def progress_line(trials: list[dict], running: int = 0, failed: int = 0) -> str:
    done = sum(1 for t in trials if read_result(t) is not None)
    return (f"[sweep {time.strftime('%H:%M:%S')}] {done}/{len(trials)} trials done, {running} running, "
            f"{failed} failed")
