"""How many chunks a threaded batch's step should split its worlds into (``batch_physics.CHUNKS_PER_THREAD``,
``MIN_CHUNK_WORLDS``): wall time per step of one batch on 2 threads, each setting in turn, rounds alternated.

    python experiments/batched_speed/chunk_count.py [--task LoadHold-v2] [--worlds 32 64] [--rounds 3]

Random actions from a fixed generator, 40 steps per round after 3 unmeasured; the median over rounds of each
setting's mean step time. The settings change only which worlds' Python runs beside which worlds' physics, never a
world's numbers.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import vswrist_gym  # noqa: F401
from vswrist_gym.envs import batch_physics
from vswrist_gym.envs.batch import VSWristVectorEnv

SETTINGS = ((4, 4), (8, 2), (16, 2))  # (chunks per thread, least worlds per chunk)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--task", default="LoadHold-v2")
    ap.add_argument("--worlds", type=int, nargs="+", default=[32, 64])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args(argv)
    kept = batch_physics.CHUNKS_PER_THREAD, batch_physics.MIN_CHUNK_WORLDS
    for n in args.worlds:
        batch = VSWristVectorEnv(f"VSWrist/{args.task}", n, threads=args.threads)
        acts = np.random.default_rng(0).uniform(-1, 1, (43, n) + batch.single_action_space.shape)
        times: dict = {}
        for r in range(args.rounds):
            for setting in SETTINGS:
                batch_physics.CHUNKS_PER_THREAD, batch_physics.MIN_CHUNK_WORLDS = setting
                batch.reset(seed=r)
                for a in acts[:3]:
                    batch.step(a)
                t0 = time.perf_counter()
                for a in acts[3:]:
                    batch.step(a)
                times.setdefault(setting, []).append((time.perf_counter() - t0) / 40)
        batch.close()
        base = np.median(times[SETTINGS[0]])
        for (per_thread, least), t in times.items():
            k = min(per_thread * args.threads, n // least)
            print(f"{args.task} {n} worlds, {args.threads} threads: {per_thread} chunks per thread, at least {least} "
                  f"worlds ({k} chunks): {1e3 * np.median(t):.2f} ms per step, {np.median(t) / base:.3f} of the first")
    batch_physics.CHUNKS_PER_THREAD, batch_physics.MIN_CHUNK_WORLDS = kept


if __name__ == "__main__":
    main()
