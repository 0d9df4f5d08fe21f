"""Replay a grid run's SAC policy (deterministic) on its protocol episodes and say what it does with the stiffness
while the drill engages (contact force above 0) and while it does not; the stiffest constant on the same episodes
beside it. Reset seeds of seed s are 1,000,000 + 1,000 s + i, as in its metrics.csv.

    python experiments/sac_stiffness/replay.py runs/results/sac_stiffness/Drill/sac_seed1 1 10
    python experiments/sac_stiffness/replay.py runs/results/sac_stiffness/Drill/sac_seed1 1 2 trace
        (trace: also every 6th step of each SAC episode: time, contact force, internal torque, posture error,
         reward)
"""

import sys

import gymnasium as gym
import numpy as np

import vswrist_gym  # noqa: F401  (registers the VSWrist/ ids)
from vswrist_gym.agents.runs import TrainedAgent

agent = TrainedAgent(sys.argv[1])
seed, n = int(sys.argv[2]), int(sys.argv[3])
show = len(sys.argv) > 4 and sys.argv[4] == "trace"
env = gym.make(agent.cfg.env_id, **agent.cfg.env_kwargs)
for who in ("SAC", "constant +1"):
    on, off, rets, en = [], [], [], []
    for i in range(n):
        obs, _ = env.reset(seed=1_000_000 + 1_000 * seed + i)
        ret, done, k = 0.0, False, 0
        while not done:
            if who == "SAC":
                o = agent.vecnorm.normalize_obs(obs[None]) if agent.vecnorm else obs[None]
                a = agent.model.predict(o, deterministic=True)[0][0]
            else:
                a = np.zeros(env.action_space.shape, np.float32)  # Drill's nominal command is +1, the stiffest
            obs, r, term, trunc, info = env.step(a)
            ret, done = ret + r, term or trunc
            (on if info["contact_force"] > 0 else off).append(info["lam"])
            en.append(info["elastic_energy"])
            if show and who == "SAC" and k % 6 == 0:
                print(f"  episode {i} t {info['time']:.2f} s: contact force {info['contact_force']:.1f} N, internal "
                      f"torque {info['lam']:.1f} N m, posture error {info['posture_error']:.3f} rad, reward {r:+.2f}")
            k += 1
        rets.append(ret)
    print(f"{who}, seed {seed}, {n} episodes: return {np.mean(rets):+.1f}; internal torque engaged "
          f"{np.mean(on):.1f} N m (5-95 %: {np.percentile(on, 5):.1f}-{np.percentile(on, 95):.1f}), not engaged "
          f"{np.mean(off):.1f} N m (5-95 %: {np.percentile(off, 5):.1f}-{np.percentile(off, 95):.1f}); "
          f"elastic energy {np.mean(en):.1f} J")
