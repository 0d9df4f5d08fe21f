"""Where Hammer's single-env time goes: its steps against its resets, and inside a reset the swing reference
(``envs.ramp.ramp_reference``, integrated at 1 ms with two evaluations of the legs' rate per point).

``python experiments/batched_speed/hammer_reset_cost.py [--steps 1200]``: random actions from a fixed generator, default config
(60-step episodes), CPU time of this process; run it under ``flock /work/bench.lock`` on a shared machine.
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import numpy as np

import vswrist_gym  # noqa: F401
from vswrist_gym.envs import ramp as hammer  # the swing ramps (patched below to time them)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=1200)
    args = ap.parse_args(argv)
    env = gym.make("VSWrist/Hammer-v0")
    env.reset(seed=0)
    actions = np.random.default_rng(0).uniform(-1, 1, (args.steps, 4)).astype(np.float32)
    ramp, in_ramp = hammer.ramp_reference, [0.0]

    def timed_ramp(*a, **k):
        t = time.process_time()
        try:
            return ramp(*a, **k)
        finally:
            in_ramp[0] += time.process_time() - t

    hammer.ramp_reference = timed_ramp
    in_step = in_reset = 0.0
    resets = 0
    for a in actions:
        t = time.process_time()
        *_, term, trunc, _ = env.step(a)
        in_step += time.process_time() - t
        if term or trunc:
            t = time.process_time()
            env.reset()
            in_reset += time.process_time() - t
            resets += 1
    resets = max(resets, 1)
    print(f"{args.steps} steps: {1e6 * in_step / args.steps:.0f} us per step; {resets} resets: "
          f"{1e3 * in_reset / resets:.1f} ms each, {1e3 * in_ramp[0] / resets:.1f} ms of it in ramp_reference; "
          f"resets take {in_reset / (in_step + in_reset):.0%} of the time")


if __name__ == "__main__":
    main()
