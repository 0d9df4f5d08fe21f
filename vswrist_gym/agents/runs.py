"""Run directories: environment construction, atomic checkpoints, and loading a trained agent back.

Layout of a run directory written by `vswrist train`:

    config.yaml          the resolved hyperparameter entry (plus env id, algo, seed): re-runnable as is
    run.json             command lines (one per invocation), seed, package versions, status
    model.zip            final model (written at the end, atomically)
    vecnormalize.pkl     final observation/reward normalisation statistics (when normalisation is on)
    checkpoints/step_<N>/{model.zip, vecnormalize.pkl, replay_buffer.pkl}, checkpoints/latest.json
    eval/evaluations.npz periodic evaluation (learning curve), eval/best_model.zip
    tb/                  TensorBoard logs
    monitor/             per-environment episode logs (Monitor CSV)

A checkpoint is written into a temporary folder and renamed into place, then `latest.json` is replaced
atomically; an interrupted run therefore never leaves a half-written checkpoint as the latest.
"""

from __future__ import annotations

import io
import json
import os
import pickle
import platform
import shutil
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import yaml

from vswrist_gym.agents.hparams import ConfigError, RunConfig, algo_class, resolve_entry


class RunDirError(RuntimeError):
    """A run directory, model or statistics file is missing, corrupted, or belongs to another task."""


# --------------------------------------------------------------------------------------------------- helpers


def limit_threads(n: int = 1) -> None:
    """One torch thread per process: the machines here have few cores shared by several processes."""
    import torch

    torch.set_num_threads(n)


def versions() -> dict:
    """Versions of the libraries that determine a result, stored with every run and every evaluation."""
    import gymnasium
    import mujoco
    import stable_baselines3
    import torch

    try:
        from importlib.metadata import version

        own = version("vswrist-gym")
    except Exception:  # noqa: BLE001 - not installed as a distribution: report unknown, never fail a run
        own = "unknown"
    return {"vswrist_gym": own, "mujoco": mujoco.__version__, "gymnasium": gymnasium.__version__,
            "stable_baselines3": stable_baselines3.__version__, "torch": torch.__version__,
            "numpy": np.__version__, "python": platform.python_version(), "platform": platform.platform(),
            "cpu_count": os.cpu_count()}


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write to a temporary file in the same folder, fsync, then rename over `path`."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def atomic_write_text(path: Path, text: str) -> None:
    atomic_write_bytes(path, text.encode())


def model_bytes(model) -> bytes:
    buf = io.BytesIO()
    model.save(buf)
    return buf.getvalue()


def import_env_package(env_id: str) -> None:
    """Importing vswrist_gym registers the VSWrist/ ids (and is harmless for other ids)."""
    import vswrist_gym  # noqa: F401


def check_env_id(env_id: str) -> None:
    import gymnasium as gym

    import_env_package(env_id)
    if env_id not in gym.registry:
        ours = sorted(k for k in gym.registry if k.startswith("VSWrist/"))
        raise ConfigError(f"unknown task '{env_id}'; registered VSWrist tasks: {', '.join(ours) or 'none yet'}")


# --------------------------------------------------------------------------------------------------- envs


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
    """The configured VecEnv (SubprocVecEnv when n_envs > 1 and vec_env is 'subproc'), seeded seed, seed+1, ..."""
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    fns = []
    for rank in range(n_envs):
        mon = None
        if monitor_dir is not None:
            monitor_dir.mkdir(parents=True, exist_ok=True)
            mon = str(monitor_dir / f"{prefix}_{rank}")
        fns.append(EnvFactory(cfg.env_id, cfg.env_kwargs, mon))
    if n_envs > 1 and cfg.vec_env == "subproc":
        venv = SubprocVecEnv(fns, start_method="forkserver")
    else:
        venv = DummyVecEnv(fns)
    venv.seed(seed)
    venv.action_space.seed(seed)
    return venv


