"""Replay a search run's final policy (deterministic) on given reset seeds: return, mean and spread of each action
component (RUD, FE, PS residual, stiffness residual) and the reward terms.

    python experiments/sac_tuned/search/replay.py runs/tune/ins_C_sde_lr1e-4_s100 10100,10104
"""

import sys

import gymnasium as gym
import numpy as np

import vswrist_gym  # noqa: F401  (registers the VSWrist/ ids)
from vswrist_gym.agents.runs import TrainedAgent

agent = TrainedAgent(sys.argv[1])
env = gym.make(agent.cfg.env_id, **agent.cfg.env_kwargs)
for seed in (int(x) for x in sys.argv[2].split(",")):
    obs, _ = env.reset(seed=seed)
    actions, ret, terms, done = [], 0.0, {}, False
    while not done:
        o = agent.vecnorm.normalize_obs(obs[None]) if agent.vecnorm else obs[None]
        a, _ = agent.model.predict(o, deterministic=True)
        obs, r, term, trunc, info = env.step(a[0])
        ret, done = ret + r, term or trunc
        actions.append(a[0])
        for k, v in info.items():
            if k.startswith("reward_"):
                terms[k[7:]] = terms.get(k[7:], 0.0) + v
    actions = np.array(actions)
    print(f"reset seed {seed}: return {ret:+.1f}; action mean {actions.mean(0).round(2)}, sd {actions.std(0).round(2)}; "
          + ", ".join(f"{k} {v:+.1f}" for k, v in terms.items()))
