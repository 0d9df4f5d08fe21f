"""The single env's step CPU time (``gym.make``), this code against another checkout, in alternating processes
(issue 14's N = 1 target: at most 1.1x the step time of the code before the batch, measured side by side).

    cd /tmp && python /path/to/experiments/batched_speed/single_ab_cpu.py OLD_CHECKOUT [TASK ...] [--pairs 5]

Per task (default: the five tasks both checkouts register, at -v0), ``--pairs`` pairs of processes (old, new), each
pinned to CPU 1: ``gym.make(id)`` with its default action mode, 200 warm-up steps, then 2,000 steps of random
actions from a fixed generator, resets included; printed are each side's median CPU time per step over the pairs
and the median of the pairs' new / old ratios. Run it from outside the checkouts so that PYTHONPATH decides which
one is imported."""
import json
import os
import statistics
import subprocess
import sys

RUN = r'''
import sys, time, os, json
os.sched_setaffinity(0, {1})
import gymnasium as gym, numpy as np, vswrist_gym
env = gym.make(sys.argv[1])
env.reset(seed=0)
rng = np.random.default_rng(0)
A = rng.uniform(-1, 1, (2200,) + env.action_space.shape)
def run(actions):
    for a in actions:
        _, _, te, tr, _ = env.step(a)
        if te or tr:
            env.reset()
run(A[:200])
t0 = time.process_time()
run(A[200:])
print(json.dumps((time.process_time() - t0) / 2000))
'''
TASKS = ("LoadHold", "Polish", "Impact", "Insertion", "Drill")


def step_time(checkout: str, env_id: str) -> float:
    env = dict(os.environ, PYTHONPATH=checkout)
    out = subprocess.run([sys.executable, "-c", RUN, env_id], env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> int:
    args = sys.argv[1:]
    n_pairs = 5
    if "--pairs" in args:
        k = args.index("--pairs")
        try:
            n_pairs = int(args[k + 1])
        except (IndexError, ValueError):
            n_pairs = 0
        if n_pairs < 1:
            print("--pairs takes an integer >= 1 (pairs of processes per task)")
            return 2
        del args[k:k + 2]
    if not args:
        print(__doc__)
        return 2
    old = args[0]
    new = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))  # the repository root
    tasks = args[1:] or TASKS
    print(f"{'task':<12}{'old us':>9}{'new us':>9}{'new/old':>9}   (median of {n_pairs} alternating pairs, CPU 1, "
          f"CPU time; new/old: the median of the pairs' ratios, with their range)")
    for task in tasks:
        env_id = task if "/" in task else f"VSWrist/{task}-v0"
        pairs = [(step_time(old, env_id), step_time(new, env_id)) for _ in range(n_pairs)]
        o = statistics.median(p[0] for p in pairs)
        n = statistics.median(p[1] for p in pairs)
        ratios = [p[1] / p[0] for p in pairs]
        r = statistics.median(ratios)
        print(f"{task:<12}{o * 1e6:>9.0f}{n * 1e6:>9.0f}{r:>9.3f}   ({min(ratios):.3f}-{max(ratios):.3f})", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
