"""Replay a search run's final policy (deterministic) on Hammer reset seeds: return, strike speed and time, and
the stiffness command (nominal + scale x action, clipped to [-1, 1]) and FE posture residual at each control step
up to the strike, to see whether the policy schedules the stiffness (the probe's rule: -0.5 until the swing's
start at 0.05 s, then +1).

    python experiments/sac_hammer/search/replay.py runs/tune/A_post02_s100 10100,10101 [latest]   (latest: last checkpoint)
"""

import sys

import gymnasium as gym
import numpy as np

import vswrist_gym  # noqa: F401  (registers the VSWrist/ ids)
from vswrist_gym.agents.runs import TrainedAgent

agent = TrainedAgent(sys.argv[1], checkpoint=sys.argv[3]) if len(sys.argv) > 3 else TrainedAgent(sys.argv[1])
env = gym.make(agent.cfg.env_id, **agent.cfg.env_kwargs)
res = env.unwrapped.cfg["residual"]
for seed in (int(x) for x in sys.argv[2].split(",")):
    obs, _ = env.reset(seed=seed)
    ret, done, cmds, fe, struck_at, speed = 0.0, False, [], [], None, float("nan")
    while not done:
        o = agent.vecnorm.normalize_obs(obs[None]) if agent.vecnorm else obs[None]
        a, _ = agent.model.predict(o, deterministic=True)
        obs, r, term, trunc, info = env.step(a[0])
        ret, done = ret + r, term or trunc
        if struck_at is None:
            cmds.append(float(np.clip(res["stiffness_nominal"] + res["stiffness_scale"] * a[0][3], -1, 1)))
            fe.append(float(a[0][1]) * res["posture_scale"])
            if info.get("struck"):
                struck_at, speed = len(cmds), info["impact_speed"]
    print(f"reset seed {seed}: return {ret:+.1f}, strike at step {struck_at}, {speed:.2f} m/s")
    print("  stiffness command:", " ".join(f"{c:+.2f}" for c in cmds))
    print("  FE residual (rad):", " ".join(f"{f:+.3f}" for f in fe))
