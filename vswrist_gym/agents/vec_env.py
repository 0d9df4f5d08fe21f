"""stable-baselines3's ``VecEnv`` over the batched VS-Wrist core (``envs.batch.VSWristVectorEnv``).

SB3 pays its own per-step cost (policy forward, buffers, callbacks) once per vector step, so one process
holding many worlds, with their physics on threads, trains faster than a process per world (docs/training.md).
SB3's conventions differ from Gymnasium's vector API in three ways this adapter bridges: a finished world is
reset in the same step (the last observation goes to ``info["terminal_observation"]``), ``done`` is
terminated or truncated with ``info["TimeLimit.truncated"]`` telling which, and infos are a list of dicts.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices


class BatchVecEnv(VecEnv):
    """SB3 VecEnv of ``num_envs`` worlds of ``env_id`` in this process (``threads`` physics threads)."""

    def __init__(self, env_id: str, num_envs: int, env_kwargs: dict | None = None, threads: int | None = None,
                 render_mode: str | None = None):
        from gymnasium.vector import AutoresetMode

        from ..envs.batch import VSWristVectorEnv

        kwargs = dict(env_kwargs or {})
        if render_mode is not None:
            kwargs["render_mode"] = render_mode
        self.venv = VSWristVectorEnv(env_id, num_envs, threads=threads, autoreset_mode=AutoresetMode.SAME_STEP,
                                     **kwargs)
        self.envs = self.venv.envs  # the worlds, as DummyVecEnv exposes them (the analytic agent reads envs[0])
        super().__init__(num_envs, self.venv.single_observation_space, self.venv.single_action_space)
        self.render_mode = render_mode
        self.metadata = self.venv.metadata
        self._actions: np.ndarray | None = None

    @staticmethod
    def from_vector_env(env) -> "VectorVecEnv":
        """SB3's VecEnv over an existing Gymnasium ``VectorEnv`` (``gym.make_vec(id, N)`` in any vectorization
        mode, with vector wrappers or not): ``PPO("MlpPolicy", BatchVecEnv.from_vector_env(envs))``."""
        return VectorVecEnv(env)

    def reset(self):
        opts = self._options
        if any(opts) and any(o != opts[0] for o in opts):
            raise ValueError("BatchVecEnv resets every world with the same options; got different ones per world")
        obs, _ = self.venv.reset(seed=list(self._seeds), options=opts[0] or None)
        self.reset_infos = [{} for _ in range(self.num_envs)]
        self._reset_seeds()
        self._reset_options()
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions

    def step_wait(self):
        obs, rew, term, trunc, infos = self.venv.step_worlds(self._actions)
        out = []
        for i, info in enumerate(infos):
            if "final_obs" in info:
                final = dict(info["final_info"])
                final["terminal_observation"] = info["final_obs"]
                final["TimeLimit.truncated"] = bool(trunc[i] and not term[i])
                self.reset_infos[i] = {k: v for k, v in info.items() if k not in ("final_obs", "final_info")}
                out.append(final)
            else:
                info["TimeLimit.truncated"] = False
                out.append(info)
        return obs, rew.astype(np.float32), term | trunc, out

    def close(self) -> None:
        self.venv.close()

    def get_images(self) -> Sequence[np.ndarray | None]:
        if self.render_mode != "rgb_array":
            return [None] * self.num_envs
        return list(self.venv.render())

    def _targets(self, indices: VecEnvIndices) -> list:
        return [self.envs[i] for i in self._get_indices(indices)]

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return [getattr(e, attr_name) for e in self._targets(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        for e in self._targets(indices):
            setattr(e, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices: VecEnvIndices = None, **method_kwargs) -> list:
        return [getattr(e, method_name)(*method_args, **method_kwargs) for e in self._targets(indices)]

    def env_is_wrapped(self, wrapper_class, indices: VecEnvIndices = None) -> list[bool]:
        return [isinstance(e, wrapper_class) for e in self._targets(indices)]  # the worlds are bare envs


def _unbatch_infos(infos: dict, n: int) -> list[dict]:
    """Gymnasium's vector infos (key -> array over envs, with a ``_key`` mask of the envs that have it) as one
    dict per env, as SB3 takes them."""
    out: list[dict] = [{} for _ in range(n)]
    for key, value in infos.items():
        if key.startswith("_"):
            continue
        mask = infos.get(f"_{key}", np.ones(n, dtype=bool))
        for i in np.flatnonzero(mask):
            out[i][key] = _unbatch_infos(value, n)[i] if isinstance(value, dict) else value[i]
    return out


class VectorVecEnv(VecEnv):
    """SB3 VecEnv over any Gymnasium ``VectorEnv`` (``BatchVecEnv.from_vector_env``). SB3 needs a finished
    env's reset observation in the same step: with autoreset SAME_STEP the vector env gives it (and the last
    observation in ``info["final_obs"]``); with NEXT_STEP or DISABLED the finished envs are reset at once
    through ``reset(options={"reset_mask": done})``. Seeds set by ``seed()`` apply at the next full reset."""

    def __init__(self, env):
        from gymnasium.vector import AutoresetMode, VectorEnv

        if not isinstance(env, VectorEnv):
            raise TypeError(f"from_vector_env takes a gymnasium.vector.VectorEnv (gym.make_vec), got "
                            f"{type(env).__name__}")
        self.venv = env
        self._same_step = env.metadata.get("autoreset_mode", AutoresetMode.NEXT_STEP) == AutoresetMode.SAME_STEP
        super().__init__(env.num_envs, env.single_observation_space, env.single_action_space)
        self.render_mode = env.render_mode
        self.metadata = env.metadata
        self._actions: np.ndarray | None = None

    def reset(self):
        opts = self._options
        if any(opts) and any(o != opts[0] for o in opts):
            raise ValueError("from_vector_env resets every env with the same options; got different ones per env")
        seeds = list(self._seeds)
        obs, infos = self.venv.reset(seed=None if all(s is None for s in seeds) else seeds, options=opts[0] or None)
        self.reset_infos = _unbatch_infos(infos, self.num_envs)
        self._reset_seeds()
        self._reset_options()
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions

    def step_wait(self):
        obs, rew, term, trunc, infos = self.venv.step(self._actions)
        done = np.logical_or(term, trunc)
        out = _unbatch_infos(infos, self.num_envs)
        if done.any():
            if self._same_step:
                for i in np.flatnonzero(done):
                    final = dict(out[i].get("final_info") or {})
                    final["terminal_observation"] = out[i]["final_obs"]
                    self.reset_infos[i] = {k: v for k, v in out[i].items() if k not in ("final_obs", "final_info")}
                    out[i] = final
            else:
                obs = np.array(obs, copy=True)
                fresh, reset_infos = self.venv.reset(options={"reset_mask": done})
                resets = _unbatch_infos(reset_infos, self.num_envs)
                for i in np.flatnonzero(done):
                    out[i]["terminal_observation"] = obs[i].copy()
                    self.reset_infos[i] = resets[i]
                obs[done] = np.asarray(fresh)[done]
        for i in range(self.num_envs):
            out[i]["TimeLimit.truncated"] = bool(trunc[i] and not term[i])
        return obs, np.asarray(rew, dtype=np.float32), done, out

    def close(self) -> None:
        self.venv.close()

    def get_images(self) -> Sequence[np.ndarray | None]:
        if self.render_mode != "rgb_array":
            return [None] * self.num_envs
        return list(self.venv.render())

    def _target(self):
        envs = getattr(self.venv.unwrapped, "envs", None)
        if envs is None:
            raise AttributeError(f"{type(self.venv.unwrapped).__name__} does not expose its envs in this process")
        return envs

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        envs = self._target()
        return [getattr(envs[i], attr_name) for i in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        envs = self._target()
        for i in self._get_indices(indices):
            setattr(envs[i], attr_name, value)

    def env_method(self, method_name: str, *method_args, indices: VecEnvIndices = None, **method_kwargs) -> list:
        envs = self._target()
        return [getattr(envs[i], method_name)(*method_args, **method_kwargs) for i in self._get_indices(indices)]

    def env_is_wrapped(self, wrapper_class, indices: VecEnvIndices = None) -> list[bool]:
        envs = getattr(self.venv.unwrapped, "envs", None)
        if envs is None:
            return [False] * len(self._get_indices(indices))
        return [isinstance(envs[i], wrapper_class) for i in self._get_indices(indices)]
