"""How PPO's training time splits between collecting rollouts and the update, on LoadHold with the packaged entry
(its worlds in one process, its rollout, epochs and minibatches; one torch thread):

    python experiments/training_speed/ppo_update_share.py [--timesteps 16384] [--torch-threads 1] [--set KEY=VALUE ...]

``--set`` changes entry keys (``--set n_envs=16 n_steps=64 batch_size=128`` is the entry before
2026-12-04), so that the update's cost per minibatch can be read off side by side.

Times SB3's own ``collect_rollouts`` (environment steps, policy forward, buffer) and ``train`` (the update) with
wall clocks around them. Why: more worlds per step amortise the first but not the second, which bounds the
training speed-up that batching can give (README, Batched speed).
"""

from __future__ import annotations

import argparse
import time

import torch
import yaml
from stable_baselines3 import PPO
from stable_baselines3.common.utils import configure_logger
from stable_baselines3.common.vec_env import VecNormalize

from vswrist_gym.agents.hparams import load_config
from vswrist_gym.agents.vec_env import BatchVecEnv


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--timesteps", type=int, default=16384)
    ap.add_argument("--torch-threads", type=int, default=1)
    ap.add_argument("--set", nargs="+", default=[], metavar="KEY=VALUE", help="entry keys to change (YAML values)")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.torch_threads)
    changes = {}
    for pair in args.set:
        key, sep, value = pair.partition("=")
        if not sep:
            ap.error(f"--set: {pair!r} is not KEY=VALUE")
        changes[key] = yaml.safe_load(value)
    cfg = load_config("ppo", "VSWrist/LoadHold-v0")
    n_envs = int(changes.pop("n_envs", cfg.n_envs))
    kwargs = {**cfg.algo_kwargs, **changes}
    venv = VecNormalize(BatchVecEnv("VSWrist/LoadHold-v0", n_envs, env_kwargs=cfg.env_kwargs, threads=2))
    model = PPO(cfg.policy, venv, device="cpu", seed=0, policy_kwargs=cfg.policy_kwargs, verbose=0, **kwargs)
    print(f"{n_envs} worlds, n_steps {kwargs['n_steps']}, batch_size {kwargs['batch_size']}, "
          f"n_epochs {kwargs.get('n_epochs', 10)}")
    model._logger = configure_logger(0, None, "", False)
    spent = {"collect_rollouts": 0.0, "train": 0.0}
    for name in spent:
        fn = getattr(model, name)

        def timed(*a, _fn=fn, _name=name, **k):
            t0 = time.perf_counter()
            try:
                return _fn(*a, **k)
            finally:
                spent[_name] += time.perf_counter() - t0

        setattr(model, name, timed)
    t0 = time.perf_counter()
    model.learn(args.timesteps)
    wall = time.perf_counter() - t0
    print(f"{args.timesteps} steps in {wall:.2f} s ({args.timesteps / wall:.0f} steps/s): rollouts "
          f"{spent['collect_rollouts']:.2f} s, update {spent['train']:.2f} s "
          f"({100 * spent['train'] / wall:.0f} % of the time)")
    venv.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
