"""Sweep speed-up: a grid of 8 short trials run one after another in this process, then as a `vswrist sweep` on
Ray embedded on this machine; prints both wall times and their ratio (not a test: it measures the machine).

    python -m vswrist_gym.sweep.bench [--steps 16384] [--out runs/sweep_bench]

The trials are PPO on LoadHold, 8 seeds, one environment each (`n_envs: 1`, `vec_env: dummy`: one CPU per trial,
so a 2-core machine runs two at a time), followed by the evaluation protocol (2 episodes). The Ray time includes
starting Ray and the summary tables; the serial time includes the same summary. Both start from empty folders.
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


def sweep_doc(out: Path, label: str, steps: int) -> dict:
    return {"mode": "grid", "tasks": ["LoadHold"], "algos": ["ppo"], "seeds": list(range(8)), "episodes": 2,
            "stiffness": [], "timesteps": {"ppo": steps},
            "overrides": {"ppo": {"n_envs": 1, "vec_env": "dummy", "eval_freq": steps, "n_eval_episodes": 1,
                                  "checkpoint_freq": steps}},
            "out": str(out / label / "out"), "runs_dir": str(out / label / "runs")}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m vswrist_gym.sweep.bench", description=__doc__.split("\n\n")[0])
    p.add_argument("--steps", type=int, default=16384, help="PPO steps per trial (default 16384)")
    p.add_argument("--out", default="runs/sweep_bench", help="scratch folder (emptied first)")
    args = p.parse_args(argv)
    out = Path(args.out).resolve()
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    load0 = os.getloadavg()[0]

    from vswrist_gym.sweep.spec import load_sweep
    from vswrist_gym.sweep.summary import write_summaries
    from vswrist_gym.sweep.trial import run_trial

    files = {}
    for label in ("serial", "ray"):
        files[label] = out / f"{label}.yaml"
        files[label].write_text(yaml.safe_dump(sweep_doc(out, label, args.steps)))
    t0 = time.time()
    sweep = load_sweep(files["serial"])
    sweep.write_entry_files()
    trials = sweep.trials()
    for t in trials:
        run_trial(t, log=lambda m: None)
    write_summaries(sweep, trials, time.time() - t0, command="serial", log=lambda m: None)
    serial_s = time.time() - t0

    t0 = time.time()
    res = subprocess.run([sys.executable, "-m", "vswrist_gym.cli", "sweep", str(files["ray"])], capture_output=True,
                         text=True)
    ray_s = time.time() - t0
    if res.returncode != 0:
        print(res.stdout[-2000:], res.stderr[-2000:], file=sys.stderr)
        return 1
    same = all(json.loads((Path(a["trial_dir"]) / "metrics.json").read_text())["episodes"]
               == json.loads((Path(b["trial_dir"]) / "metrics.json").read_text())["episodes"]
               for a, b in zip(trials, load_sweep(files["ray"]).trials()))
    print(f"8 trials (PPO LoadHold, {args.steps} steps + 2 evaluation episodes each) on {os.cpu_count()} cores, "
          f"1-min load average {load0:.1f} at start, {os.getloadavg()[0]:.1f} at end, "
          f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}")
    print(f"serial (one process, one trial after another): {serial_s:.1f} s")
    print(f"vswrist sweep (Ray embedded, {os.cpu_count()} CPUs, startup included): {ray_s:.1f} s")
    print(f"speed-up: {serial_s / ray_s:.2f}x; per-episode metrics identical to serial: {same}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
