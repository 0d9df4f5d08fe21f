"""Drill's `paper` variant: is the oracle's gain the drill's disturbance or the start? (docs/environments.md,
Stiffness range). ``python docs/paperrange/drill_start.py``: mean return over seeds 1000-1011 and the episodes whose
posture error over the last 0.5 s is above 0.5 rad, for constant commands and for schedules that step from +0.5 to
+1 at a fixed time, unrelated to when the drill engages (slewed as the probe's rules are)."""

import gymnasium as gym
import numpy as np

import vswrist_gym  # noqa: F401
from vswrist_gym.envs.variants import variant_config
from vswrist_gym.tools.probe import _slew

env = gym.make("VSWrist/Drill-v0", config=variant_config("Drill"))
u = env.unwrapped
for name, sched in [("constant +0.5", lambda t: 0.5), ("constant +1", lambda t: 1.0),
                    ("+0.5, then +1 from 0.5 s", lambda t: 0.5 if t < 0.5 else 1.0),
                    ("+0.5, then +1 from 1.5 s", lambda t: 0.5 if t < 1.5 else 1.0)]:
    returns, settled_off = [], 0
    for seed in range(1000, 1012):
        obs, _ = env.reset(seed=seed)
        state, total, errs, done = {}, 0.0, [], False
        while not done:
            a = u.reference_to_action(obs[u.obs_slices["target"]], _slew(state, sched(u._t), u.ctrl_dt))
            obs, r, term, trunc, info = env.step(a)
            total += r
            errs.append(info["posture_error"])
            done = term or trunc
        returns.append(total)
        settled_off += np.mean(errs[-25:]) > 0.5
    print(f"{name:<26} mean return {np.mean(returns):8.1f}, settled > 0.5 rad off in {settled_off}/12")
