"""A batch's step time on this code against another checkout, in alternating processes (the VM's drift between
runs falls on both alike).

    python experiments/batched_speed/batch_ab.py --old PATH [--tasks LoadHold Polish Hammer] [--pairs 5] [--worlds 32] [--steps 200]

``PATH``: a checkout of the other code (e.g. ``git worktree add /tmp/old 2535bdc``), put first on PYTHONPATH
of its processes. Each process builds a batch of ``--worlds`` worlds of the task, steps it 30 times to warm
up, then times ``--steps`` steps of random actions on 1 thread and on 2 threads (wall time; NEXT_STEP
autoresets). Printed per task: the medians and ranges over the pairs of old / new step time on 1 and on 2
threads, and of each side's 2-thread speed-up.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

ONE_RUN = r"""
import json, sys, time
import gymnasium as gym, numpy as np
import vswrist_gym
from vswrist_gym import LATEST
task, n, steps = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
out = {}
for threads in (1, 2):
    v = gym.make_vec(LATEST[task], num_envs=n, vectorization_mode="vector_entry_point", threads=threads)
    acts = np.random.default_rng(0).uniform(-1, 1, (steps + 30, n) + v.single_action_space.shape)
    v.reset(seed=0)
    for a in acts[:30]:
        v.step(a)
    t0 = time.perf_counter()
    for a in acts[30:]:
        v.step(a)
    out[threads] = 1e6 * (time.perf_counter() - t0) / (steps * n)
    v.close()
print(json.dumps(out))
"""


def run(root: Path, task: str, n: int, steps: int) -> dict:
    env = dict(os.environ, PYTHONPATH=str(root))
    res = subprocess.run([sys.executable, "-c", ONE_RUN, task, str(n), str(steps)], env=env, capture_output=True,
                         text=True, cwd=root)
    if res.returncode != 0:
        raise SystemExit(f"{root}: {res.stderr.strip().splitlines()[-1:]}")
    return {int(k): v for k, v in json.loads(res.stdout.strip().splitlines()[-1]).items()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--old", required=True, type=Path, help="checkout of the code to compare with")
    ap.add_argument("--tasks", nargs="+", default=["LoadHold", "Polish", "Hammer"])
    ap.add_argument("--pairs", type=int, default=5)
    ap.add_argument("--worlds", type=int, default=32)
    ap.add_argument("--steps", type=int, default=200)
    args = ap.parse_args(argv)
    new = Path(__file__).resolve().parents[1]
    if not (args.old / "vswrist_gym").is_dir():
        ap.error(f"--old {args.old} is not a checkout of vswrist-gym (no vswrist_gym/ in it)")
    rows: dict = {t: {"old": [], "new": []} for t in args.tasks}
    for _ in range(args.pairs):
        for task in args.tasks:
            rows[task]["old"].append(run(args.old.resolve(), task, args.worlds, args.steps))
            rows[task]["new"].append(run(new, task, args.worlds, args.steps))

    def stat(xs: list[float]) -> str:
        return f"{statistics.median(xs):.2f} ({min(xs):.2f}-{max(xs):.2f})"

    print(f"{args.worlds} worlds, {args.steps} steps, {args.pairs} alternating pairs; medians (ranges)")
    print(f"{'task':<10}{'old/new, 1 thread':>22}{'old/new, 2 threads':>22}{'speed-up old':>20}{'speed-up new':>20}")
    for task, v in rows.items():
        o, n = v["old"], v["new"]
        one, two = stat([a[1] / b[1] for a, b in zip(o, n)]), stat([a[2] / b[2] for a, b in zip(o, n)])
        print(f"{task:<10}{one:>22}{two:>22}{stat([a[1] / a[2] for a in o]):>20}{stat([b[1] / b[2] for b in n]):>20}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
