"""Where a batch's step goes: calls per step and milliseconds per step of each phase of
``VSWristVectorEnv`` (wall time), and the cost of the ``stiffness`` observation term over arrays against world by
world (the array term's cost per call is what a batch of few worlds pays for it).

    python experiments/batched_speed/batch_phases.py [--task Drill] [--threads 1 2] [--worlds 32] [--steps 300]

Each setting runs in this process after 30 warm-up steps of random actions (NEXT_STEP autoresets). The phases
nest (``_native_step`` holds ``_begin`` and ``_finish`` on the compiled path; ``_step_core`` holds everything), so
they do not add up. Wall time on a shared VM moves between runs: compare settings within one run.
"""

from __future__ import annotations

import argparse
import time
import timeit

import gymnasium as gym
import numpy as np

import vswrist_gym
from vswrist_gym import LATEST
from vswrist_gym.envs import batch as B

PHASES = ("_step_core", "_native_step", "_begin", "_finish", "_start_resets", "_end_reset", "_vector_info")


def timed_phases() -> dict:
    """Wraps the phases of the batch class with wall-clock timers; returns {phase: [seconds per call]}."""
    record: dict = {}

    def wrap(name):
        fn = getattr(B.VSWristVectorEnv, name)

        def timed(*args, **kwargs):
            t0 = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                record.setdefault(name, []).append(time.perf_counter() - t0)

        setattr(B.VSWristVectorEnv, name, timed)

    for name in PHASES:
        wrap(name)
    return record


def stiffness_costs(env_id: str, n: int = 4, number: int = 500) -> tuple[float, float]:
    """(us per call of the array term for ``n`` worlds, us per world of the single env's term)."""
    v = gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", threads=1)
    v.reset(seed=0)
    venv, worlds = v.unwrapped, v.unwrapped.envs
    first = worlds[0]
    P = np.array([e._posture for e in worlds])
    D = np.array([e._defl for e in worlds])
    law = B.SpringLaw(np.array([[e.params.spring.K] for e in worlds]), np.array([[e.params.spring.delta0]
                                                                                  for e in worlds]))
    arrays = timeit.timeit(lambda: venv._coupler_stiffness(first, P, D, law), number=number) / number
    single = timeit.timeit(lambda: first._obs_stiffness(), number=number) / number
    v.close()
    return 1e6 * arrays, 1e6 * single


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--task", default="Drill")
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--worlds", type=int, default=32)
    ap.add_argument("--steps", type=int, default=300)
    args = ap.parse_args(argv)
    env_id = LATEST[args.task] if args.task in LATEST else args.task
    record = timed_phases()
    for threads in args.threads:
        v = gym.make_vec(env_id, num_envs=args.worlds, vectorization_mode="vector_entry_point", threads=threads)
        acts = np.random.default_rng(0).uniform(-1, 1, (args.steps + 30, args.worlds) + v.single_action_space.shape)
        v.reset(seed=0)
        for a in acts[:30]:
            v.step(a)
        record.clear()
        t0 = time.perf_counter()
        for a in acts[30:]:
            v.step(a)
        wall = time.perf_counter() - t0
        v.close()
        print(f"{env_id}, {args.worlds} worlds, {threads} thread(s): {1e3 * wall / args.steps:.3f} ms per step")
        for name in PHASES:
            x = record.get(name, [])
            if x:
                print(f"  {name:<14} calls/step {len(x) / args.steps:5.2f}  ms/step {1e3 * sum(x) / args.steps:6.3f}"
                      f"  ms/call {1e3 * np.mean(x):6.3f}")
    arrays, single = stiffness_costs(env_id)
    print(f"stiffness term: {arrays:.0f} us per array call of 4 worlds, {single:.1f} us per world one by one")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
