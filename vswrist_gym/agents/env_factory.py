"""Environments of a run: the task id checked, the configured VecEnv (batch, subproc or dummy) with its Monitor
logs, and the frame-stacking and normalisation wrappers."""

from __future__ import annotations

import sys
from pathlib import Path

from vswrist_gym.agents.hparams import ConfigError, RunConfig
from vswrist_gym.agents.procs import limit_threads


def import_env_package(env_id: str) -> None:
    """Importing vswrist_gym registers the VSWrist/ ids (and is harmless for other ids)."""
    import vswrist_gym  # noqa: F401


def check_env_id(env_id: str) -> None:
    import gymnasium as gym

    import_env_package(env_id)
    if env_id not in gym.registry:
        ours = sorted(k for k in gym.registry if k.startswith("VSWrist/"))
        raise ConfigError(f"unknown task '{env_id}'; registered VSWrist tasks: {', '.join(ours) or 'none yet'}")


class EnvFactory:
    """Picklable environment constructor for SubprocVecEnv workers (each worker limits torch to one thread)."""

    def __init__(self, env_id: str, env_kwargs: dict, monitor_file: str | None = None, render_mode=None):
        self.env_id, self.env_kwargs = env_id, dict(env_kwargs)
        self.monitor_file, self.render_mode = monitor_file, render_mode

    def __call__(self):
        import gymnasium as gym
        from stable_baselines3.common.monitor import Monitor

        if "torch" in sys.modules:
            limit_threads(1)
        import_env_package(self.env_id)
        kwargs = dict(self.env_kwargs)
        if self.render_mode is not None:
            kwargs["render_mode"] = self.render_mode
        env = gym.make(self.env_id, **kwargs)
        return Monitor(env, filename=self.monitor_file)


def check_env_kwargs(env_id: str, env_kwargs: dict) -> None:
    """Build the environment once in this process, so that bad env_kwargs are a clear error, not a dead worker."""
    import gymnasium as gym

    check_env_id(env_id)
    try:
        gym.make(env_id, **env_kwargs).close()
    except (ValueError, TypeError, KeyError) as exc:
        raise ConfigError(f"env_kwargs {env_kwargs} rejected by {env_id}: {type(exc).__name__}: {exc}") from None


def make_vec_env(cfg: RunConfig, n_envs: int, seed: int, monitor_dir: Path | None = None, prefix: str = "train"):
    """The configured VecEnv, seeded seed, seed+1, ...: for VS-Wrist ids with ``vec_env: batch`` (the default) all
    worlds in this process (``agents.vec_env.BatchVecEnv``, physics on threads, one ``VecMonitor`` log);
    otherwise SubprocVecEnv when n_envs > 1 and vec_env is 'subproc' ('batch' on another id means the same),
    else DummyVecEnv (a Monitor log per env)."""
    import gymnasium as gym
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    spec = gym.registry.get(cfg.env_id)
    if cfg.vec_env == "batch" and spec is not None and cfg.env_id.startswith("VSWrist/") \
            and spec.vector_entry_point is not None:
        from stable_baselines3.common.vec_env import VecMonitor

        from .vec_env import BatchVecEnv

        if "torch" in sys.modules:
            limit_threads(1)
        venv = BatchVecEnv(cfg.env_id, n_envs, cfg.env_kwargs)
        mon = None
        if monitor_dir is not None:
            monitor_dir.mkdir(parents=True, exist_ok=True)
            mon = str(monitor_dir / f"{prefix}_batch")
        venv = VecMonitor(venv, filename=mon)
        venv.seed(seed)
        venv.action_space.seed(seed)
        return venv
    fns = []
    for rank in range(n_envs):
        mon = None
        if monitor_dir is not None:
            monitor_dir.mkdir(parents=True, exist_ok=True)
            mon = str(monitor_dir / f"{prefix}_{rank}")
        fns.append(EnvFactory(cfg.env_id, cfg.env_kwargs, mon))
    if n_envs > 1 and cfg.vec_env in ("subproc", "batch"):
        venv = SubprocVecEnv(fns, start_method="forkserver")
    else:
        venv = DummyVecEnv(fns)
    venv.seed(seed)
    venv.action_space.seed(seed)
    return venv


def wrap_frame_stack(venv, n_stack: int):
    """SB3's VecFrameStack over `venv` when `n_stack` > 1 (the entry's `frame_stack`): outside the normalisation,
    as rl_zoo3 wraps it, so the statistics stay per observation and a run loads in either tool."""
    if n_stack <= 1:
        return venv
    from stable_baselines3.common.vec_env import VecFrameStack

    return VecFrameStack(venv, n_stack)


def wrap_normalize(venv, cfg: RunConfig, training: bool = True):
    from stable_baselines3.common.vec_env import VecNormalize

    if cfg.normalize is None:
        return venv
    gamma = cfg.algo_kwargs.get("gamma", 0.99)
    return VecNormalize(venv, training=training, gamma=gamma, **cfg.normalize)
