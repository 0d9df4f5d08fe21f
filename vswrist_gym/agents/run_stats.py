"""Normalisation statistics and the SAC replay buffer as plain arrays (.npz, read with `allow_pickle=False`), so
that loading them executes nothing; normalisation statistics that only exist as a pickle (RL Zoo's
vecnormalize.pkl, an older run's) go through an unpickler that builds only the classes they are made of."""

from __future__ import annotations

import pickle
import zipfile
from pathlib import Path

import numpy as np

from vswrist_gym.agents.fileio import RunDirError, atomic_write_npz


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
