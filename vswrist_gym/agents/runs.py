"""Run directories: environment construction, atomic checkpoints, and loading a trained agent back.

Layout of a run directory written by `vswrist train`:

    config.yaml          the resolved hyperparameter entry (plus env id, algo, seed): re-runnable as is
    run.json             command lines (one per invocation), seed, package versions, status, the training
                         process (pid, host, start time) and a history of ended invocations (finished,
                         interrupted, failed, killed) with the step each reached
    model.zip            final model (written at the end, atomically)
    vecnormalize.npz     final observation/reward normalisation statistics as plain arrays (when normalisation is on)
    checkpoints/step_<N>/{model.zip, vecnormalize.npz, replay_buffer.npz}, checkpoints/latest.json
    eval/evaluations.npz periodic evaluation (learning curve), eval/best_model.zip
    tb/                  TensorBoard logs
    monitor/             per-environment episode logs (Monitor CSV)

What makes a folder a run directory is its `config.yaml`; `vswrist train` refuses to start a new run in a folder
that holds anything else.

Every kept checkpoint holds the SAC replay buffer (its filled part only), so that `--resume --timesteps N`
continues with the transitions the run had, also when it falls back to the older checkpoint; a run that will not
be extended needs only `model.zip` and `vecnormalize.npz`, and its `checkpoints/` may be deleted.

A checkpoint is written into a temporary folder and renamed into place, then `latest.json` is replaced
atomically; an interrupted run therefore never leaves a half-written checkpoint as the latest. `--resume` loads the
newest checkpoint that reads back completely and falls back to an older one when the newest is damaged.

Loading a run's data executes nothing: normalisation statistics and the SAC replay buffer are `.npz` arrays read
with `allow_pickle=False`; an older run's `vecnormalize.pkl` is read through an unpickler that admits only the
classes VecNormalize statistics are made of. `model.zip` is stable-baselines3's own format, which holds pickled
objects: a model file is code and must come from a trusted source.
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
import zipfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import yaml

from vswrist_gym.agents.hparams import ALGO_NAMES, ConfigError, RunConfig, algo_class, resolve_entry


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


def atomic_write_npz(path: Path, arrays: dict) -> None:
    """`np.savez` into memory, then an atomic write: a kill never leaves a half-written archive under `path`."""
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    atomic_write_bytes(path, buf.getvalue())


# --------------------------------------------------------------------------------------------------- input checks

SEED_MAX = 2**32 - 1  # NumPy's and stable-baselines3's seeds are unsigned 32-bit integers


def check_seed(seed, name: str = "--seed") -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= int(seed) <= SEED_MAX:
        raise ConfigError(f"{name} must be an integer in [0, 2**32 - 1 = {SEED_MAX}] (the range NumPy and "
                          f"stable-baselines3 accept), got {seed}")
    return int(seed)


def _nearest_existing(path: Path) -> Path:
    path = Path(os.path.abspath(path))
    while not path.exists() and path != path.parent:
        path = path.parent
    return path


def check_writable(path: str | Path, name: str = "--out") -> None:
    """`path` (a folder, existing or not) can be created and written: a probe file is created and removed in the
    folder itself or, when it does not exist yet, in its nearest existing ancestor. Raises RunDirError otherwise."""
    path = Path(path)
    base = _nearest_existing(path)
    if not base.is_dir():
        what = "is a file" if base == Path(os.path.abspath(path)) else f"lies under {base}, which is a file"
        raise RunDirError(f"{name} {path}: cannot be a folder: it {what}")
    try:
        fd, probe = tempfile.mkstemp(prefix=".vswrist_write_probe_", dir=base)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        where = "" if base == Path(os.path.abspath(path)) else f" (in {base}, its nearest existing folder)"
        raise RunDirError(f"{name} {path}: not writable{where}: {exc.strerror or exc}") from None


def check_new_out(path: str | Path, allowed: tuple[str, ...], what: str, name: str = "--out") -> None:
    """A folder to write `what` into: writable, and either absent, empty, or holding only names in `allowed`
    (output of the same kind, which the command replaces or continues). A non-empty folder of anything else is
    refused, so that no command writes its files among someone else's."""
    path = Path(path)
    check_writable(path, name)
    if path.is_dir():
        other = sorted(p.name for p in path.iterdir() if p.name not in allowed)
        if other:
            shown = ", ".join(other[:5]) + (f" and {len(other) - 5} more" if len(other) > 5 else "")
            raise RunDirError(f"{name} {path} is a non-empty folder that is not {what} (it holds {shown}); "
                              f"choose a new or empty folder")


