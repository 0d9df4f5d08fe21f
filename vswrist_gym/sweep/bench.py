"""Sweep speed-up: a grid of 8 short trials run by a serial loop, then as one `vswrist sweep` on Ray embedded on this
machine; prints the wall times, their ratio and where the sweep's time went (not a test: it measures the machine).

    flock /work/bench.lock python -m vswrist_gym.sweep.bench [--steps 32768] [--episodes 10] [--serial cli inprocess]

The grid: PPO on LoadHold, seeds 0-7, STEPS steps each with the packaged hyperparameters except `n_envs: 1`, then
the evaluation protocol (EPISODES episodes on the trial's seed). One environment makes a trial a one-CPU job: a
2-core machine runs two at a time (a batched run, `vec_env: batch`, asks for one CPU whatever its n_envs).
The default 32,768 steps is 40 % of LoadHold's packaged budget
(80,000): a short trial, long enough that a learning curve has three periodic evaluations (every 10,000 steps).

Serial references (both run the same trial work as a sweep trial: one torch thread, the default of `vswrist train`,
and one physics thread, since a batch of one world has one; the same config, seeds and evaluation):
- `cli`, the reference a user has: the loop they would write without a sweep (a shell loop of commands), for each
  seed `vswrist train --task LoadHold --algo ppo --seed S --timesteps STEPS --n-envs 1` then `vswrist evaluate
  --agent RUN --seeds S --episodes EPISODES`, one command after another, default settings. Each command starts
  a Python process and imports torch, Stable-Baselines3 and MuJoCo (seconds); a sweep pays that once per worker.
- `inprocess`: the same trials by `run_trial` one after another in this process, then the summary tables: no
  start-up per trial, the strictest reference (it isolates what running two trials at a time gains).

The sweep's time includes starting the `vswrist sweep` process, Ray's start and stop, and the summary tables
(which the `cli` loop does not write). All runs start from empty folders; the per-episode metrics of every
reference are compared with the sweep's.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import yaml

SEEDS = list(range(8))
REFERENCES = ("cli", "inprocess")


def sweep_doc(out: Path, label: str, steps: int, episodes: int) -> dict:
    return {"mode": "grid", "tasks": ["LoadHold"], "algos": ["ppo"], "seeds": SEEDS, "episodes": episodes,
            "stiffness": [], "timesteps": {"ppo": steps}, "n_envs": {"ppo": 1},
            "out": str(out / label / "out"), "runs_dir": str(out / label / "runs")}


def _episodes(path: Path) -> list[dict]:
    return [{k: v for k, v in e.items() if k != "agent"} for e in json.loads(path.read_text())["episodes"]]


def _cli(*args) -> float:
    t0 = time.time()
    res = subprocess.run([sys.executable, "-m", "vswrist_gym.cli", *map(str, args)], capture_output=True, text=True)
    if res.returncode != 0:
        raise RuntimeError(f"vswrist {' '.join(map(str, args))} failed: {res.stderr[-2000:]}")
    return time.time() - t0


def run_cli_loop(out: Path, steps: int, episodes: int) -> tuple[float, dict, list[float]]:
    """The user's loop; returns its wall time, metrics file per seed and each trial's seconds."""
    t0, metrics, seconds = time.time(), {}, []
    for s in SEEDS:
        run, ev = out / "cli" / f"ppo_seed{s}", out / "cli" / f"eval_seed{s}"
        seconds.append(_cli("train", "--task", "LoadHold", "--algo", "ppo", "--seed", s, "--timesteps", steps,
                            "--n-envs", 1, "--out", run, "--no-progress")
                       + _cli("evaluate", "--task", "LoadHold", "--agent", run, "--seeds", s, "--episodes", episodes,
                              "--out", ev))
        metrics[s] = ev / "metrics.json"
    return time.time() - t0, metrics, seconds


def run_inprocess(file: Path) -> tuple[float, dict, list[float]]:
    from vswrist_gym.sweep.spec import load_sweep
    from vswrist_gym.sweep.summary import write_summaries
    from vswrist_gym.sweep.trial import run_trial

    t0 = time.time()
    sweep = load_sweep(file)
    sweep.write_entry_files()
    trials = sweep.trials()
    seconds = []
    for t in trials:
        t1 = time.time()
        run_trial(t, log=lambda m: None)
        seconds.append(time.time() - t1)
    write_summaries(sweep, trials, time.time() - t0, command="serial", log=lambda m: None)
    return time.time() - t0, {t["seed"]: Path(t["trial_dir"]) / "metrics.json" for t in trials}, seconds


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m vswrist_gym.sweep.bench", description=__doc__.split("\n\n")[0])
    p.add_argument("--steps", type=int, default=32768, help="PPO steps per trial (default 32768)")
    p.add_argument("--episodes", type=int, default=10, help="evaluation episodes per trial (default 10, as a sweep)")
    p.add_argument("--serial", nargs="+", choices=REFERENCES, default=list(REFERENCES),
                   help="serial references to time (default: both)")
    p.add_argument("--out", default="runs/sweep_bench", help="scratch folder (emptied first)")
    args = p.parse_args(argv)
    for name in ("steps", "episodes"):
        if getattr(args, name) < 1:
            p.error(f"--{name} must be a positive integer, got {getattr(args, name)}")
    out = Path(args.out).resolve()
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    from vswrist_gym.sweep.spec import load_sweep

    files = {}
    for label in ("inprocess", "sweep"):
        files[label] = out / f"{label}.yaml"
        files[label].write_text(yaml.safe_dump(sweep_doc(out, label, args.steps, args.episodes)))
    loads = [os.getloadavg()[0]]
    serial = {}
    for ref in args.serial:
        serial[ref] = run_cli_loop(out, args.steps, args.episodes) if ref == "cli" else run_inprocess(files[ref])
        loads.append(os.getloadavg()[0])

    t0 = time.time()
    res = subprocess.run([sys.executable, "-m", "vswrist_gym.cli", "sweep", str(files["sweep"])],
                         capture_output=True, text=True)
    sweep_s = time.time() - t0
    loads.append(os.getloadavg()[0])
    if res.returncode != 0:
        print(res.stdout[-2000:], res.stderr[-2000:], file=sys.stderr)
        return 1
    trials = load_sweep(files["sweep"]).trials()
    records = [json.loads((Path(t["trial_dir"]) / "result.json").read_text()) for t in trials]
    starts = [r["finished"] - r["seconds"] for r in records]
    in_trials = sum(r["seconds"] for r in records) / len(records)

    print(f"{len(SEEDS)} trials (PPO LoadHold, {args.steps} steps, n_envs 1, + {args.episodes} evaluation episodes "
          f"each) on {os.cpu_count()} cores, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; 1-min load average "
          f"{' -> '.join(f'{x:.1f}' for x in loads)} (start, after each reference, after the sweep)")
    for ref, (wall, metrics, seconds) in serial.items():
        same = all(_episodes(metrics[t["seed"]]) == _episodes(Path(t["trial_dir"]) / "metrics.json") for t in trials)
        what = ("vswrist train + vswrist evaluate, one command after another" if ref == "cli"
                else "run_trial one after another in one process, + summary")
        print(f"serial ({ref}: {what}): {wall:.1f} s, {sum(seconds) / len(seconds):.1f} s per trial; "
              f"per-episode metrics identical to the sweep's: {same}")
    print(f"vswrist sweep (Ray embedded, {os.cpu_count()} CPUs, two trials at a time): {sweep_s:.1f} s = "
          f"{min(starts) - t0:.1f} s until the first trial started (process, Ray, Tune, worker) + "
          f"{max(r['finished'] for r in records) - min(starts):.1f} s of trials ({in_trials:.1f} s per trial) + "
          f"{t0 + sweep_s - max(r['finished'] for r in records):.1f} s after the last (summary, Ray's stop)")
    for ref, (wall, _, seconds) in serial.items():
        slower = (f" (a trial took {in_trials / (sum(seconds) / len(seconds)):.2f}x as long two at a time)"
                  if ref == "inprocess" else "")
        print(f"speed-up over serial {ref}: {wall / sweep_s:.2f}x{slower}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
