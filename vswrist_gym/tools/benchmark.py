"""The leaderboard: every headline task x track x algorithm, trained on the benchmark seeds, scored held out.

``vswrist benchmark [--tasks ...] [--tracks ...] [--algos ...] [--write docs/leaderboard.md]`` runs the protocol
that ``experiments/leaderboard/NOTES.md`` fixes before any result:

* **Tasks**: by default the headline suite, the ids whose validity gate (``vswrist gate``,
  ``experiments/gate/<Task>-vN.json``) passes it (headroom, necessity, posture feedback). The gate's selection (on tuning
  episodes) gives each task its best constant stiffness; its headroom (the selected rule minus that constant on
  the 100 held-out episodes) is the unit of the normalised score.
* **Tracks** (``TRACKS``), all from the algorithm's packaged entry of the task (``configs/<algo>.yaml``) in the
  ``residual`` action mode: *stiffness* (the posture reference is the task's, the policy sets the stiffness),
  *full* (a posture residual of the entry's ``posture_scale``, or ``gate.POSTURE_SCALE`` where the entry has none,
  and the stiffness) and *posture* (the same posture residual, the stiffness held at the best constant: the
  gate's posture-only policy).
* **Budget**: the entry's ``n_timesteps``, fixed before the run; **training seeds** ``BENCHMARK_TRAIN_SEEDS``
  (0-9); the final model is evaluated with deterministic actions on the held-out episodes
  (``HELDOUT_EVAL_SEEDS`` x 10), the same episodes as the gate's constant and rule.
* **Per training seed**: the mean return and success; the paired difference to the best constant; its share of
  the headroom (the normalised score: 0 = best constant, 1 = the gate's rule); the **freeze test**, the same policy
  on the same episodes with its stiffness command held at its own per-episode mean (what the *variation* of the
  stiffness earns; not defined on the posture track).
* **Per cell** (task, track, algorithm): the mean over training seeds and its Student-t 95 % interval; the
  stiffness counts as *learned* when the intervals of the difference to the constant and of the freeze test both
  lie above zero. **Across tasks**, per track and algorithm: the IQM of the normalised scores and the probability
  of improvement over the best constant, with stratified-bootstrap intervals (rliable, ``agents.aggregate``).

Results go to ``OUT/<Task>-vN.json`` seed by seed (a stopped run resumes; the trained runs under ``RUNS_DIR``, not
committed); ``--write`` rebuilds the ``leaderboard`` block of a markdown file from those files alone.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import platform
import shlex
import sys
import time
from pathlib import Path

import numpy as np

from vswrist_gym.agents.protocol import BENCHMARK_TRAIN_SEEDS, HELDOUT_EVAL_SEEDS, mean_ci, reset_seed
from vswrist_gym.tools.gate import (EPISODES_PER_SEED, POSTURE_SCALE, GateError, check_heldout_seeds, packaged_entry,
                                    paired, passes, publish, result_path)

TRACKS = ("stiffness", "full", "posture")
ALGOS = ("ppo", "sac")
STIFFNESS_INDEX = 3   # the residual action: (RUD, FE, PS) posture offsets, then the stiffness command
BOOTSTRAP_REPS = 2000


class BenchmarkError(GateError):
    """Bad input, or a stored result made under another protocol; the message names the field."""


# ------------------------------------------------------------------------------------------------ entries


def track_entry(env_id: str, algo: str, track: str, best_constant: float, budget: int | None = None) -> dict:
    """The hyperparameter file's content (the entry and its ``vswrist:`` run settings) of one cell: the packaged
    entry of ``env_id`` (or of the task's newest version that has one) on ``track``."""
    if track not in TRACKS:
        raise BenchmarkError(f"track must be one of {', '.join(TRACKS)}, got {track!r}")
    entry, settings = packaged_entry(env_id, algo)
    kwargs = dict(entry.get("env_kwargs") or {})
    if kwargs.get("action_mode", "residual") != "residual":
        raise BenchmarkError(f"configs/{algo}.yaml: the entry of {env_id} has action_mode "
                             f"{kwargs['action_mode']!r}; the benchmark's tracks need 'residual'")
    residual = dict(kwargs.get("residual") or {})
    posture = float(residual.get("posture_scale") or 0.0) or POSTURE_SCALE
    if track == "stiffness":
        residual["posture_scale"] = 0.0
    elif track == "full":
        residual["posture_scale"] = posture
    else:
        residual.update(posture_scale=posture, stiffness_scale=0.0, stiffness_nominal=float(best_constant))
    entry["env_kwargs"] = {**kwargs, "action_mode": "residual", "residual": residual}
    if budget is not None:
        entry["n_timesteps"] = int(budget)
    return {env_id: entry, "vswrist": {env_id: settings}}


def cell_budget(env_id: str, algo: str, budget: int | None) -> int:
    return int(budget) if budget is not None else int(track_entry(env_id, algo, "stiffness", 0.0)[env_id]
                                                        ["n_timesteps"])


def train_cell(env_id: str, algo: str, track: str, best_constant: float, seed: int, runs_dir: Path,
               budget: int, log=print) -> Path:
    """Train (or finish) one run of a cell; returns its run directory."""
    import yaml

    from vswrist_gym.agents.train import train

    cell = Path(runs_dir) / env_id.split("/")[-1] / f"{track}_{algo}"
    run_dir = cell / f"seed{seed}"
    if (run_dir / "model.zip").is_file():
        return run_dir
    cfg_path = cell / f"{algo}.yaml"
    cfg_path.parent.mkdir(parents=True, exist_ok=True)
    cfg_path.write_text(yaml.safe_dump(track_entry(env_id, algo, track, best_constant, budget), sort_keys=False))
    resume = (run_dir / "config.yaml").is_file()
    train(env_id, algo, run_dir, config=None if resume else cfg_path, timesteps=budget, seed=seed, resume=resume,
          progress=False, log=log)
    return run_dir


# ------------------------------------------------------------------------------------------------ evaluation


class FrozenStiffness:
    """A policy whose stiffness action is replaced, world by world, by a fixed value: the freeze test. ``values``
    is one number per world of the batch it plays in."""

    def __init__(self, agent, values):
        self.agent, self.values = agent, np.asarray(values, dtype=np.float32)

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        action, state = self.agent.predict(obs, state=state, episode_start=episode_start, deterministic=deterministic)
        action = np.array(action, dtype=np.float32, copy=True)
        action[..., STIFFNESS_INDEX] = self.values
        return action, state


def held_actions(env, commands) -> np.ndarray:
    """The residual stiffness actions that command ``commands`` (the inverse of s = nominal + scale a), with the
    nominal and scale the environment applies: the task's own defaults (a task may set its nominal) under the
    run's settings."""
    r = env.unwrapped.cfg["residual"]
    return np.clip((np.asarray(commands, dtype=float) - r["stiffness_nominal"]) / r["stiffness_scale"], -1.0, 1.0)


def _records(venv, agent, seeds) -> list[tuple[dict, object]]:
    from vswrist_gym.agents.protocol import run_episodes_batched

    return [r for s in seeds for r in run_episodes_batched(venv, agent, reset_seed(s, 0))]


def evaluate_run(run_dir: Path, env_id: str, seeds=HELDOUT_EVAL_SEEDS, episodes: int = EPISODES_PER_SEED,
                 freeze: bool = True) -> dict:
    """The final model of ``run_dir`` on the held-out episodes (the episodes of a seed as the worlds of one batch:
    the same records as one env episode after episode): per episode its return, success and mean stiffness
    command, and with ``freeze`` the return with the stiffness command held at that mean."""
    import gymnasium as gym

    from vswrist_gym.agents.evaluate import AgentSpec

    seeds = check_heldout_seeds(seeds)
    spec = AgentSpec(str(run_dir), checkpoint="final")
    spec.check_task(env_id)
    kwargs = spec.env_kwargs
    env = gym.make(env_id, **kwargs)
    venv = gym.make_vec(env_id, num_envs=episodes, vectorization_mode="vector_entry_point", **kwargs)
    try:
        agent = spec.make(env)
        recs = _records(venv, agent, seeds)
        u = env.unwrapped
        commands = [float(np.mean([u.lam_to_stiffness_command(lam) for lam in tr.lam])) for _, tr in recs]
        out = {"returns": [float(r["return"]) for r, _ in recs],
               "success": [None if math.isnan(r["success"]) else float(r["success"]) for r, _ in recs],
               "mean_commands": commands}
        if freeze:
            a = held_actions(u, commands)
            frozen = []
            for k, s in enumerate(seeds):
                held = FrozenStiffness(agent, a[k * episodes:(k + 1) * episodes])
                frozen += [float(rec["return"]) for rec, _ in _records(venv, held, [s])]
            out["frozen_returns"] = frozen
    finally:
        env.close()
        venv.close()
    return out


# ------------------------------------------------------------------------------------------------ statistics


def seed_scores(run: dict, constant: list[float], headroom: float) -> dict:
    """One training seed's paired difference to the constant, normalised score and freeze test."""
    d = paired(run["returns"], constant)
    out = {"return": float(np.mean(run["returns"])), "vs_constant": d["mean"], "score": d["mean"] / headroom,
           "success": float(np.mean(run["success"])) if None not in run["success"] else math.nan}
    if "frozen_returns" in run:
        out["freeze"] = paired(run["returns"], run["frozen_returns"])["mean"]
    return out


def cell_summary(cell: dict, constant: list[float], headroom: float) -> dict:
    """Mean and 95 % Student-t interval over training seeds of each per-seed measure; the learned verdict."""
    per_seed = {s: seed_scores(r, constant, headroom) for s, r in cell["runs"].items()}
    keys = ("return", "vs_constant", "score", "success", "freeze")
    out = {k: mean_ci([p[k] for p in per_seed.values() if k in p], bounds=(0.0, 1.0) if k == "success" else
                      (-math.inf, math.inf)) for k in keys}
    out["seeds"] = len(per_seed)
    out["learned"] = bool(out["vs_constant"]["low"] > 0 and "freeze" in next(iter(per_seed.values()), {})
                          and out["freeze"]["low"] > 0) if per_seed else False
    return out


def score_matrices(docs: list[dict], tracks=TRACKS, algos=ALGOS) -> dict[str, np.ndarray]:
    """Normalised scores (runs x tasks) per track/algorithm present on every task with the same seeds, and the
    best constant's (zeros), for rliable."""
    out = {}
    for track in tracks:
        for algo in algos:
            key = f"{track}/{algo}"
            cells = [d.get("cells", {}).get(key) for d in docs]
            if not cells or any(c is None or not c["runs"] for c in cells):
                continue
            seeds = sorted(cells[0]["runs"], key=int)
            if any(sorted(c["runs"], key=int) != seeds for c in cells):
                continue
            cols = []
            for d, c in zip(docs, cells):
                const, hr = _gate_terms(d)
                cols.append([seed_scores(c["runs"][s], const, hr)["score"] for s in seeds])
            out[key] = np.asarray(cols, dtype=float).T
    if out:
        shape = next(iter(out.values())).shape
        out["best constant"] = np.zeros(shape)
    return out


def _gate_terms(doc: dict) -> tuple[list[float], float]:
    g = doc["gate"]
    return g["constant_returns"], g["headroom"]


# ------------------------------------------------------------------------------------------------ one task


def protocol_block(seeds, budgets: dict[str, int]) -> dict:
    return {"train_seeds": [int(s) for s in seeds], "heldout_eval_seeds": list(HELDOUT_EVAL_SEEDS),
            "episodes_per_seed": EPISODES_PER_SEED, "budgets": dict(budgets), "posture_scale": POSTURE_SCALE,
            "checkpoint": "final", "deterministic": True}


def gate_block(env_id: str, gate_dir: Path) -> dict:
    """What the benchmark takes from the task's gate result: the selected constant, its held-out returns, the
    rule's headroom; refused unless the task passes the gate."""
    path = result_path(gate_dir, env_id)
    if not path.is_file():
        raise BenchmarkError(f"no gate result for {env_id} in {gate_dir}: run `vswrist gate --tasks {env_id}` first")
    doc = json.loads(path.read_text())
    if not passes(doc):
        raise BenchmarkError(f"{env_id} does not pass the validity gate ({path}); the leaderboard holds the tasks "
                             "that pass it")
    best = doc["selection"]["best_constant"]
    hr = doc["headroom"]
    return {"file": str(path), "best_constant": float(best),
            "constant_returns": [float(x) for x in hr["returns"]["constant"][f"{best:+.1f}"]],
            "rule_levels": doc["selection"]["rule_levels"], "headroom": float(hr["rule_minus_constant"]["mean"]),
            "headroom_se": float(hr["rule_minus_constant"]["se"]), "reset_seeds": hr["reset_seeds"]}


def _stamp(cell: dict, seed: int) -> None:
    cell.setdefault("made", {})[str(seed)] = {
        "utc": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M"),
        "machine": f"{platform.node()}, {platform.machine()}, {os.cpu_count()} cores"}


def _seed_run(env_id: str, algo: str, track: str, best_constant: float, seed: int, runs_dir: Path, budget: int,
              log=print) -> dict:
    """One training seed of one cell: trained, then scored on the held-out episodes (what the result file keeps)."""
    t0 = time.time()
    run_dir = train_cell(env_id, algo, track, best_constant, seed, runs_dir, budget, log=log)
    run = evaluate_run(run_dir, env_id, freeze=track != "posture")
    return {"run_dir": str(run_dir), "seconds": round(time.time() - t0, 1), **run}


def _worker_init(threads: int) -> None:
    """A ``--jobs`` worker: one torch thread, and its share of the cores for the batch's physics threads."""
    from vswrist_gym.agents.procs import limit_threads
    from vswrist_gym.envs.batch import THREADS_ENV

    os.environ[THREADS_ENV] = str(threads)
    limit_threads(1)


def _seed_run_quiet(args: tuple) -> dict:
    return _seed_run(*args, log=lambda *a: None)


def run_task(env_id: str, out: Path, runs_dir: Path, gate_dir: Path, tracks, algos, seeds, budget: int | None = None,
             command: str = "", log=print, jobs: int = 1) -> dict:
    """Every cell of one task, seed by seed, each saved to OUT/<Task>-vN.json as it is done (done ones skipped).
    ``jobs`` > 1 trains that many seeds at once, each in its own process with its share of the cores; a run's
    numbers do not depend on it (every run is seeded, and the batch's threads step as in sequence)."""
    from vswrist_gym.tools.gate import _save

    path = result_path(out, env_id)
    budgets = {a: cell_budget(env_id, a, budget) for a in algos}
    doc = json.loads(path.read_text()) if path.is_file() else {"task": env_id, "cells": {}}
    gate = gate_block(env_id, gate_dir)
    if doc.get("gate", gate) != gate:
        raise BenchmarkError(f"{path} was scored against another gate result; move it away to start over")
    doc["gate"] = gate
    proto = doc.setdefault("protocol", protocol_block(seeds, budgets))
    for a in algos:
        if a in proto["budgets"] and proto["budgets"][a] != budgets[a]:
            raise BenchmarkError(f"{path}: {a} was run with a budget of {proto['budgets'][a]} steps, not "
                                 f"{budgets[a]}; move the file away to start over")
        proto["budgets"][a] = budgets[a]
    if command and command not in doc.setdefault("commands", []):
        doc["commands"].append(command)
    todo = []  # (track, algo, seed) still to run, in the order a single job runs them
    for track in tracks:
        for algo in algos:
            cell = doc["cells"].setdefault(f"{track}/{algo}", {"runs": {}})
            entry = track_entry(env_id, algo, track, gate["best_constant"], budgets[algo])
            if cell["runs"] and cell.get("entry", entry) != entry:
                raise BenchmarkError(f"{path}: the {track}/{algo} runs were trained with another hyperparameter "
                                     f"entry than configs/{algo}.yaml's; move the file away to start over")
            cell["entry"] = entry
            todo += [(track, algo, s) for s in seeds if str(s) not in cell["runs"]]

    def done(track: str, algo: str, s: int, run: dict) -> None:
        cell = doc["cells"][f"{track}/{algo}"]
        cell["runs"][str(s)] = run
        # seed order whatever order the jobs finish in, so that the file does not depend on --jobs
        cell["runs"] = {k: cell["runs"][k] for k in sorted(cell["runs"], key=int)}
        _stamp(cell, s)
        _save(path, doc)
        sc = seed_scores(run, gate["constant_returns"], gate["headroom"])
        log(f"{env_id} {track}/{algo} seed {s}: {sc['vs_constant']:+.2f} over the constant, score "
            f"{sc['score']:+.2f}" + (f", freeze {sc['freeze']:+.2f}" if "freeze" in sc else "")
            + f" ({run['seconds']:.0f} s)")

    args = {t: (env_id, t[1], t[0], gate["best_constant"], t[2], runs_dir, budgets[t[1]]) for t in todo}
    if jobs <= 1:
        for t in todo:
            done(*t, _seed_run(*args[t], log=log))
        return doc
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    from vswrist_gym.envs.batch import default_threads

    # spawn: the workers start clean rather than as forks of a process that has loaded torch
    with ProcessPoolExecutor(max_workers=jobs, mp_context=multiprocessing.get_context("spawn"),
                             initializer=_worker_init, initargs=(max(1, default_threads() // jobs),)) as pool:
        futures = {pool.submit(_seed_run_quiet, args[t]): t for t in todo}
        for fut in as_completed(futures):
            done(*futures[fut], fut.result())
    return doc


# ------------------------------------------------------------------------------------------------ the table


def _ci(m: dict, fmt: str = "+.1f") -> str:
    if m["n"] == 0:
        return ""
    if m["n"] < 2:
        return f"{m['mean']:{fmt}}"
    return f"{m['mean']:{fmt}} [{m['low']:{fmt}}, {m['high']:{fmt}}]"


HEADER = ("| task | track | algorithm | seeds | return | - best constant [95 %] | normalised score [95 %] "
          "| freeze test [95 %] | success | stiffness learned |\n|---|---|---|---|---|---|---|---|---|---|")


def leaderboard(docs: list[dict], reps: int = BOOTSTRAP_REPS) -> str:
    """The leaderboard block: one row per cell, the aggregate per track and algorithm, the targets, the command."""
    rows = [HEADER]
    for d in docs:
        const, hr = _gate_terms(d)
        g = d["gate"]
        rows.append(f"| `{d['task']}` | best constant | s = {g['best_constant']:+.1f} | | {np.mean(const):.1f} | 0 "
                    f"| 0 | | | |")
        for key, cell in d["cells"].items():
            if not cell["runs"]:
                continue
            track, algo = key.split("/")
            s = cell_summary(cell, const, hr)
            learned = "n/a" if track == "posture" else ("**yes**" if s["learned"] else "no")
            rows.append(f"| `{d['task']}` | {track} | {algo.upper()} | {s['seeds']} | {_ci(s['return'], '.1f')} "
                        f"| {_ci(s['vs_constant'])} | {_ci(s['score'], '+.2f')} | {_ci(s['freeze'])} "
                        f"| {_ci(s['success'], '.2f')} | {learned} |")
    lines = rows + [""]
    scores = score_matrices(docs)
    if len(scores) > 1:
        from vswrist_gym.agents.aggregate import aggregate

        agg = aggregate(scores, reps=reps)
        lines += ["| track / algorithm | runs x tasks | IQM of normalised scores [95 %] | P(better than the best "
                  "constant) [95 %] |", "|---|---|---|---|"]
        for key, m in scores.items():
            if key == "best constant":
                continue
            iqm = agg["metrics"][key]["iqm"]
            poi = agg["probability_of_improvement"][f"{key} > best constant"]
            lines.append(f"| {key} | {m.shape[0]} x {m.shape[1]} | {iqm['estimate']:+.2f} [{iqm['low']:+.2f}, "
                         f"{iqm['high']:+.2f}] | {poi['estimate']:.2f} [{poi['low']:.2f}, {poi['high']:.2f}] |")
        lines.append("")
    made = sorted({v["utc"].split(" ")[0] for d in docs for c in d["cells"].values() for v in c.get("made", {}).values()})
    machines = sorted({v["machine"] for d in docs for c in d["cells"].values() for v in c.get("made", {}).values()})
    commands = sorted({c for d in docs for c in d.get("commands", [])})
    lines.append(f"{'; '.join(f'`{c}`' for c in commands) or '?'}, "
                 f"{' to '.join(dict.fromkeys([made[0], made[-1]])) if made else '?'} on {'; '.join(machines) or '?'} "
                 "(other jobs sharing its cores; the returns do not depend on the load).")
    return "\n".join(lines)


# ------------------------------------------------------------------------------------------------ command line


def headline_tasks(gate_dir: Path) -> list[str]:
    """The ids whose gate result in ``gate_dir`` passes (``gate.passes``), in the registry's order."""
    import gymnasium as gym

    import vswrist_gym  # noqa: F401

    out = []
    for env_id in (k for k in gym.registry if k.startswith("VSWrist/")):
        try:
            gate_block(env_id, gate_dir)
        except BenchmarkError:
            continue
        out.append(env_id)
    return out


def main(argv: list[str] | None = None) -> int:
    from vswrist_gym import resolve_id

    ap = argparse.ArgumentParser(prog="vswrist benchmark", description=__doc__.split("\n\n")[0])
    ap.add_argument("--tasks", nargs="+", type=resolve_id, default=None,
                    help="short names or full ids (default: every id that passes the validity gate)")
    ap.add_argument("--tracks", nargs="+", choices=TRACKS, default=list(TRACKS))
    ap.add_argument("--algos", nargs="+", choices=ALGOS, default=list(ALGOS))
    ap.add_argument("--train-seeds", type=int, nargs="+", default=list(BENCHMARK_TRAIN_SEEDS), metavar="SEED")
    ap.add_argument("--budget", type=int, default=None,
                    help="env steps per run for every algorithm (default: each entry's n_timesteps); another "
                         "budget needs another --out, since a result file records its budgets")
    ap.add_argument("--gate-dir", default="experiments/gate", help="folder of the gate's per-task JSON results")
    ap.add_argument("--out", default="experiments/leaderboard", help="folder of the per-task JSON results")
    ap.add_argument("--runs-dir", default="runs/leaderboard", help="folder of the trained runs (git-ignored)")
    ap.add_argument("--write", default=None, metavar="PATH",
                    help="rewrite the 'leaderboard' generated block of PATH (docs/leaderboard.md) from the JSON files")
    ap.add_argument("--table-only", action="store_true", help="compute nothing: print (and --write) the table")
    ap.add_argument("--jobs", type=int, default=1,
                    help="training seeds run at once, each in its own process with its share of the cores "
                         "(default 1); the results do not depend on it")
    args = ap.parse_args(argv)
    if args.jobs < 1:
        ap.error(f"--jobs must be a positive number of processes, got {args.jobs}")
    if args.budget is not None and args.budget < 1:
        ap.error(f"--budget must be a positive number of env steps, got {args.budget}")
    if len(set(args.train_seeds)) < 2 or min(args.train_seeds) < 0:
        ap.error(f"--train-seeds must be at least two distinct seeds >= 0, got {args.train_seeds}")
    gate_dir, out = Path(args.gate_dir), Path(args.out)
    ids = list(dict.fromkeys(args.tasks)) if args.tasks else headline_tasks(gate_dir)
    if not ids:
        print(f"vswrist benchmark: no task passes the validity gate in {gate_dir}", file=sys.stderr)
        return 2
    from vswrist_gym.agents.procs import limit_threads

    limit_threads(1)
    command = "vswrist benchmark " + shlex.join(argv if argv is not None else sys.argv[1:])
    if not args.table_only:
        for env_id in ids:
            try:
                run_task(env_id, out, Path(args.runs_dir), gate_dir, args.tracks, args.algos,
                         list(dict.fromkeys(args.train_seeds)), args.budget, command=command,
                         log=lambda *a: print(*a, flush=True), jobs=args.jobs)
            except GateError as exc:
                print(f"vswrist benchmark: {exc}", file=sys.stderr)
                return 2
    return publish("vswrist benchmark", out, ids, "leaderboard", leaderboard, args.write)

if __name__ == "__main__":
    raise SystemExit(main())
