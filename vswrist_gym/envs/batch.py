"""N VS-Wrist worlds behind one ``gymnasium.vector.VectorEnv`` (``gym.make_vec(id, N)``), physics on threads.

Each world is a task environment (its own MjModel/MjData, so domain randomisation that rebuilds a world's model
works per world). One ``step`` of the batch:

1. every action row is checked first (shape ``(N, action_dim)``, real and finite; else ``ValueError`` naming the
   env index), so a bad batch changes nothing;
2. worlds that ended on the previous step are reset (``autoreset_mode`` NEXT_STEP, the default) or, with
   SAME_STEP, right after the step that ended them;
3. the Python pre-physics phase of every world (action -> controller -> motor references, task loads);
4. the physics of all worlds: one control period each, ``mj_step(m, d, nstep)`` per world on a pool of
   ``threads`` threads, each thread a contiguous chunk of worlds. MuJoCo's bindings release the GIL inside
   ``mj_step``, and the compiled plugins (``model.native``: springs and motors, the loop-closure monitor, and
   Polish's and Hammer's per-substep contact meter ``vswrist.contact``) keep no global mutable state (theirs
   lives in each MjData's ``plugin_data``/``plugin_state``), so worlds advance in parallel; no task steps
   substep by substep from Python. With the Python fallback callbacks (no C compiler) each substep re-enters
   Python, so threads would only contend for the GIL: the batch then steps serially;
5. the post-physics phase of every world (measures, reward, observation, info), stacked.

Seeding follows Gymnasium: ``reset(seed=s)`` seeds world i with ``s + i`` (a list gives one seed per world), so
world i replays ``gym.make(id).reset(seed=s + i)`` step for step (``tests/test_batch.py``).
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Mapping, Sequence

import gymnasium as gym
import numpy as np
from gymnasium.error import ResetNeeded
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from .actions import check_action


THREADS_ENV = "VSWRIST_THREADS"  # physics threads of every batch made without ``threads`` (e.g. by vswrist train)


def default_threads() -> int:
    """``$VSWRIST_THREADS`` if set, else the cores this process may run on (``os.sched_getaffinity``)."""
    value = os.environ.get(THREADS_ENV)
    if value:
        try:
            n = int(value)
        except ValueError:
            n = 0
        if n < 1:
            raise ValueError(f"{THREADS_ENV} must be an integer >= 1 (physics threads per batch), got {value!r}")
        return n
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - macOS, Windows
        return max(1, os.cpu_count() or 1)


def _env_class(env_id: str):
    from gymnasium.envs.registration import load_env_creator

    import vswrist_gym  # noqa: F401  (registers the ids)

    if env_id not in gym.registry:
        ours = sorted(k for k in gym.registry if k.startswith("VSWrist/"))
        raise gym.error.Error(f"unknown environment id {env_id!r}; VS-Wrist ids: {ours}")
    entry = gym.registry[env_id].entry_point
    return load_env_creator(entry) if isinstance(entry, str) else entry


class VSWristVectorEnv(VectorEnv):
    """``num_envs`` worlds of one task (``env_id``), stepped together; see the module docstring.

    ``config``/``overrides``: as for ``gym.make`` (the same for every world). ``threads``: physics threads
    (default: the cores available; 1 = serial). ``autoreset_mode``: NEXT_STEP (Gymnasium's default) or
    SAME_STEP (the reset observation is returned at once, the last one in ``info["final_obs"]``).
    """

    def __init__(self, env_id: str, num_envs: int = 1, render_mode: str | None = None,
                 config: Mapping[str, Any] | None = None, threads: int | None = None,
                 autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP, max_episode_steps: int | None = None,
                 **overrides: Any):
        if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
            raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}")
        self.autoreset_mode = AutoresetMode(autoreset_mode)
        if self.autoreset_mode == AutoresetMode.DISABLED:
            raise ValueError("autoreset_mode must be NEXT_STEP or SAME_STEP (worlds end their own episodes)")
        cls = _env_class(env_id)
        self.env_id = env_id
        self.num_envs = int(num_envs)
        spec = gym.registry[env_id]
        # the id's registered kwargs (an older version's id_config), as gym.make(env_id) passes them; make_vec
        # already merged them into overrides, a direct construction did not
        kwargs = {**spec.kwargs, **overrides}
        self.envs = [cls(render_mode=render_mode, config=config, **kwargs) for _ in range(self.num_envs)]
        for e in self.envs:
            e.spec = spec
        first = self.envs[0]
        if max_episode_steps is not None and max_episode_steps != first.episode_steps:
            raise ValueError(f"max_episode_steps = {max_episode_steps} differs from the task's episode length "
                             f"({first.episode_steps} steps = episode_s / ctrl_dt); set 'episode_s' in config")
        self.render_mode = render_mode
        self.metadata = dict(first.metadata, autoreset_mode=self.autoreset_mode)
        self.single_action_space = first.action_space
        self.single_observation_space = first.observation_space
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self._act_shape = first.action_space.shape
        self._dict_obs = first.cfg["obs_mode"] == "dict"
        self._autoreset = np.zeros(self.num_envs, dtype=bool)
        self._started = False
        # "c" (compiled per-substep springs and motors) or "python" (the fallback callbacks: no threads)
        self.backend = getattr(first.sim, "backend", "c")
        self.set_threads(threads)

    # ------------------------------------------------------------------ threads
    def set_threads(self, threads: int | None) -> None:
        """Physics threads (None: the cores available). With the Python fallback callbacks: always 1."""
        if threads is not None and (isinstance(threads, bool) or not isinstance(threads, (int, np.integer))
                                    or threads < 1):
            raise ValueError(f"threads must be an integer >= 1 or None (the core count), got {threads!r}")
        n = default_threads() if threads is None else int(threads)
        if self.backend != "c":
            n = 1  # Python callbacks run under the GIL inside every substep: threads would only contend
        n = min(n, self.num_envs)
        self._close_pool()
        self.threads = n
        bounds = np.linspace(0, self.num_envs, n + 1).round().astype(int)
        self._chunks = [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])]
        self._pool = ThreadPoolExecutor(max_workers=n - 1, thread_name_prefix="vswrist-physics") if n > 1 else None

    def _close_pool(self) -> None:
        pool = getattr(self, "_pool", None)
        if pool is not None:
            pool.shutdown(wait=True)
        self._pool = None

    def _advance_chunk(self, lo: int, hi: int, live: np.ndarray) -> None:
        envs = self.envs
        for i in range(lo, hi):
            if live[i]:
                envs[i]._advance()

    def _physics(self, live: np.ndarray) -> None:
        """One control period of every live world: serially, or one contiguous chunk of worlds per thread."""
        if self._pool is None:
            self._advance_chunk(0, self.num_envs, live)
            return
        futures = [self._pool.submit(self._advance_chunk, a, b, live) for a, b in self._chunks[1:]]
        self._advance_chunk(*self._chunks[0], live)  # this thread takes the first chunk instead of waiting
        for f in futures:
            f.result()  # re-raises a world's exception here

    # ------------------------------------------------------------------ API
    def _seeds(self, seed) -> list:
        if seed is None:
            return [None] * self.num_envs
        if isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
            return [int(seed) + i for i in range(self.num_envs)]
        seeds = list(seed)
        if len(seeds) != self.num_envs:
            raise ValueError(f"seed must be an int, None or a list of {self.num_envs} seeds, got {len(seeds)}")
        return seeds

    def reset(self, *, seed: int | Sequence[int | None] | None = None, options: dict | None = None):
        """Reset every world (world i with ``seed + i``); ``options["reset_mask"]`` (bool (N,)) resets only
        those worlds, as Gymnasium's vector envs do."""
        seeds = self._seeds(seed)
        mask = np.ones(self.num_envs, dtype=bool)
        if options and "reset_mask" in options:
            mask = np.asarray(options["reset_mask"], dtype=bool)
            if mask.shape != (self.num_envs,):
                raise ValueError(f"options['reset_mask'] must be a bool array of shape ({self.num_envs},)")
            options = {k: v for k, v in options.items() if k != "reset_mask"}
            if not self._started and not mask.all():
                raise ResetNeeded("the first reset() must reset every world (no reset_mask)")
        super().reset(seed=seed if isinstance(seed, (int, np.integer)) else None)
        obs = list(self._last_obs) if self._started else [None] * self.num_envs
        infos = [{} for _ in range(self.num_envs)]
        for i in np.flatnonzero(mask):
            obs[i], infos[i] = self.envs[i].reset(seed=seeds[i], options=options)
            self._autoreset[i] = False
        self._started = True
        self._last_obs = obs
        return self._stack(obs), self._merge_infos(infos, mask)

    def check_actions(self, actions) -> np.ndarray:
        """The batch of actions as float64 (N, action_dim), or a ``ValueError`` naming the env index."""
        n, shape = self.num_envs, self._act_shape
        try:
            arr = np.asarray(actions)
        except (ValueError, TypeError) as exc:
            raise ValueError(f"actions must be an array of shape ({n}, {', '.join(map(str, shape))}), got "
                             f"{type(actions).__name__} that is not a regular array: {exc}") from None
        if arr.shape != (n,) + shape:
            raise ValueError(f"actions must have shape {(n,) + shape} (one row per env), got {arr.shape}")
        if arr.dtype.kind not in "fiu":
            raise ValueError(f"actions must hold real numbers (a float or integer dtype), got dtype {arr.dtype}")
        arr = arr.astype(np.float64)
        if not np.isfinite(arr).all():
            for i in range(n):
                try:
                    check_action(arr[i], shape)
                except ValueError as exc:
                    raise ValueError(f"env {i}: {exc}") from None
        return arr

    def step(self, actions):
        obs, rew, term, trunc, infos = self._step_core(actions)
        return self._stack(obs), rew, term, trunc, self._merge_infos(infos)

    def step_worlds(self, actions):
        """One step, returned per world for adapters (SB3): stacked observations, rewards, terminated,
        truncated, and the list of the worlds' own info dicts. Same autoreset rule as ``step``."""
        obs, rew, term, trunc, infos = self._step_core(actions)
        return self._stack(obs), rew, term, trunc, infos

    def _step_core(self, actions):
        acts = self.check_actions(actions)  # before anything changes: a bad batch steps no world
        if not self._started:
            raise ResetNeeded("step() called before the first reset(); call reset() to start the episodes")
        envs = self.envs
        resetting = self._autoreset
        live = ~resetting
        for i in np.flatnonzero(live):
            envs[i]._begin_step(acts[i])
        self._physics(live)
        n = self.num_envs
        obs, infos = [None] * n, [None] * n
        rew = np.zeros(n)
        term = np.zeros(n, dtype=bool)
        trunc = np.zeros(n, dtype=bool)
        same_step = self.autoreset_mode == AutoresetMode.SAME_STEP
        for i in range(n):
            e = envs[i]
            if resetting[i]:
                obs[i], infos[i] = e.reset()
                continue
            obs[i], rew[i], term[i], trunc[i], infos[i] = e._finish_step()
            if same_step and (term[i] or trunc[i]):
                final_obs, final_info = obs[i], infos[i]
                obs[i], infos[i] = e.reset()
                infos[i] = dict(infos[i], final_obs=final_obs, final_info=final_info)
        self._autoreset = (term | trunc) if not same_step else np.zeros(n, dtype=bool)
        self._last_obs = obs
        return obs, rew, term, trunc, infos

    # ------------------------------------------------------------------ batching
    def _stack(self, obs: list):
        if self._dict_obs:
            return {k: np.stack([o[k] for o in obs]) for k in self.single_observation_space.spaces}
        return np.stack(obs)

    def _merge_infos(self, infos: list[dict], mask: np.ndarray | None = None) -> dict:
        """Gymnasium's vector info: each key an array over worlds, with a bool mask ``_key`` of the worlds that
        have it. Keys every world has (the common case) are stacked at once; the rest go through ``_add_info``."""
        out: dict[str, Any] = {}
        n = self.num_envs
        present = [i for i in range(n) if mask is None or mask[i]]
        if not present:
            return out
        keys0 = infos[present[0]].keys()
        uniform = all(infos[i].keys() == keys0 for i in present)
        stacked: set = set()
        if len(present) == n:
            common = set(keys0)
            if not uniform:
                for i in present[1:]:
                    common &= infos[i].keys()
            for k in keys0:
                if k not in common or k in ("final_obs", "final_info"):
                    continue
                vals = [d[k] for d in infos]
                v0 = vals[0]
                if isinstance(v0, (bool, np.bool_)):
                    out[k] = np.array(vals, dtype=bool)
                elif isinstance(v0, (int, float, np.number)):
                    out[k] = np.array(vals, dtype=type(v0))
                elif isinstance(v0, np.ndarray):
                    out[k] = np.stack(vals)
                else:
                    continue
                out[f"_{k}"] = np.ones(n, dtype=bool)
                stacked.add(k)
        if uniform and len(stacked) == len(keys0):
            return out
        for i in present:
            rest = {k: v for k, v in infos[i].items() if k not in stacked}
            if rest:
                out = self._add_info(out, rest, i)
        return out

    # ------------------------------------------------------------------ rendering, closing, pickling
    def render(self, env_index: int | None = None):
        """rgb_array frames of every world (a tuple, as Gymnasium's SyncVectorEnv), or of world ``env_index``."""
        if env_index is not None:
            if not 0 <= int(env_index) < self.num_envs:
                raise ValueError(f"env_index must be in [0, {self.num_envs - 1}], got {env_index}")
            return self.envs[int(env_index)].render()
        return tuple(e.render() for e in self.envs)

    def call(self, name: str, *args, **kwargs) -> tuple:
        """``getattr(world, name)(*args, **kwargs)`` (or the attribute) of every world, as SyncVectorEnv."""
        out = []
        for e in self.envs:
            f = getattr(e, name)
            out.append(f(*args, **kwargs) if callable(f) else f)
        return tuple(out)

    def get_attr(self, name: str) -> tuple:
        return tuple(getattr(e, name) for e in self.envs)

    def set_attr(self, name: str, values) -> None:
        if not isinstance(values, (list, tuple)):
            values = [values] * self.num_envs
        for e, v in zip(self.envs, values):
            setattr(e, name, v)

    def close_extras(self, **kwargs) -> None:
        self._close_pool()
        for e in self.envs:
            e.close()

    def __getstate__(self):
        state = dict(self.__dict__)
        state["_pool"] = None
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self.set_threads(self.threads)

    def __repr__(self) -> str:
        return f"VSWristVectorEnv({self.env_id}, num_envs={self.num_envs}, threads={self.threads})"


def _vector_entry(env_id: str):
    def make(num_envs: int = 1, **kwargs) -> VSWristVectorEnv:
        return VSWristVectorEnv(env_id, num_envs, **kwargs)

    make.__doc__ = f"``gym.make_vec({env_id!r}, num_envs, vectorization_mode='vector_entry_point', ...)``"
    return make


def _register_entries() -> None:
    from .. import ENV_IDS, vector_entry_name

    for env_id in ENV_IDS:
        globals()[vector_entry_name(env_id)] = _vector_entry(env_id)


_register_entries()
