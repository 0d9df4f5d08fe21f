"""Does the reference agent track the posture on a task's `paper` variant? (docs/environments.md, Stiffness range)

``python docs/paperrange/tracking.py [--task LoadHold] [--episodes 12] [--params PRESET]``: for every constant
stiffness command, the reference agent on the task's variant (vswrist_gym.envs.variants; ``--params`` replaces the
device preset, e.g. ``paper_knm`` with the task's own loads, ``--no-variant``). Prints, over the episodes (seeds
from 1000): the posture error (RUD, FE, PS; rad) at the first step, its mean over the episode and over the last
0.5 s, the number of episodes whose error over the last 0.5 s stays above 0.5 rad (the wrist has settled far from
the reference), and the coupler stiffness the observation reports at the end (RUD-RUD, FE-FE, N m/rad, mean).
"""

from __future__ import annotations

import argparse

import gymnasium as gym
import numpy as np

import vswrist_gym  # noqa: F401
from vswrist_gym.envs.config import merge
from vswrist_gym.envs.variants import variant_config
from vswrist_gym.tools.probe import CONSTANT_COMMANDS


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--task", default="LoadHold")
    ap.add_argument("--episodes", type=int, default=12)
    ap.add_argument("--params", default=None)
    ap.add_argument("--no-variant", action="store_true", help="the task as it is (its own loads)")
    args = ap.parse_args()
    cfg = {} if args.no_variant else variant_config(args.task)
    if args.params:
        cfg = merge(cfg, {"params": args.params})
    env = gym.make(f"VSWrist/{args.task}-v0", config=cfg)
    u = env.unwrapped
    print(f"{args.task}, {cfg.get('params', u.cfg['params'])}{'' if args.no_variant else ', paper variant loads'}: "
          f"posture error (rad) of the reference agent, {args.episodes} episodes from seed 1000")
    print(f"{'command':<9}{'first':>8}{'mean':>8}{'last 0.5 s':>12}{'settled > 0.5 rad':>19}{'stiffness RUD, FE':>20}")
    last = int(round(0.5 / u.ctrl_dt))
    for s in CONSTANT_COMMANDS:
        first, mean, end, stiff = [], [], [], []
        for seed in range(1000, 1000 + args.episodes):
            obs, _ = env.reset(seed=seed)
            errs = []
            done = False
            while not done:
                obs, _, term, trunc, info = env.step(u.reference_to_action(obs[u.obs_slices["target"]], s))
                errs.append(info["posture_error"])
                done = term or trunc
            first.append(errs[0])
            mean.append(np.mean(errs))
            end.append(np.mean(errs[-last:]))
            stiff.append(obs[u.obs_slices["stiffness"]][[0, 2]])
        k = np.mean(stiff, axis=0)
        print(f"s={s:+.1f}  {np.mean(first):8.3f}{np.mean(mean):8.3f}{np.mean(end):12.3f}"
              f"{sum(e > 0.5 for e in end):>13}/{args.episodes:<5}{k[0]:10.3f}, {k[1]:.3f}")
    env.close()


if __name__ == "__main__":
    main()
