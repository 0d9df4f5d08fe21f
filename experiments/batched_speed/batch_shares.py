"""Where a batch's step goes, in units of the physics: CPU time of each phase over the CPU time inside the worlds'
``mj_step`` substeps (``physics_seconds``, timed by the compiled advance), one thread pinned to CPU 1, after 30
warm-up steps of random actions. What is left once the physics is paid, and which part grows with the worlds:

    python experiments/batched_speed/batch_shares.py [--task Drill] [--worlds 32 128] [--steps 600]

``advance`` is the compiled call (its share above 1 is its own work beside mj_step: motor references, the sync of
poses and sensors, the checks); ``_settle`` is the resets' settling physics (bench-env counts it as physics);
``_reset_begin_worlds``, ``_reset_worlds`` and ``_reset_finish`` are the resets' Python. The phases nest
(``_start_resets`` holds ``_reset_begin_worlds``, ``_settle`` and ``_reset_worlds``), so they do not add up."""
from __future__ import annotations

import argparse
import inspect
import os
import time

import gymnasium as gym
import numpy as np

import vswrist_gym  # noqa: F401
from vswrist_gym import LATEST
from vswrist_gym.envs import base, batch as B
from vswrist_gym.model import advance_lib

acc: dict = {}


def timed(owner, name: str) -> None:
    static = inspect.getattr_static(owner, name)
    fn = static.__func__ if isinstance(static, classmethod) else getattr(owner, name)

    def wrapper(*args, **kwargs):
        t0 = time.process_time()
        try:
            return fn(*args, **kwargs)
        finally:
            acc[name] = acc.get(name, 0.0) + time.process_time() - t0

    setattr(owner, name, classmethod(wrapper) if isinstance(static, classmethod) else wrapper)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--task", default="Drill")
    ap.add_argument("--worlds", type=int, nargs="+", default=[32, 128])
    ap.add_argument("--steps", type=int, default=600)
    args = ap.parse_args(argv)
    if hasattr(os, "sched_setaffinity") and os.cpu_count() and os.cpu_count() > 1:
        os.sched_setaffinity(0, {1})
    for name in ("_finish", "_begin", "_start_resets", "_end_reset", "_vector_info", "_after_native"):
        timed(B.VSWristVectorEnv, name)
    for name in ("_reset_begin_worlds", "_reset_worlds", "_settle", "_reset_finish"):
        timed(base.VSWristEnv, name)
    timed(advance_lib, "advance")
    env_id = LATEST.get(args.task, args.task)
    for n in args.worlds:
        v = gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", threads=1)
        rng = np.random.default_rng(0)
        acts = rng.uniform(-1, 1, (args.steps + 30,) + v.action_space.shape)
        v.reset(seed=0)
        for a in acts[:30]:
            v.step(a)
        v.unwrapped.physics_seconds = 0.0
        acc.clear()
        t0 = time.process_time()
        for a in acts[30:]:
            v.step(a)
        cpu = time.process_time() - t0
        phys = v.unwrapped.physics_seconds
        v.close()
        settle = acc.get("_settle", 0.0)
        print(f"{env_id}, {n} worlds, 1 thread: CPU / mj_step {cpu / phys:.3f}; with the settling counted as "
              f"physics (bench-env's env/phys) {cpu / (phys + settle):.3f}")
        for name, x in sorted(acc.items(), key=lambda kv: -kv[1]):
            print(f"  {name:<15} {x / phys:6.3f} x mj_step")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
