"""Microseconds of the small per-step and per-reset pieces a change of this kind touches, on the code
PYTHONPATH imports, so that two checkouts can be compared:

    cd /tmp && PYTHONPATH=<checkout> python <repo>/experiments/batched_speed/hook_costs.py

Printed (median of 5 timeit runs each, one thread pinned to CPU 1): the analytic controller's step
(``AnalyticController.step`` with a commanded lam); the load hook of one Drill world while it drills and of one
LoadHold world once loaded (``_before_physics``); the internal-torque basis of one posture, and per posture in
a stack of 64 where the kinematics takes stacks (``WristKinematics.internal_torque_basis``)."""
import os
import statistics
import timeit

import gymnasium as gym
import numpy as np

import vswrist_gym  # noqa: F401
from vswrist_gym.control import AnalyticController
from vswrist_gym.kinematics import WristKinematics


def us(fn, number: int) -> float:
    return 1e6 * statistics.median(timeit.repeat(fn, number=number, repeat=5)) / number


def main() -> int:
    if hasattr(os, "sched_setaffinity") and (os.cpu_count() or 1) > 1:
        os.sched_setaffinity(0, {1})
    ctrl, ref = AnalyticController(), np.array([0.1, 0.2, 0.3])
    print(f"controller step                     {us(lambda: ctrl.step(ref, lam=0.5), 20000):8.1f} us")
    drill = gym.make("VSWrist/Drill-v0").unwrapped
    drill.reset(seed=0)
    t_drill = drill._t_on + 0.1
    print(f"Drill load hook, one world drilling {us(lambda: drill._before_physics(t_drill), 5000):8.1f} us")
    hold = gym.make("VSWrist/LoadHold-v0").unwrapped
    hold.reset(seed=0)
    t_hold = hold._onset + 0.1
    print(f"LoadHold load hook, one world loaded{us(lambda: hold._before_physics(t_hold), 5000):8.1f} us")
    kin = WristKinematics()
    U = np.random.default_rng(0).uniform(kin.u_min, kin.u_max, (64, 2))
    print(f"internal-torque basis, one posture  {us(lambda: kin.internal_torque_basis(U[0]), 500):8.1f} us")
    try:
        kin.internal_torque_basis(U)
    except ValueError:
        print("internal-torque basis, stack of 64: this checkout takes one posture at a time")
    else:
        print(f"internal-torque basis, per posture of a stack of 64 "
              f"{us(lambda: kin.internal_torque_basis(U), 20) / 64:8.1f} us")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