def created_root(path: Path) -> Path | None:
    """The top-most folder that `mkdir(parents=True)` of `path` would create (None when `path` exists)."""
    path = Path(os.path.abspath(path))
    if path.exists():
        return None
    while not path.parent.exists():
        path = path.parent
    return path


def folder_bytes(path: Path) -> int:
    """Bytes of the files under `path` (its footprint on disk, up to block rounding)."""
    total = 0
    for root, _, files in os.walk(path):
        for f in files:
            try:
                total += os.lstat(os.path.join(root, f)).st_size
            except OSError:
                pass
    return total


def steps_done(run_dir: Path, prefix: str = "") -> int:
    """Environment steps of finished training episodes in the Monitor logs whose name starts with `prefix`
    (cheap progress for a process that is running, or was killed, without asking it)."""
    total = 0
    for f in (Path(run_dir) / "monitor").glob(f"{prefix}*.monitor.csv"):
        try:
            lines = f.read_text().splitlines()[2:]
            total += sum(int(float(line.split(",")[1])) for line in lines if line.count(",") >= 2)
        except (OSError, ValueError, IndexError):
            pass
    return total


# --------------------------------------------------------------------------------------------------- processes


def _proc_start_ticks(pid: int) -> int | None:
    """Start time of process `pid` in clock ticks since boot (Linux /proc), which tells a recycled pid apart."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
        return int(stat.rsplit(")", 1)[1].split()[19])
    except (OSError, ValueError, IndexError):
        return None


def this_process() -> dict:
    """What identifies the training process in run.json: pid, host, and the process start time where known."""
    return {"pid": os.getpid(), "host": platform.node(), "proc_start": _proc_start_ticks(os.getpid())}


def process_alive(record: dict) -> bool | None:
    """Whether the process recorded in run.json still runs: True / False, or None when it ran on another host
    (its pid means nothing here). A pid that exists but started at another time is a recycled pid: not alive."""
    pid = record.get("pid")
    if not isinstance(pid, int) or pid <= 0:
        return False
    if record.get("host") not in (None, platform.node()):
        return None
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass  # exists, owned by someone else
    started = record.get("proc_start")
    now = _proc_start_ticks(pid)
    return not (started is not None and now is not None and now != started)


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
        elif key == "history":
            doc.setdefault("history", []).append(value)
        else:
            doc[key] = value
    atomic_write_text(path, json.dumps(doc, indent=2))
    return doc


# --------------------------------------------------------------------------------------------------- statistics

VECNORM_FILE = "vecnormalize.npz"
VECNORM_LEGACY_FILE = "vecnormalize.pkl"
REPLAY_FILE = "replay_buffer.npz"
REPLAY_LEGACY_FILE = "replay_buffer.pkl"


def _space_arrays(prefix: str, space) -> dict:
    from gymnasium import spaces

    if not isinstance(space, spaces.Box):
        raise RunDirError(f"normalisation statistics of a {type(space).__name__} space cannot be saved as arrays")
    return {f"{prefix}_low": space.low, f"{prefix}_high": space.high, f"{prefix}_dtype": np.array(space.dtype.str)}


def vecnormalize_arrays(vn) -> dict:
    """VecNormalize statistics as plain arrays (everything its pickled form holds except the environment)."""
    if getattr(vn, "norm_obs_keys", None):
        raise RunDirError("normalisation of dict observations is not supported")
    return {"obs_mean": vn.obs_rms.mean, "obs_var": vn.obs_rms.var, "obs_count": np.float64(vn.obs_rms.count),
            "ret_mean": vn.ret_rms.mean, "ret_var": vn.ret_rms.var, "ret_count": np.float64(vn.ret_rms.count),
            "clip_obs": np.float64(vn.clip_obs), "clip_reward": np.float64(vn.clip_reward),
            "gamma": np.float64(vn.gamma), "epsilon": np.float64(vn.epsilon), "training": np.bool_(vn.training),
            "norm_obs": np.bool_(vn.norm_obs), "norm_reward": np.bool_(vn.norm_reward),
            **_space_arrays("observation_space", vn.observation_space),
            **_space_arrays("action_space", vn.action_space)}


def save_vecnormalize(path: Path, vn) -> None:
    atomic_write_npz(path, vecnormalize_arrays(vn))


def _vecnormalize_from_arrays(a) -> object:
    """A VecNormalize built from arrays the way unpickling builds one (`__setstate__`, then `set_venv`)."""
    from gymnasium import spaces
    from stable_baselines3.common.running_mean_std import RunningMeanStd
    from stable_baselines3.common.vec_env import VecNormalize

    def rms(prefix):
        r = RunningMeanStd(shape=np.shape(a[f"{prefix}_mean"]))
        r.mean, r.var, r.count = (np.array(a[f"{prefix}_mean"], dtype=np.float64),
                                  np.array(a[f"{prefix}_var"], dtype=np.float64), float(a[f"{prefix}_count"]))
        return r

    def box(prefix):
        return spaces.Box(low=a[f"{prefix}_low"], high=a[f"{prefix}_high"], dtype=np.dtype(str(a[f"{prefix}_dtype"])))

    state = {"obs_rms": rms("obs"), "ret_rms": rms("ret"), "clip_obs": float(a["clip_obs"]),
             "clip_reward": float(a["clip_reward"]), "gamma": float(a["gamma"]), "epsilon": float(a["epsilon"]),
             "training": bool(a["training"]), "norm_obs": bool(a["norm_obs"]), "norm_reward": bool(a["norm_reward"]),
             "norm_obs_keys": None, "observation_space": box("observation_space"),
             "action_space": box("action_space"), "num_envs": 1, "metadata": {}, "render_mode": None,
             "old_obs": np.array([]), "old_reward": np.array([]), "_seeds": [None], "_options": [{}],
             "reset_infos": [{}]}
    vn = VecNormalize.__new__(VecNormalize)
    vn.__setstate__(state)
    return vn


# (module, name) pairs a pickled VecNormalize refers to: the wrapper, its running statistics, the Box spaces and
# NumPy's array/scalar/dtype/generator reconstruction. Anything else in a vecnormalize.pkl is refused unloaded.
VECNORM_PICKLE_ALLOWED = {
    ("stable_baselines3.common.vec_env.vec_normalize", "VecNormalize"),
    ("stable_baselines3.common.running_mean_std", "RunningMeanStd"),
    ("gymnasium.spaces.box", "Box"),
    ("numpy", "ndarray"), ("numpy", "dtype"),
    ("numpy.core.multiarray", "_reconstruct"), ("numpy._core.multiarray", "_reconstruct"),
    ("numpy.core.multiarray", "scalar"), ("numpy._core.multiarray", "scalar"),
    ("numpy.core.numeric", "_frombuffer"), ("numpy._core.numeric", "_frombuffer"),
    ("numpy.random._pickle", "__generator_ctor"), ("numpy.random._pickle", "__bit_generator_ctor"),
    ("numpy.random._pickle", "__randomstate_ctor"),
    # the spaces' random generators, as rl_zoo3's vecnormalize.pkl (VecNormalize.save) holds them
    ("numpy.random._pcg64", "PCG64"), ("numpy.random._pcg64", "PCG64DXSM"), ("numpy.random._mt19937", "MT19937"),
    ("numpy.random._philox", "Philox"), ("numpy.random._sfc64", "SFC64"),
    ("numpy.random.bit_generator", "SeedSequence"), ("numpy.random.bit_generator", "__pyx_unpickle_SeedSequence"),
}


class _StatisticsUnpickler(pickle.Unpickler):
    def find_class(self, module, name):
        if (module, name) not in VECNORM_PICKLE_ALLOWED:
            raise pickle.UnpicklingError(f"it refers to {module}.{name}, which normalisation statistics never hold "
                                         f"(refused without running it)")
        return super().find_class(module, name)


def load_vecnormalize(path: Path, venv):
    """Normalisation statistics from `vecnormalize.npz` (plain arrays, `allow_pickle=False`) or, for a run written
    by an older version, `vecnormalize.pkl` through an allow-list unpickler; wrapped around `venv` if given.
    `path` is the file or the folder that holds it."""
    from stable_baselines3.common.vec_env import VecNormalize

    path = Path(path)
    if path.is_dir() or path.name in (VECNORM_FILE, VECNORM_LEGACY_FILE):
        folder = path if path.is_dir() else path.parent
        path = folder / VECNORM_FILE
        if not path.is_file() and (folder / VECNORM_LEGACY_FILE).is_file():
            path = folder / VECNORM_LEGACY_FILE
    if not path.is_file():
        raise RunDirError(f"normalisation statistics not found: {path} (the run was trained with normalisation)")
    try:
        if path.suffix == ".npz":
            with np.load(path, allow_pickle=False) as a:
                vn = _vecnormalize_from_arrays(a)
        else:
            with path.open("rb") as fh:
                vn = _StatisticsUnpickler(fh).load()
            if not isinstance(vn, VecNormalize):
                raise TypeError(f"contains a {type(vn).__name__}, not VecNormalize statistics")
        if venv is not None:
            vn.set_venv(venv)
        return vn
    except pickle.UnpicklingError as exc:
        raise RunDirError(f"normalisation file {path} not loaded: {exc}") from None
    except Exception as exc:  # noqa: BLE001 - zip, key, value and shape errors all mean "unreadable"
        raise RunDirError(f"normalisation file {path} is corrupted ({type(exc).__name__}: {exc})") from None


REPLAY_ARRAYS = ("observations", "next_observations", "actions", "rewards", "dones", "timeouts")


def save_replay_buffer(path: Path, buffer) -> None:
    """The filled part of an SB3 ReplayBuffer as plain arrays: a buffer sized for 100,000 transitions that holds
    20,000 costs a fifth of its pickled size, and reading it back executes nothing."""
    n = buffer.buffer_size if buffer.full else buffer.pos
    arrays = {name: getattr(buffer, name)[:n] for name in REPLAY_ARRAYS if getattr(buffer, name, None) is not None}
    atomic_write_npz(path, {**arrays, "pos": np.int64(buffer.pos), "full": np.bool_(buffer.full),
                            "buffer_size": np.int64(buffer.buffer_size), "n_envs": np.int64(buffer.n_envs)})


def load_replay_buffer(path: Path, buffer) -> None:
    """Fill `buffer` (the empty one a freshly loaded model built from its config) from `save_replay_buffer`."""
    try:
        with np.load(path, allow_pickle=False) as a:
            if int(a["buffer_size"]) != buffer.buffer_size or int(a["n_envs"]) != buffer.n_envs:
                raise ValueError(f"buffer of {int(a['buffer_size'])} x {int(a['n_envs'])} envs saved, the model has "
                                 f"{buffer.buffer_size} x {buffer.n_envs}")
            for name in REPLAY_ARRAYS:
                target = getattr(buffer, name, None)
                if target is None:
                    continue
                data = a[name]
                if data.shape[1:] != target.shape[1:] or len(data) > len(target):
                    raise ValueError(f"{name} of shape {data.shape}, the model's buffer is {target.shape}")
                target[:len(data)] = data
            buffer.pos, buffer.full = int(a["pos"]), bool(a["full"])
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        raise RunDirError(f"replay buffer {path} is corrupted ({type(exc).__name__}: {exc})") from None


# --------------------------------------------------------------------------------------------------- checkpoints


def save_checkpoint(run_dir: Path, model, vecnorm, keep: int = 2, with_replay_buffer: bool = True) -> Path:
    """Write checkpoints/step_<N>/ completely under a temporary name, rename it, then point latest.json at it."""
    from stable_baselines3.common.buffers import ReplayBuffer

    ck_root = Path(run_dir) / "checkpoints"
    ck_root.mkdir(parents=True, exist_ok=True)
    step = int(model.num_timesteps)
    final = ck_root / f"step_{step:010d}"
    tmp = Path(tempfile.mkdtemp(prefix=".tmp_step_", dir=ck_root))
    try:
        (tmp / "model.zip").write_bytes(model_bytes(model))
        if vecnorm is not None:
            save_vecnormalize(tmp / VECNORM_FILE, vecnorm)
        buffer = getattr(model, "replay_buffer", None)
        # other buffer classes (HER, dict observations) have no plain-array form and are not saved: SB3's own
        # format is a pickle, which vswrist never reads back; such a run resumes with an empty buffer
        if with_replay_buffer and type(buffer) is ReplayBuffer:
            save_replay_buffer(tmp / REPLAY_FILE, buffer)
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


def checkpoints(run_dir: Path) -> list[Path]:
    """Complete checkpoints (renamed into place, with a model file), newest first."""
    ck_root = Path(run_dir) / "checkpoints"
    return sorted((p for p in ck_root.glob("step_*") if (p / "model.zip").is_file()), reverse=True)


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
    complete = checkpoints(run_dir)
    return complete[0] if complete else None


def checkpoint_step(folder: Path | None) -> int | None:
    """The training step of a checkpoint folder step_<N> (None for no folder or another name)."""
    try:
        return int(folder.name.split("_", 1)[1]) if folder is not None and folder.name.startswith("step_") else None
    except ValueError:
        return None


def final_model_step(run_dir: Path) -> int | None:
    """The training step of the run's top-level model.zip, from run.json: `final_model_step` (written with it)
    or, for runs written before that field, the step of the last 'finished' invocation; None when unknown."""
    try:
        doc = json.loads((Path(run_dir) / "run.json").read_text())
    except (OSError, ValueError):
        return None
    if isinstance(doc.get("final_model_step"), int):
        return doc["final_model_step"]
    finished = [h for h in doc.get("history", []) if isinstance(h, dict) and h.get("status") == "finished"]
    step = finished[-1].get("reached_step") if finished else None
    return int(step) if isinstance(step, (int, float)) else None


def load_checkpoint(checkpoint: Path, algo: str, venv, normalize: bool, frame_stack: int = 1):
    """Model (with its normalisation and frame-stacking wrappers around `venv` and its replay buffer) from one
    checkpoint folder. Raises RunDirError naming the file when any part of it does not read back."""
    env = venv
    if normalize:
        env = load_vecnormalize(checkpoint, venv)
        env.training = True
    env = wrap_frame_stack(env, frame_stack)
    refuse_pickles(checkpoint)
    model = load_model(checkpoint / "model.zip", algo, env=env)
    if getattr(model, "replay_buffer", None) is not None and (checkpoint / REPLAY_FILE).is_file():
        load_replay_buffer(checkpoint / REPLAY_FILE, model.replay_buffer)
    return model, env


def refuse_pickles(run_dir: Path) -> None:
    """A replay buffer (or any file but normalisation statistics) saved as a pickle under `run_dir` is refused
    unread: unpickling can run any code, and vswrist writes replay buffers as plain arrays only."""
    found = sorted(p for p in Path(run_dir).rglob("*.pkl") if p.name != VECNORM_LEGACY_FILE)
    if found:
        more = f" (and {len(found) - 1} more)" if len(found) > 1 else ""
        raise RunDirError(f"{found[0]}{more}: a pickle file, which vswrist never loads (unpickling can run any "
                          f"code; replay buffers are saved as {REPLAY_FILE}); delete it to go on, a resumed run "
                          f"then continues with an empty replay buffer")


def load_newest_intact(run_dir: Path, algo: str, venv, normalize: bool, log=print, frame_stack: int = 1):
    """(checkpoint, model, env) from the newest checkpoint that reads back completely; older ones are tried when
    the newest is damaged (truncated file, missing statistics), and the fallback is reported in one line.
    (None, None, venv) when the run has no checkpoint; RunDirError when none is intact."""
    refuse_pickles(run_dir)
    found = checkpoints(run_dir)
    latest = latest_checkpoint(run_dir)
    if latest is not None and latest in found:  # latest.json first, then the others newest first
        found = [latest] + [c for c in found if c != latest]
    if (Path(run_dir) / "model.zip").is_file():  # the final model last: it has no replay buffer
        found.append(Path(run_dir))
    damaged = []
    for ck in found:
        try:
            model, env = load_checkpoint(ck, algo, venv, normalize, frame_stack)
        except RunDirError as exc:
            damaged.append(f"{ck.name}: {exc}")
            continue
        if damaged:
            what = ck.name if ck != Path(run_dir) else "the run's final model.zip"
            log(f"checkpoint {damaged[0]}; resuming from the newest intact one, {what}")
        if getattr(model, "replay_buffer", None) is not None and not any(
                (ck / name).is_file() for name in (REPLAY_FILE,)):
            log(f"{ck / 'model.zip'} has no replay buffer beside it: training continues with an empty one")
        return ck, model, env
    if damaged:
        raise RunDirError(f"no intact checkpoint in {Path(run_dir) / 'checkpoints'}: " + "; ".join(damaged)
                          + " (start a new run with another --out)")
    return None, None, venv


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


# ------------------------------------------------------------------------------------------- RL Zoo log folders

ZOO_CONFIG_FILE, ZOO_ARGS_FILE, ZOO_VECNORM_FILE = "config.yml", "args.yml", "vecnormalize.pkl"


class _ZooYamlLoader(yaml.SafeLoader):
    """SafeLoader plus the one Python tag rl_zoo3 writes into config.yml and args.yml (an OrderedDict, as a list
    of key-value pairs); any other Python tag stays an error, so reading the files runs nothing."""


def _ordered_dict(loader, node):
    if not isinstance(node, yaml.SequenceNode):
        raise yaml.constructor.ConstructorError(None, None, "an OrderedDict that is not a list of pairs",
                                                node.start_mark)
    args = loader.construct_sequence(node, deep=True)  # [[[key, value], ...]]: the constructor's one argument
    return {k: v for k, v in (args[0] if args else [])}


_ZooYamlLoader.add_constructor("tag:yaml.org,2002:python/object/apply:collections.OrderedDict", _ordered_dict)


def zoo_params_folder(folder: Path) -> Path | None:
    """The parameters folder (config.yml, args.yml, vecnormalize.pkl) of an RL Zoo experiment folder such as
    logs/ppo/VSWrist-Polish-v1_1, or None when `folder` is not one."""
    folder = Path(folder)
    if not folder.is_dir():
        return None
    found = [p for p in sorted(folder.iterdir()) if p.is_dir() and (p / ZOO_ARGS_FILE).is_file()
             and (p / ZOO_CONFIG_FILE).is_file()]
    return found[0] if len(found) == 1 else None


def read_zoo_run(folder: Path) -> tuple[RunConfig, int, Path]:
    """(config, seed, parameters folder) of an RL Zoo experiment folder, from the files rl_zoo3 wrote: the env id,
    algorithm and seed from args.yml, the entry (env_kwargs, normalize, ...) from config.yml. env_kwargs follow
    rl_zoo3.enjoy: the entry's, replaced by args.yml's --env-kwargs when those were given."""
    params = zoo_params_folder(folder)
    if params is None:
        raise RunDirError(f"{folder} is not an RL Zoo experiment folder (no <env>/{ZOO_ARGS_FILE} and "
                          f"<env>/{ZOO_CONFIG_FILE} in it)")
    try:
        args = yaml.load((params / ZOO_ARGS_FILE).read_text(), Loader=_ZooYamlLoader)
        hyper = yaml.load((params / ZOO_CONFIG_FILE).read_text(), Loader=_ZooYamlLoader)
        algo, env_id = str(args["algo"]).lower(), str(args["env"])
        seed = int(args.get("seed", 0) or 0)
        if not isinstance(hyper, dict):
            raise TypeError(f"{ZOO_CONFIG_FILE} holds a {type(hyper).__name__}, not the entry")
    except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError) as exc:
        raise RunDirError(f"{params}: RL Zoo files not readable ({type(exc).__name__}: {exc})") from None
    if algo not in ALGO_NAMES:
        raise RunDirError(f"{folder}: an RL Zoo {algo.upper()} run; vswrist evaluates {', '.join(ALGO_NAMES)} runs "
                          f"only")
    hyper = dict(hyper)
    if args.get("env_kwargs") is not None:
        hyper["env_kwargs"] = args["env_kwargs"]
    # keys that shape training but not the policy's inputs or outputs: the model file holds the network itself,
    # so these need not be understood to replay it (env_wrapper and the like do change what the policy sees, and
    # stay errors; frame_stack is replayed as rl_zoo3 trains it)
    for key in ("policy_kwargs", "callback", "monitor_kwargs", "noise_type", "noise_std", "replay_buffer_class",
                "replay_buffer_kwargs"):
        hyper.pop(key, None)
    normalize = hyper.get("normalize")
    if isinstance(normalize, dict):  # rl_zoo3 adds the algorithm's gamma (reward normalisation only)
        hyper["normalize"] = {k: v for k, v in normalize.items() if k != "gamma"}
    try:
        cfg = resolve_entry(algo, env_id, hyper, source=str(params / ZOO_CONFIG_FILE))
    except ConfigError as exc:
        raise RunDirError(f"{params / ZOO_CONFIG_FILE}: {exc}") from None
    return cfg, seed, params


def resolve_agent_path(text: str | Path) -> tuple[Path, str | None]:
    """(run folder, checkpoint implied by the file) for what a user names as a trained agent: a vswrist run
    directory, an RL Zoo experiment folder, or a model file inside either. A model file anywhere else is refused:
    it does not say which action mode or normalisation statistics it was trained with."""
    path = Path(text)
    if path.is_dir() or path.suffix != ".zip":
        return path, None
    if not path.is_file():
        raise RunDirError(f"model file not found: {path}")
    parent = path.parent
    if (parent / "config.yaml").is_file() and path.name == "model.zip":
        return parent, "final"
    if parent.name == "eval" and (parent.parent / "config.yaml").is_file() and path.name == "best_model.zip":
        return parent.parent, "best"
    params = zoo_params_folder(parent)
    if params is not None and path.name == f"{params.name}.zip":
        return parent, "final"
    if params is not None and path.name == "best_model.zip":
        return parent, "best"
    raise RunDirError(f"{path}: a model file alone does not say the action mode and normalisation it was trained "
                      f"with; give its run directory (vswrist train) or RL Zoo experiment folder (logs/<algo>/<env>_N)")


def env_config_mismatch(env, env_kwargs: dict) -> str | None:
    """None when `env` was built with the settings `env_kwargs` give (rendering aside); otherwise the first
    setting that differs, as 'key: trained with X, the environment has Y'. Environments without a resolved
    `cfg` (not VS-Wrist tasks) are compared through their spaces only, by the caller."""
    import gymnasium as gym

    have = getattr(env.unwrapped, "cfg", None)
    if not isinstance(have, dict) or env.spec is None:
        return None
    ref = gym.make(env.spec.id, **env_kwargs)
    try:
        want = ref.unwrapped.cfg
    finally:
        ref.close()

    def first_diff(a, b, where=""):
        if isinstance(a, dict) and isinstance(b, dict):
            for key in sorted(set(a) | set(b), key=lambda k: (k != "action_mode", str(k))):
                if not where and key == "render":
                    continue
                diff = first_diff(a.get(key), b.get(key), f"{where}.{key}" if where else str(key))
                if diff:
                    return diff
            return None
        same = a == b
        if isinstance(same, np.ndarray):
            same = bool(np.all(same))
        return None if same else f"{where}: trained with {a!r}, the environment has {b!r}"

    return first_diff(want, have)


class TrainedAgent:
    """A trained run (a `vswrist train` run directory or an RL Zoo experiment folder) as an agent with the SB3
    `predict` interface on raw (unnormalised) observations, with the run's own normalisation statistics."""

    def __init__(self, run_dir: str | Path, checkpoint: str = "newest"):
        from gymnasium import spaces

        run_dir, implied = resolve_agent_path(run_dir)
        if implied is not None:
            checkpoint = implied
        self.run_dir = Path(run_dir)
        if not self.run_dir.is_dir():
            raise RunDirError(f"run directory not found: {self.run_dir}")
        self.kind = "vswrist"
        self.note = None  # a line to show the user when the model evaluated is not the run's newest
        if not (self.run_dir / "config.yaml").is_file() and zoo_params_folder(self.run_dir) is not None:
            self.kind = "rl_zoo"
            self.cfg, self.seed, params = read_zoo_run(self.run_dir)
            name = {"final": f"{params.name}.zip", "newest": f"{params.name}.zip",
                    "best": "best_model.zip"}.get(checkpoint)
            if name is None:
                raise RunDirError(f"--checkpoint {checkpoint}: an RL Zoo folder has its final model and "
                                  f"best_model.zip (final or best)")
            model_path, stats = self.run_dir / name, params / ZOO_VECNORM_FILE
        else:
            self.cfg, self.seed = read_config(self.run_dir)
            model_path, stats = self._vswrist_files(checkpoint)
        self.model_path = model_path
        self.model = load_model(model_path, self.cfg.algo)
        self.vecnorm = None
        if self.cfg.normalize is not None:
            self.vecnorm = load_vecnormalize(stats, None)
            self.vecnorm.training = False
        if not isinstance(self.model.observation_space, spaces.Box):
            raise RunDirError(f"{self.run_dir}: unsupported observation space {self.model.observation_space}")
        self.frame_stack = self.cfg.frame_stack
        self._stack = None  # the stacked frames, one row per environment, built at the first query

    @property
    def observation_shape(self) -> tuple:
        """The shape of one environment observation the policy was trained on (the model sees frame_stack of
        them side by side, the newest last, as VecFrameStack stacks flat observations)."""
        shape = tuple(self.model.observation_space.shape)
        if self.frame_stack > 1:
            if shape[-1] % self.frame_stack:
                raise RunDirError(f"{self.run_dir}: model observations of shape {shape} do not split into "
                                  f"frame_stack {self.frame_stack} frames")
            shape = (*shape[:-1], shape[-1] // self.frame_stack)
        return shape

    def _vswrist_files(self, checkpoint: str) -> tuple[Path, Path]:
        final_step, latest = final_model_step(self.run_dir), latest_checkpoint(self.run_dir)
        latest_step = checkpoint_step(latest)
        newer = latest if latest is not None and (not (self.run_dir / "model.zip").exists() or (
            latest_step is not None and (final_step is None or latest_step > final_step))) else None
        if checkpoint == "newest":
            if newer is None:
                checkpoint = "final"
            else:
                checkpoint = "latest"
                if (self.run_dir / "model.zip").exists():
                    self.note = (f"{self.run_dir}: evaluating {newer.relative_to(self.run_dir)} (step {latest_step}), "
                                 f"the newest model run.json accounts for; model.zip holds the older step "
                                 f"{final_step if final_step is not None else 'unknown'} (--checkpoint final for it)")
        elif checkpoint == "final" and newer is not None and (self.run_dir / "model.zip").exists():
            self.note = (f"{self.run_dir}: evaluating model.zip (step {final_step if final_step is not None else '?'})"
                         f" as asked; the run went on to step {latest_step} ({newer.relative_to(self.run_dir)})")
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
            raise ValueError(f"checkpoint must be newest, final, latest or best, got {checkpoint!r}")
        name = "best_model.zip" if checkpoint == "best" else "model.zip"
        return folder / name, (self.run_dir if checkpoint == "best" else folder)

    @property
    def env_id(self) -> str:
        return self.cfg.env_id

    def check_env(self, env) -> None:
        """The environment must be the one the run was trained on: same spaces and, for a VS-Wrist task, the same
        resolved settings (action mode above all), so that a policy never drives an environment it does not know."""
        if env.observation_space.shape != self.observation_shape:
            raise RunDirError(f"{self.run_dir} was trained on observations of shape "
                              f"{self.observation_shape}, the environment gives "
                              f"{env.observation_space.shape}")
        if env.action_space != self.model.action_space:
            raise RunDirError(f"{self.run_dir} was trained with actions in {self.model.action_space}, the "
                              f"environment takes {env.action_space}")
        diff = env_config_mismatch(env, self.cfg.env_kwargs)
        if diff:
            raise RunDirError(f"{self.run_dir} does not match the environment: {diff} (build it with the run's "
                              f"env_kwargs {self.cfg.env_kwargs})")
        if self.vecnorm is not None and self.vecnorm.norm_obs and \
                np.shape(self.vecnorm.obs_rms.mean) != env.observation_space.shape:
            raise RunDirError(f"{self.run_dir}: normalisation statistics of shape {np.shape(self.vecnorm.obs_rms.mean)}"
                              f" for observations of shape {env.observation_space.shape}")

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        """The action for `obs` (one observation or a batch, one row per environment). With frame stacking the
        agent keeps each environment's last frames as VecFrameStack does in training: a row whose
        `episode_start` is true starts from zeros with its observation newest. Without `episode_start` (a caller
        that runs one episode, as `vswrist video` does) every row starts at the first query and continues after."""
        if self.vecnorm is not None and self.vecnorm.norm_obs:
            obs = self.vecnorm.normalize_obs(np.asarray(obs, dtype=np.float32))
        if self.frame_stack <= 1:
            return self.model.predict(obs, state=state, episode_start=episode_start, deterministic=deterministic)
        obs = np.asarray(obs, dtype=np.float32)
        single = obs.shape == self.observation_shape
        rows = obs.reshape(1, *obs.shape) if single else obs
        starts = np.zeros(len(rows), dtype=bool) if episode_start is None else \
            np.asarray(episode_start, dtype=bool).reshape(len(rows))
        width = rows.shape[-1]
        if self._stack is None or self._stack.shape[0] != len(rows):
            self._stack = np.zeros((len(rows), *rows.shape[1:-1], width * self.frame_stack), dtype=np.float32)
            starts = np.ones(len(rows), dtype=bool)
        # VecFrameStack's update of flat observations: every row shifts by one frame, a row whose episode starts
        # is zeroed, and the new frames go last
        self._stack = np.roll(self._stack, -width, axis=-1)
        self._stack[starts] = 0.0
        self._stack[..., -width:] = rows
        stacked = self._stack.copy()
        action, state = self.model.predict(stacked, state=state, episode_start=episode_start,
                                           deterministic=deterministic)
        return (action[0] if single else action), state


def override(cfg: RunConfig, **changes) -> RunConfig:
    """A copy of the config with run keys changed (None means keep)."""
    changes = {k: v for k, v in changes.items() if v is not None}
    return replace(cfg, **changes)
