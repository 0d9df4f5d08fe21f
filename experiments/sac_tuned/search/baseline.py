"""The best constant (a zero residual action) on the episodes of a training run's periodic evaluation: reset seeds
seed + 10,000 + i (vswrist_gym/agents/train.py, EVAL_SEED_OFFSET), the reference for the search's learning curves.

    python experiments/sac_tuned/search/baseline.py --tasks Insertion-v0 Drill-v0 --seeds 100 101 --episodes 5
"""

import argparse

import gymnasium as gym
import numpy as np

import vswrist_gym  # noqa: F401  (registers the VSWrist/ ids)
from vswrist_gym.agents.train import EVAL_SEED_OFFSET

p = argparse.ArgumentParser()
p.add_argument("--tasks", nargs="+", default=["Insertion-v0", "Drill-v0"])
p.add_argument("--seeds", nargs="+", type=int, default=[100, 101])
p.add_argument("--episodes", type=int, default=5)
args = p.parse_args()
for task in args.tasks:
    env = gym.make(f"VSWrist/{task}", action_mode="residual")
    for seed in args.seeds:
        returns = []
        for i in range(args.episodes):
            env.reset(seed=seed + EVAL_SEED_OFFSET + i)
            ret, done = 0.0, False
            while not done:
                _, r, term, trunc, _ = env.step(np.zeros(env.action_space.shape, np.float32))
                ret, done = ret + r, term or trunc
            returns.append(ret)
        print(f"{task} seed {seed}: {np.mean(returns):+.1f}  ({' '.join(f'{r:+.1f}' for r in returns)})")
