"""Hyperparameter files for PPO and SAC, RL-Zoo style: one YAML per algorithm, keyed by environment id.

The files are plain YAML: nothing in them is evaluated. Every key of an entry is consumed exactly once while
resolving it (run keys here, algorithm keys by the stable-baselines3 constructor, policy keys by the policy),
and an unknown key is an error that names it, so a typo cannot be silently ignored.
"""

from __future__ import annotations

import copy
import inspect
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

CONFIG_DIR = Path(__file__).resolve().parents[1] / "configs"
ALGO_NAMES = ("ppo", "sac")

# Keys of an entry that configure the run rather than the algorithm, with their meaning.
RUN_KEYS = {
    "n_timesteps": "total environment steps of training (int > 0)",
    "n_envs": "parallel environments (int > 0), run as vec_env says",
    "vec_env": "'batch' (default: one process, physics on threads), 'subproc' or 'dummy': how the n_envs "
               "environments are run",
    "policy": "stable-baselines3 policy class name (MlpPolicy)",
    "normalize": "false, true, or a mapping of VecNormalize options (norm_obs, norm_reward, clip_obs, clip_reward)",
    "env_kwargs": "mapping passed to gymnasium.make",
    "eval_freq": "environment steps between periodic evaluations (int > 0; at most half the run)",
    "n_eval_episodes": "episodes per periodic evaluation (int > 0)",
    "checkpoint_freq": "environment steps between checkpoints (int > 0)",
    "keep_checkpoints": "how many of the newest checkpoints to keep on disk (int > 0)",
    "policy_kwargs": "mapping passed to the policy; activation_fn is a name (tanh, relu, elu, leaky_relu)",
}
# Keys the training command sets itself; an entry may not set them.
RESERVED_ALGO_KEYS = {"self", "policy", "env", "tensorboard_log", "seed", "verbose", "device", "_init_setup_model",
                      "replay_buffer_class", "rollout_buffer_class"}
NORMALIZE_KEYS = {"norm_obs", "norm_reward", "clip_obs", "clip_reward", "epsilon"}
ACTIVATIONS = ("tanh", "relu", "elu", "leaky_relu")


class ConfigError(ValueError):
    """A hyperparameter file or entry is missing, malformed, or has a key outside the allowed set."""


@dataclass(frozen=True)
class RunConfig:
    """One resolved entry: run settings plus the keyword arguments of the algorithm's constructor."""

    env_id: str
    algo: str
    n_timesteps: int
    n_envs: int
    vec_env: str
    policy: str
    normalize: dict | None
    env_kwargs: dict
    eval_freq: int
    n_eval_episodes: int
    checkpoint_freq: int
    keep_checkpoints: int
    policy_kwargs: dict
    algo_kwargs: dict
    source: str = ""
    raw: dict = field(default_factory=dict)

    def to_yaml_dict(self) -> dict:
        """The entry as written to a run directory: plain YAML that `resolve_entry` reads back unchanged."""
        out = copy.deepcopy(self.raw)
        out["n_timesteps"] = self.n_timesteps
        out["n_envs"] = self.n_envs
        out["vec_env"] = self.vec_env
        return out


def algo_class(algo: str):
    """The stable-baselines3 class for 'ppo' or 'sac' (imported lazily: torch is heavy)."""
    if algo not in ALGO_NAMES:
        raise ConfigError(f"algo must be one of {', '.join(ALGO_NAMES)}, got {algo!r}")
    import stable_baselines3

    return getattr(stable_baselines3, algo.upper())


def default_config_path(algo: str) -> Path:
    if algo not in ALGO_NAMES:
        raise ConfigError(f"algo must be one of {', '.join(ALGO_NAMES)}, got {algo!r}")
    return CONFIG_DIR / f"{algo}.yaml"


def load_file(path: str | Path) -> dict:
    """Read a hyperparameter file: a mapping from environment id to an entry mapping."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"hyperparameter file not found: {path}")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ConfigError(f"hyperparameter file {path} is not valid YAML: {exc}") from None
    if not isinstance(data, dict) or not all(isinstance(v, dict) for v in data.values()):
        raise ConfigError(f"hyperparameter file {path} must map environment ids to mappings of hyperparameters")
    return data


def load_config(algo: str, env_id: str, path: str | Path | None = None) -> RunConfig:
    """The resolved entry for `env_id` in the algorithm's file (default: the packaged `configs/<algo>.yaml`)."""
    path = Path(path) if path is not None else default_config_path(algo)
    data = load_file(path)
    if env_id not in data:
        raise ConfigError(f"{path} has no entry for '{env_id}'; entries: {', '.join(sorted(data))}")
    return resolve_entry(algo, env_id, data[env_id], source=str(path))


