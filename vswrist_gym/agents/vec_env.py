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