def wrap_normalize(venv, cfg: RunConfig, training: bool = True):
    from stable_baselines3.common.vec_env import VecNormalize

    if cfg.normalize is None:
        return venv
    gamma = cfg.algo_kwargs.get("gamma", 0.99)
    return VecNormalize(venv, training=training, gamma=gamma, **cfg.normalize)


# --------------------------------------------------------------------------------------------------- run dir


def write_config(run_dir: Path, cfg: RunConfig, seed: int) -> None:
    doc = {"env_id": cfg.env_id, "algo": cfg.algo, "seed": seed, "source": cfg.source,
           "hyperparameters": cfg.to_yaml_dict()}
    atomic_write_text(run_dir / "config.yaml", yaml.safe_dump(doc, sort_keys=False))


def read_config(run_dir: Path) -> tuple[RunConfig, int]:
    path = Path(run_dir) / "config.yaml"
    if not path.is_file():
        raise RunDirError(f"{run_dir} is not a run directory: {path.name} is missing (create one with vswrist train)")
    try:
        doc = yaml.safe_load(path.read_text())
        cfg = resolve_entry(doc["algo"], doc["env_id"], doc["hyperparameters"], source=str(path))
        return cfg, int(doc["seed"])
    except (yaml.YAMLError, KeyError, TypeError, ConfigError) as exc:
        raise RunDirError(f"{path} is corrupted or from an incompatible version: {exc}") from None


def update_run_json(run_dir: Path, **fields) -> dict:
    path = Path(run_dir) / "run.json"
    doc = json.loads(path.read_text()) if path.is_file() else {}
    for key, value in fields.items():
        if key == "command":
            doc.setdefault("commands", []).append(value)
        else:
            doc[key] = value
    atomic_write_text(path, json.dumps(doc, indent=2))
    return doc


# --------------------------------------------------------------------------------------------------- checkpoints


