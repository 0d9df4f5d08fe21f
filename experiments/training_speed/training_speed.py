"""Training speed and returns at equal env steps: the pre-batch default (a process per env) against the default.

    python experiments/training_speed/training_speed.py [--task LoadHold] [--algo ppo] [--timesteps 80000] [--seeds 0 1 2]
                                     [--out experiments/training_speed] [--worlds N]
                                     [--variant LABEL KEY=VALUE [KEY=VALUE ...]] ...

Trains, with the packaged hyperparameters of ``--algo`` for the task, one run per setting and seed through the
``vswrist train`` command:

* ``subproc-2``: the pre-batch default: ``--vec-env subproc`` with 2 envs (a process each) and, for PPO, the
  entry as it was before the batch (``PRE_BATCH_PPO``: 2 x 512 steps per rollout, 128-sample minibatches,
  learning rate 3e-4), the entry most committed results were produced with;
* ``default``: the packaged entry as it is (``vec_env: batch``: its ``n_envs`` worlds in one process);
* ``batch-N`` (with ``--worlds N``): ``--vec-env batch`` with N worlds, PPO's ``n_steps`` scaled so that a
  rollout holds as many env steps as the packaged entry's;
* ``LABEL`` (with ``--variant LABEL KEY=VALUE ...``, repeatable): the packaged entry with those keys set (values
  read as YAML: ``batch_size=256 learning_rate=6.0e-4``), to measure a retuned entry before it is packaged.

Speed: env steps per second of training from the episode logs (Monitor/VecMonitor ``t``: seconds since the envs
were made, so start-up is excluded; evaluation and updates are included). Returns: the mean episode return in
each quarter of the budget (episodes ordered by their end time; env steps counted over all worlds), and a Welch
t-test against ``subproc-2`` of the training seeds' last-quarter means (the seed is the unit of replication:
episodes of one run are not independent), with its two-sided p-value (SciPy). A short run shows the mechanics
and the speed; equal returns need the full budgets and several seeds.
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

# PPO's pre-batch entry for the VS-Wrist tasks: what `vswrist train` ran before the batched env (and what the
# committed sweeps pin), so that the reference stays "today's default" whatever the packaged entry becomes.
PRE_BATCH_PPO = {"n_envs": 2, "n_steps": 512, "batch_size": 128, "learning_rate": 3.0e-4}


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
    """Welch's t statistic of mean(a) - mean(b) and its two-sided p-value (NaN with fewer than 2 values a side)."""
    if len(a) < 2 or len(b) < 2:
        return float("nan"), float("nan")
    from scipy import stats

    res = stats.ttest_ind(a, b, equal_var=False)
    return float(res.statistic), float(res.pvalue)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--task", default="LoadHold")
    ap.add_argument("--algo", default="ppo", choices=("ppo", "sac"))
    ap.add_argument("--timesteps", type=int, default=80000)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--worlds", type=int, default=None, help="also a batch of N worlds (PPO's n_steps scaled)")
    ap.add_argument("--variant", nargs="+", action="append", default=[], metavar="LABEL KEY=VALUE",
                    help="also the packaged entry with these keys set (repeatable)")
    ap.add_argument("--out", default=None, help="folder for the runs and results.json (default: a temp folder)")
    args = ap.parse_args(argv)
    from vswrist_gym import resolve_id

    env_id = resolve_id(args.task)  # a short name is the task's newest version
    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="training_speed_"))
    out.mkdir(parents=True, exist_ok=True)

    from vswrist_gym.agents.hparams import CONFIG_DIR, RUN_SECTION

    packaged = yaml.safe_load((CONFIG_DIR / f"{args.algo}.yaml").read_text())
    entry = packaged[env_id]
    # the packaged run settings (evaluation and checkpoint frequencies) go with every setting, so that each does
    # the same work beside training; the vec env is each setting's own flag
    section = packaged.get(RUN_SECTION, {}).get(env_id, {})
    run_section = {k: v for k, v in section.items() if k != "vec_env"}

    def write(label: str, e: dict) -> Path:
        path = out / f"{args.algo}_{label}.yaml"
        doc = {env_id: e, RUN_SECTION: {env_id: run_section}} if run_section else {env_id: e}
        path.write_text(yaml.safe_dump(doc, sort_keys=False))
        return path
    base_envs = int(entry.get("n_envs", 1))

    def with_envs(n: int, label: str, pre_batch: bool = False) -> Path:
        scaled = dict(entry, n_envs=n)
        if args.algo == "ppo" and pre_batch:
            scaled.update(PRE_BATCH_PPO)
        elif args.algo == "ppo":  # the same env steps per rollout, so the same updates per env step
            scaled["n_steps"] = max(1, int(entry.get("n_steps", 2048)) * base_envs // n)
        return write(label, scaled)

    settings = {"subproc-2": ["--vec-env", "subproc", "--config", str(with_envs(2, "subproc2", pre_batch=True))],
                "default": []}
    if args.worlds:
        settings[f"batch-{args.worlds}"] = ["--vec-env", "batch", "--config",
                                            str(with_envs(args.worlds, f"batch{args.worlds}"))]

    entry_vec_env = section.get("vec_env", entry.get("vec_env", "batch"))
    for label, *pairs in args.variant:
        changed = dict(entry)
        for pair in pairs:
            key, sep, value = pair.partition("=")
            if not sep or not key:
                ap.error(f"--variant {label}: {pair!r} is not KEY=VALUE")
            changed[key] = yaml.safe_load(value)
        if label in settings:
            ap.error(f"--variant {label}: that label is taken")
        settings[label] = ["--vec-env", str(entry_vec_env), "--config", str(write(label, changed))]

    results = {}
    # seed by seed, the settings back to back: the machine's drift over the runs falls on every setting alike
    for seed in args.seeds:
        for name, extra in settings.items():
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
    print(f"{'setting':<12}{'steps/s':>9}{'x subproc-2':>12}" + "".join(f"{f'ret Q{q + 1}':>10}" for q in range(4))
          + f"{'t (last Q)':>11}{'p':>6}   last-quarter mean per seed")
    doc = {"task": env_id, "algo": args.algo, "timesteps": args.timesteps, "seeds": args.seeds, "settings": {}}
    ref_speed = sum(results[("subproc-2", s)]["steps_per_s"] for s in args.seeds) / len(args.seeds)

    def seed_means(name: str) -> list[float]:
        return [sum(results[(name, s)]["last"]) / max(len(results[(name, s)]["last"]), 1) for s in args.seeds]

    ref_last = seed_means("subproc-2")
    for name in settings:
        rs = [results[(name, s)] for s in args.seeds]
        speed = sum(r["steps_per_s"] for r in rs) / len(rs)
        quarters = [sum(r["quarters"][q] for r in rs) / len(rs) for q in range(4)]
        last = seed_means(name)
        t, pval = welch(last, ref_last)
        print(f"{name:<12}{speed:>9.0f}{speed / ref_speed:>12.2f}" + "".join(f"{q:>10.1f}" for q in quarters)
              + f"{t:>11.2f}{pval:>6.2f}   " + " ".join(f"{x:.1f}" for x in last))
        doc["settings"][name] = {"steps_per_s": speed, "vs_subproc_2": speed / ref_speed, "quarter_returns": quarters,
                                 "last_quarter_per_seed": last, "welch_t_last_quarter": t, "welch_p": pval,
                                 "args": settings[name]}
    (out / "results.json").write_text(json.dumps(doc, indent=2))
    print(f"runs and results.json in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
