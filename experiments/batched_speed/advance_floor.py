"""The floor of env step / physics: what the compiled advance costs beyond its ``mj_step`` substeps, with no
Python at all, for each sync the advance can end a period with (none; poses and velocities only, as LoadHold's;
a full ``mj_forward`` with the sensors, as every task that reads a touch or force/torque sensor):

    python experiments/batched_speed/advance_floor.py [--worlds 32] [--periods 60] [--repeats 3]

One thread pinned to CPU 1; per task, ``repeats`` x each sync, ``periods`` control periods of ``worlds`` worlds
at their reset state (fixed motor references), CPU time of the calls over the CPU time inside their substeps
(timed by the advance itself); the medians. ``in use`` is the sync the task's batch ends each period with. The
issue-14 target (env step / physics <= 1.10) leaves the Python of a step whatever the floor of the sync in use
leaves of 0.10."""
from __future__ import annotations

import argparse
import os
import time

import gymnasium as gym
import numpy as np

import vswrist_gym
from vswrist_gym.model import advance_lib as A

SYNCS = ((A.SYNC_NONE, "none"), (A.SYNC_KINEMATICS, "poses"), (A.SYNC_FORWARD, "mj_forward"))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--worlds", type=int, default=32)
    ap.add_argument("--periods", type=int, default=60)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    if hasattr(os, "sched_setaffinity") and (os.cpu_count() or 1) > 1:
        os.sched_setaffinity(0, {1})
    n = args.worlds
    print(f"{'task':<11}{'substeps':>9}" + "".join(f"{lab:>12}" for _, lab in SYNCS) + f"{'in use':>12}")
    for task, env_id in vswrist_gym.LATEST.items():
        v = gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", threads=1)
        core = v.unwrapped
        bsim = core.batch_sim
        if bsim.lib is None:
            print(f"{task:<11} no compiled advance (no C++ compiler)")
            v.close()
            continue
        v.reset(seed=0)
        worlds = np.arange(n, dtype=np.int32)
        theta = np.ascontiguousarray([e.sim.motor_references() for e in core.envs])
        status = np.zeros(n, dtype=np.int32)
        ratios: dict[str, list] = {}
        for _ in range(args.repeats):
            for sync, label in SYNCS:
                seconds = np.zeros(n)
                t0 = time.process_time()
                for _ in range(args.periods):
                    A.advance(bsim.lib, bsim.handles, worlds, theta, bsim.ctrl_idx, bsim.nstep, sync, status,
                              seconds)
                ratios.setdefault(label, []).append((time.process_time() - t0) / float(seconds.sum()))
        used = dict((s, lab) for s, lab in SYNCS)[bsim.sync]
        print(f"{task:<11}{bsim.nstep:>9}" + "".join(f"{np.median(ratios[lab]):>12.3f}" for _, lab in SYNCS)
              + f"{used:>12}")
        v.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