def save_checkpoint(run_dir: Path, model, vecnorm, keep: int = 2, with_replay_buffer: bool = True) -> Path:
    """Write checkpoints/step_<N>/ completely under a temporary name, rename it, then point latest.json at it."""
    ck_root = Path(run_dir) / "checkpoints"
    ck_root.mkdir(parents=True, exist_ok=True)
    step = int(model.num_timesteps)
    final = ck_root / f"step_{step:010d}"
    tmp = Path(tempfile.mkdtemp(prefix=".tmp_step_", dir=ck_root))
    try:
        (tmp / "model.zip").write_bytes(model_bytes(model))
        if vecnorm is not None:
            (tmp / "vecnormalize.pkl").write_bytes(pickle.dumps(vecnorm))
        if with_replay_buffer and getattr(model, "replay_buffer", None) is not None:
            buf = io.BytesIO()
            model.save_replay_buffer(buf)
            (tmp / "replay_buffer.pkl").write_bytes(buf.getvalue())
        if final.exists():
            shutil.rmtree(final)
        os.rename(tmp, final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    atomic_write_text(ck_root / "latest.json", json.dumps({"step": step, "dir": final.name, "time": time.time()}))
    complete = sorted(p for p in ck_root.glob("step_*") if p.is_dir())
    for old in complete[:-keep]:
        if old != final:
            shutil.rmtree(old, ignore_errors=True)
    return final


def latest_checkpoint(run_dir: Path) -> Path | None:
    """The checkpoint latest.json names; if that is unreadable, the newest complete step_* folder."""
    ck_root = Path(run_dir) / "checkpoints"
    try:
        doc = json.loads((ck_root / "latest.json").read_text())
        path = ck_root / doc["dir"]
        if (path / "model.zip").is_file():
            return path
    except (OSError, ValueError, KeyError, TypeError):
        pass
    complete = sorted(p for p in ck_root.glob("step_*") if (p / "model.zip").is_file())
    return complete[-1] if complete else None


# --------------------------------------------------------------------------------------------------- loading


def load_model(path: Path, algo: str, env=None, device: str = "cpu"):
    """Load an SB3 model, turning a missing or unreadable file into a RunDirError that says what to do."""
    path = Path(path)
    if not path.is_file():
        raise RunDirError(f"model file not found: {path}")
    try:
        return algo_class(algo).load(path, env=env, device=device)
    except Exception as exc:  # noqa: BLE001 - zip, pickle, torch and key errors all mean "unreadable"
        raise RunDirError(f"model file {path} is corrupted or not a {algo.upper()} model "
                          f"({type(exc).__name__}: {exc})") from None


def load_vecnormalize(path: Path, venv):
    from stable_baselines3.common.vec_env import VecNormalize

    path = Path(path)
    if not path.is_file():
        raise RunDirError(f"normalisation statistics not found: {path} (the run was trained with normalisation)")
    try:
        vn = pickle.loads(path.read_bytes())
        if not isinstance(vn, VecNormalize):
            raise TypeError(f"contains a {type(vn).__name__}, not VecNormalize statistics")
        if venv is not None:
            vn.set_venv(venv)
        return vn
    except Exception as exc:  # noqa: BLE001
        raise RunDirError(f"normalisation file {path} is corrupted ({type(exc).__name__}: {exc})") from None


class TrainedAgent:
    """A trained run as an agent with the SB3 `predict` interface on raw (unnormalised) observations."""

    def __init__(self, run_dir: str | Path, checkpoint: str = "final"):
        from gymnasium import spaces

        self.run_dir = Path(run_dir)
        if not self.run_dir.is_dir():
            raise RunDirError(f"run directory not found: {self.run_dir}")
        self.cfg, self.seed = read_config(self.run_dir)
        if checkpoint == "final":
            folder = self.run_dir
            if not (folder / "model.zip").exists():
                latest = latest_checkpoint(self.run_dir)
                hint = (f"; the run did not finish: resume it with `vswrist train ... --out {self.run_dir} --resume`"
                        f" or evaluate its last checkpoint with --checkpoint latest") if latest else ""
                raise RunDirError(f"model file not found: {folder / 'model.zip'}{hint}")
        elif checkpoint == "latest":
            folder = latest_checkpoint(self.run_dir)
            if folder is None:
                raise RunDirError(f"no complete checkpoint in {self.run_dir / 'checkpoints'}")
        elif checkpoint == "best":
            folder = self.run_dir / "eval"
            if not (folder / "best_model.zip").exists():
                raise RunDirError(f"no best model in {folder} (periodic evaluation never ran)")
        else:
            raise ValueError(f"checkpoint must be final, latest or best, got {checkpoint!r}")
        name = "best_model.zip" if checkpoint == "best" else "model.zip"
        self.model = load_model(folder / name, self.cfg.algo)
        self.vecnorm = None
        if self.cfg.normalize is not None:
            vn_file = (self.run_dir if checkpoint == "best" else folder) / "vecnormalize.pkl"
            self.vecnorm = load_vecnormalize(vn_file, None)
            self.vecnorm.training = False
        if not isinstance(self.model.observation_space, spaces.Box):
            raise RunDirError(f"{self.run_dir}: unsupported observation space {self.model.observation_space}")

    @property
    def env_id(self) -> str:
        return self.cfg.env_id

    def check_env(self, env) -> None:
        """The run's spaces must match the environment it is evaluated on."""
        if env.observation_space.shape != self.model.observation_space.shape:
            raise RunDirError(f"{self.run_dir} was trained on observations of shape "
                              f"{self.model.observation_space.shape}, the environment gives "
                              f"{env.observation_space.shape}")

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        if self.vecnorm is not None and self.vecnorm.norm_obs:
            obs = self.vecnorm.normalize_obs(np.asarray(obs, dtype=np.float32))
        return self.model.predict(obs, state=state, episode_start=episode_start, deterministic=deterministic)


def override(cfg: RunConfig, **changes) -> RunConfig:
    """A copy of the config with run keys changed (None means keep)."""
    changes = {k: v for k, v in changes.items() if v is not None}
    return replace(cfg, **changes)