def _positive_int(entry: dict, key: str, default: int | None = None) -> int:
    value = entry.pop(key, default)
    if value is None:
        raise ConfigError(f"'{key}' is required ({RUN_KEYS[key]})")
    if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
        raise ConfigError(f"'{key}' must be a positive integer ({RUN_KEYS[key]}), got {value!r}")
    return value


def parse_schedule(key: str, value: Any):
    """A number, or 'lin_<x>' for a linear decay from x to 0 over training (RL-Zoo notation, parsed, not evaluated)."""
    if isinstance(value, str) and value.startswith("lin_"):
        try:
            start = float(value[4:])
        except ValueError:
            raise ConfigError(f"'{key}': cannot read a number from {value!r} (expected e.g. lin_3e-4)") from None

        def schedule(progress_remaining: float, _start=start) -> float:
            return progress_remaining * _start

        return schedule
    return value


def _policy_kwargs(value: Any) -> dict:
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise ConfigError(f"'policy_kwargs' must be a mapping, got {value!r}")
    out = copy.deepcopy(value)
    if "activation_fn" in out:
        name = out["activation_fn"]
        if name not in ACTIVATIONS:
            raise ConfigError(f"'policy_kwargs.activation_fn' must be one of {', '.join(ACTIVATIONS)}, got {name!r}")
        import torch.nn as nn

        out["activation_fn"] = {"tanh": nn.Tanh, "relu": nn.ReLU, "elu": nn.ELU, "leaky_relu": nn.LeakyReLU}[name]
    return out


VEC_ENVS = ("batch", "subproc", "dummy")


def resolve_entry(algo: str, env_id: str, entry: dict, source: str = "") -> RunConfig:
    """Check and split one entry; every key is consumed here or validated against the algorithm's constructor."""
    cls = algo_class(algo)
    raw = copy.deepcopy(entry)
    entry = copy.deepcopy(entry)
    n_timesteps = _positive_int(entry, "n_timesteps")
    n_envs = _positive_int(entry, "n_envs", 1)
    vec_env = entry.pop("vec_env", "batch")
    if vec_env not in VEC_ENVS:
        raise ConfigError(f"'vec_env' must be one of {list(VEC_ENVS)}, got {vec_env!r}")
    policy = entry.pop("policy", "MlpPolicy")
    if policy != "MlpPolicy":
        raise ConfigError(f"'policy' must be 'MlpPolicy' (the observations are flat vectors), got {policy!r}")
    normalize = entry.pop("normalize", False)
    if normalize is True:
        normalize = {}
    elif normalize is False or normalize is None:
        normalize = None
    elif isinstance(normalize, dict):
        bad = set(normalize) - NORMALIZE_KEYS
        if bad:
            raise ConfigError(f"'normalize' has unknown keys {sorted(bad)}; allowed: {sorted(NORMALIZE_KEYS)}")
    else:
        raise ConfigError(f"'normalize' must be true, false or a mapping, got {normalize!r}")
    env_kwargs = entry.pop("env_kwargs", None) or {}
    if not isinstance(env_kwargs, dict):
        raise ConfigError(f"'env_kwargs' must be a mapping, got {env_kwargs!r}")
    eval_freq = _positive_int(entry, "eval_freq", max(n_timesteps // 10, 1))
    n_eval_episodes = _positive_int(entry, "n_eval_episodes", 5)
    checkpoint_freq = _positive_int(entry, "checkpoint_freq", max(n_timesteps // 5, 1))
    keep_checkpoints = _positive_int(entry, "keep_checkpoints", 2)
    policy_kwargs = _policy_kwargs(entry.pop("policy_kwargs", None))

    allowed = set(inspect.signature(cls.__init__).parameters) - RESERVED_ALGO_KEYS
    bad = sorted(set(entry) - allowed)
    if bad:
        raise ConfigError(
            f"{source or 'entry'} [{env_id}]: unknown key(s) {bad} for {algo.upper()}; allowed: "
            f"run keys {sorted(RUN_KEYS)} and {algo.upper()} arguments {sorted(allowed - {'policy_kwargs'})}"
        )
    algo_kwargs = {k: parse_schedule(k, v) for k, v in entry.items()}
    return RunConfig(env_id=env_id, algo=algo, n_timesteps=n_timesteps, n_envs=n_envs, vec_env=vec_env,
                     policy=policy, normalize=normalize, env_kwargs=env_kwargs, eval_freq=eval_freq,
                     n_eval_episodes=n_eval_episodes, checkpoint_freq=checkpoint_freq,
                     keep_checkpoints=keep_checkpoints, policy_kwargs=policy_kwargs, algo_kwargs=algo_kwargs,
                     source=source, raw=raw)
