"""Training speed and returns at equal env steps: a process per env (the pre-batch default) against the batch.

    python results/training_speed.py [--task LoadHold] [--algo ppo] [--timesteps 8192] [--seeds 0 1]
                                     [--out results/training_speed] [--worlds 16]

Trains, with the packaged hyperparameters of ``--algo`` for the task, one run per setting and seed through the
``vswrist train`` command:

* ``subproc``: ``--vec-env subproc`` with the config's ``n_envs`` (a process per env: the pre-batch default);
* ``batch``: ``--vec-env batch`` with the config's ``n_envs`` (the default now);
* ``batch-N``: ``--vec-env batch`` with ``--worlds`` worlds and, for PPO, ``n_steps`` scaled so that a rollout
  holds as many env steps as the config's (so the update schedule per env step is the same).

Speed: env steps per second of training from the episode logs (Monitor/VecMonitor ``t``: seconds since the envs
were made, so start-up is excluded; evaluation and updates are included). Returns: the mean episode return in
each quarter of the budget (episodes ordered by their end time; env steps counted over all worlds), and a Welch
t-test of the last quarter against ``subproc``. A short run shows the mechanics and the speed; equal returns
need the full budgets and several seeds.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import subprocess
import sys
import tempfile
from pathlib import Path

import yaml


def episodes(run_dir: Path) -> list[tuple[float, int, float]]:
    """(end time s, length, return) of every training episode, over all monitor logs of the run, by end time."""
    rows = []
    for f in (run_dir / "monitor").glob("*.monitor.csv"):
        with f.open() as fh:
            next(fh)  # the JSON header line
            for r in csv.DictReader(fh):
                rows.append((float(r["t"]), int(r["l"]), float(r["r"])))
    return sorted(rows)


def summarise(rows, budget: int) -> dict:
    steps, quarters = 0, [[] for _ in range(4)]
    for _, length, ret in rows:
        steps += length
        quarters[min(3, (steps - 1) * 4 // budget)].append(ret)
    t_end = rows[-1][0] if rows else float("nan")
    return {"env_steps": steps, "seconds": t_end, "steps_per_s": steps / t_end if rows else float("nan"),
            "quarters": [sum(q) / len(q) if q else float("nan") for q in quarters], "last": quarters[3]}


def welch(a: list[float], b: list[float]) -> tuple[float, float]:
    """Welch's t statistic and its degrees of freedom (NaN with fewer than 2 samples a side)."""
    if len(a) < 2 or len(b) < 2:
        return float("nan"), float("nan")
    ma, mb = sum(a) / len(a), sum(b) / len(b)
    va = sum((x - ma) ** 2 for x in a) / (len(a) - 1) / len(a)
    vb = sum((x - mb) ** 2 for x in b) / (len(b) - 1) / len(b)
    if va + vb == 0:
        return float("nan"), float("nan")
    t = (ma - mb) / math.sqrt(va + vb)
    df = (va + vb) ** 2 / ((va ** 2 / (len(a) - 1) if va else 0) + (vb ** 2 / (len(b) - 1) if vb else 0))
    return t, df


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--task", default="LoadHold")
    ap.add_argument("--algo", default="ppo", choices=("ppo", "sac"))
    ap.add_argument("--timesteps", type=int, default=8192)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--worlds", type=int, default=16, help="worlds of the batch-N setting (default 16)")
    ap.add_argument("--out", default=None, help="folder for the runs and results.json (default: a temp folder)")
    args = ap.parse_args(argv)
    from vswrist_gym import resolve_id

    env_id = resolve_id(args.task)  # a short name is the task's newest version
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="training_speed_"))
    out.mkdir(parents=True, exist_ok=True)

    from vswrist_gym.agents.hparams import CONFIG_DIR

    entry = yaml.safe_load((CONFIG_DIR / f"{args.algo}.yaml").read_text())[env_id]
    base_envs = int(entry.get("n_envs", 1))
    scaled = dict(entry, n_envs=args.worlds)
    if args.algo == "ppo":
        scaled["n_steps"] = max(1, int(entry.get("n_steps", 2048)) * base_envs // args.worlds)
    scaled_cfg = out / f"{args.algo}_batch_{args.worlds}.yaml"
    scaled_cfg.write_text(yaml.safe_dump({env_id: scaled}, sort_keys=False))
    settings = {"subproc": ["--vec-env", "subproc"], "batch": ["--vec-env", "batch"],
                f"batch-{args.worlds}": ["--vec-env", "batch", "--config", str(scaled_cfg)]}

    results = {}
    for name, extra in settings.items():
        for seed in args.seeds:
            run = out / f"{name}_seed{seed}"
            cmd = [sys.executable, "-m", "vswrist_gym.cli", "train", "--task", env_id, "--algo", args.algo,
                   "--timesteps", str(args.timesteps), "--seed", str(seed), "--out", str(run), "--no-progress",
                   *extra]
            if run.exists():
                cmd.append("--resume")
            res = subprocess.run(cmd, capture_output=True, text=True)
            if res.returncode != 0:
                print(res.stderr, file=sys.stderr)
                return res.returncode
            results[(name, seed)] = summarise(episodes(run), args.timesteps)
            r = results[(name, seed)]
            print(f"{name:<12} seed {seed}: {r['steps_per_s']:.0f} env steps/s over {r['env_steps']} steps", flush=True)

    print(f"\n{env_id}, {args.algo.upper()}, {args.timesteps} steps, seeds {args.seeds}")
    print(f"{'setting':<12}{'steps/s':>9}{'x subproc':>10}" + "".join(f"{f'ret Q{q + 1}':>10}" for q in range(4))
          + f"{'t (last Q)':>11}{'df':>6}")
    doc = {"task": env_id, "algo": args.algo, "timesteps": args.timesteps, "seeds": args.seeds, "settings": {}}
    ref_speed = sum(results[("subproc", s)]["steps_per_s"] for s in args.seeds) / len(args.seeds)
    ref_last = [x for s in args.seeds for x in results[("subproc", s)]["last"]]
    for name in settings:
        rs = [results[(name, s)] for s in args.seeds]
        speed = sum(r["steps_per_s"] for r in rs) / len(rs)
        quarters = [sum(r["quarters"][q] for r in rs) / len(rs) for q in range(4)]
        last = [x for r in rs for x in r["last"]]
        t, df = welch(last, ref_last)
        print(f"{name:<12}{speed:>9.0f}{speed / ref_speed:>10.2f}" + "".join(f"{q:>10.1f}" for q in quarters)
              + f"{t:>11.2f}{df:>6.0f}")
        doc["settings"][name] = {"steps_per_s": speed, "vs_subproc": speed / ref_speed, "quarter_returns": quarters,
                                 "welch_t_last_quarter": t, "welch_df": df, "args": settings[name]}
    (out / "results.json").write_text(json.dumps(doc, indent=2))
    print(f"runs and results.json in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
