"""N VS-Wrist worlds behind one ``gymnasium.vector.VectorEnv`` (``gym.make_vec(id, N)``), physics on threads.

Each world is a task environment (its own MjModel/MjData, so domain randomisation that rebuilds a world's model
works per world). One ``step`` of the batch:

1. every action row is checked first (shape ``(N, action_dim)``, real and finite; else ``ValueError`` naming the
   env index), so a bad batch changes nothing;
2. worlds that ended on the previous step are reset (``autoreset_mode`` NEXT_STEP, the default) or, with
   SAME_STEP, right after the step that ended them; the worlds that reset at a step begin their episodes together
   (``VSWristEnv._reset_begin_worlds``: the kinematics of all their initial postures in one pass) and settle (the
   reset's physics) on a thread pool meanwhile;
3. before the physics: the array step's ``_begin`` (``batch_step``: actions, the controller over arrays, the
   task's loads);
4. the physics of all worlds, one control period each, on threads (``batch_physics``);
5. after the physics: the array step's ``_finish`` (``batch_step``: the simulators' reads, the task hooks world by
   world, and the observation, the reward and the info over arrays with the single env's own functions), so that
   world i of a batch is the single env with seed s + i (``tests/test_batch.py``); the infos as Gymnasium's vector
   info (``vector_info``).

Modules: this one (the ``VectorEnv``: construction, threads, resets, the step's order, rendering, pickling),
``batch_step`` (the step's phases over arrays), ``batch_physics`` (the physics on threads) and ``vector_info``.

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

from ..batch_sim import BatchSim
from .actions import check_actions
from .base import VSWristEnv
from .batch_physics import PhysicsMixin
from .batch_step import STEP_METHODS, ArrayStepMixin
from .episode import share
from .hooks import over_arrays
from .shared import PeriodMeanForce
from .vector_info import VectorInfoMixin

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


class VSWristVectorEnv(PhysicsMixin, ArrayStepMixin, VectorInfoMixin, VectorEnv):
    """``num_envs`` worlds of one task (``env_id``), stepped together; see the module docstring.

    ``config``/``overrides``: as for ``gym.make`` (the same for every world). ``threads``: physics threads
    (default: the cores available; 1 = serial). ``autoreset_mode``: NEXT_STEP (Gymnasium's default),
    SAME_STEP (the reset observation is returned at once, the last one in ``info["final_obs"]``) or DISABLED
    (a world that ended stays ended until ``reset(options={"reset_mask": mask})`` restarts it; stepping it
    before raises). After ``close()``, ``step`` and ``reset`` raise ``ClosedEnvironmentError``.
    """

    def __init__(self, env_id: str, num_envs: int = 1, render_mode: str | None = None,
                 config: Mapping[str, Any] | None = None, threads: int | None = None,
                 autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP, max_episode_steps: int | None = None,
                 **overrides: Any):
        if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
            raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}")
        self.autoreset_mode = AutoresetMode(autoreset_mode)
        cls = _env_class(env_id)
        overridden = [m for m in STEP_METHODS if getattr(cls, m) is not getattr(VSWristEnv, m)]
        if overridden:
            raise TypeError(f"{cls.__name__} overrides {', '.join(overridden)}: a batch steps the base class's "
                            f"step methods over arrays and would not run the override; change the step through "
                            f"the task hooks (_before_physics, _contact_force, _task_reward_terms, _task_info, "
                            f"task observation terms) instead")
        self.env_id = env_id
        self.num_envs = int(num_envs)
        spec = gym.registry[env_id]
        # the id's registered kwargs (an older version's id_config), as gym.make(env_id) passes them; make_vec
        # already merged them into overrides, a direct construction did not
        kwargs = {**spec.kwargs, **overrides}
        self.envs = [cls(render_mode=render_mode, config=config, **kwargs) for _ in range(self.num_envs)]
        for e in self.envs:
            e.spec = spec
        # every world's episode state as one structure of (N,) arrays, each world's its row (``episode.share``)
        self._ep = share(self.envs)
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
        # what the array step needs to know of the task (the same for every world)
        cls = type(first)
        self._mode = first.cfg["action_mode"]
        # the hooks the task writes, in either form (``hooks``): the array step calls their form over arrays
        self._hook_before, self._hook_contact, self._hook_reward, self._hook_info = (
            getattr(cls, h) is not getattr(VSWristEnv, h) or over_arrays(cls, f"{h}_worlds")
            for h in ("_before_physics", "_contact_force", "_task_reward_terms", "_task_info"))
        self._obs_size = first.obs_size
        self._obs_names = [t.name for t in first.obs_terms]
        self._obs_slices = dict(first.obs_slices)
        # "c" (compiled per-substep springs and motors) or "python" (the reference callbacks: no threads)
        self.backend = getattr(first.sim, "backend", "c")
        # The compiled advance (``BatchSim``): one GIL-free call per chunk of worlds, for tasks whose
        # physics is the base class's, the contact meter's plugin path or a watch of every substep that the
        # compiled advance runs (``_watch_worlds``: Throw's release); else ``_advance`` world by world.
        self._watch = over_arrays(cls, "_watch_worlds")
        standard = cls._advance is VSWristEnv._advance and (self._watch or cls._advance_physics in (
            VSWristEnv._advance_physics, PeriodMeanForce._advance_physics))
        self._meter_task = issubclass(cls, PeriodMeanForce)
        self.batch_sim = BatchSim(self.num_envs, first.sim, first.ctrl_dt, first._light_sync,
                                  "tool_wrench" in first.cfg["observation"], self._meter_task,
                                  compiled=self.backend == "c" and standard, watch=self._watch)
        # CPU seconds inside the worlds' mj_step substeps (the compiled path), summed while not None (benchmarks)
        self.physics_seconds: float | None = None
        self.set_threads(threads)

    # ------------------------------------------------------------------ threads
    def set_threads(self, threads: int | None) -> None:
        """Physics threads (None: the cores available). With the Python reference callbacks: always 1."""
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
        # n workers: with the compiled advance the calling thread computes rewards and observations meanwhile
        self._pool = ThreadPoolExecutor(max_workers=n, thread_name_prefix="vswrist-physics") if n > 1 else None

    def _close_pool(self) -> None:
        pool = getattr(self, "_pool", None)
        if pool is not None:
            pool.shutdown(wait=True)
        self._pool = None
        bsim = getattr(self, "batch_sim", None)
        if bsim is not None:
            bsim.close()

    # ------------------------------------------------------------------ resets, settled on the threads
    def _start_resets(self, worlds: list, started: dict, seeds: list | None = None) -> None:
        """Begin the resets of ``worlds`` (with ``seeds[i]``, or none: their generators go on) and settle
        them: on the pool, beside whatever runs next, or at once without threads. ``started``: world ->
        its settling's future (None: settled), for ``_end_reset``."""
        if not worlds:
            return
        pool = self._pool
        ws = [self.envs[i] for i in worlds]
        cls = type(ws[0])
        cls._reset_begin_worlds(ws, [None if seeds is None else seeds[i] for i in worlds])
        for i, e in zip(worlds, ws):
            if pool is None:
                e._settle()
                started[i] = None
            else:
                started[i] = pool.submit(e._settle)
        cls._reset_worlds(ws)  # the task's set-up over the worlds that reset together, beside their settling

    def _end_reset(self, i: int, started: dict):
        """World i's reset, begun by ``_start_resets``: waits for its settling, then the single env's last
        phase. Returns (observation, info)."""
        f = started.pop(i)
        if f is not None:
            f.result()  # re-raises the settling's exception here
        out = self.envs[i]._reset_finish()
        self._attach([i])
        return out

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
        self._check_open("reset")
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
        obs = self._last_obs.copy() if self._started else np.zeros((self.num_envs, self._obs_size), np.float32)
        infos = [{} for _ in range(self.num_envs)]
        chosen = np.flatnonzero(mask).tolist()
        started: dict = {}
        self._start_resets(chosen, started, seeds)
        for i in chosen:
            o, infos[i] = self._end_reset(i, started)
            obs[i] = self._flat(o)
            self._autoreset[i] = False
        self._started = True
        self._last_obs = obs
        return self._unflat(obs), self._merge_infos(infos, mask)

    def check_actions(self, actions) -> np.ndarray:
        """The batch of actions as float64 (N, action_dim), or a ``ValueError`` naming the env index."""
        return check_actions(actions, self.num_envs, self._act_shape)

    def step(self, actions):
        obs, rew, term, trunc, (cols, rows, extras) = self._step_core(actions)
        return self._unflat(obs), rew, term, trunc, self._vector_info(cols, rows, extras)

    def step_worlds(self, actions):
        """One step, returned per world for adapters (SB3): stacked observations, rewards, terminated,
        truncated, and the list of the worlds' own info dicts. Same autoreset rule as ``step``."""
        obs, rew, term, trunc, (cols, rows, extras) = self._step_core(actions)
        return self._unflat(obs), rew, term, trunc, self._world_infos(cols, rows, extras)

    def _step_core(self, actions):
        """Returns the flat observations (N, obs_size), rewards, terminated, truncated and the infos as
        (cols, rows, extras): ``cols`` = (world indices, {key: array over those worlds}), ``rows`` = {world: its
        whole info dict} (worlds reset in this step), ``extras`` = {world: more keys} (a divergence's message)."""
        self._check_open("step")
        acts = self.check_actions(actions)  # before anything changes: a bad batch steps no world
        if not self._started:
            raise ResetNeeded("step() called before the first reset() (or after a step raised inside a task's "
                              "code); call reset() to start the episodes")
        if self.autoreset_mode == AutoresetMode.DISABLED and self._autoreset.any():
            ended = np.flatnonzero(self._autoreset).tolist()
            raise ResetNeeded(f"worlds {ended} ended their episodes and autoreset_mode is DISABLED: reset them "
                              f"first with reset(options={{'reset_mask': mask}})")
        envs = self.envs
        n = self.num_envs
        resetting = self._autoreset
        live = ~resetting
        ids = np.flatnonzero(live)
        idx = ids.tolist()
        worlds = [envs[i] for i in idx]
        same_step = self.autoreset_mode == AutoresetMode.SAME_STEP
        # resets begun, settling on the pool beside the physics: the worlds that ended on the last step (NEXT_STEP)
        # or, with the compiled advance, those that end in a chunk already finished (SAME_STEP)
        started: dict = {}
        reset_now = np.flatnonzero(resetting).tolist()
        native = bool(worlds) and self._native_ready(idx)
        if not native:
            self._start_resets(reset_now, started)
        if worlds and not native:
            self._begin(worlds, ids, acts[idx])
        finished = None
        if native:  # the array step's _begin, then the physics, beside which the resets begin
            finished = self._native_step(worlds, idx, acts[idx], started if same_step else None,
                                         lambda: self._start_resets(reset_now, started))
        else:
            self._physics(live)
        obs = np.empty((n, self._obs_size), dtype=np.float32)
        rew = np.zeros(n)
        term = np.zeros(n, dtype=bool)
        trunc = np.zeros(n, dtype=bool)
        rows: dict[int, dict] = {}
        extras: dict[int, dict] = {}
        cols: dict[str, np.ndarray] = {}
        if worlds:
            o, r, te, tr, cols, failures = finished if finished is not None else self._finish(worlds, ids)
            obs[idx], rew[idx], term[idx], trunc[idx] = o, r, te, tr
            for k, msg in failures.items():
                extras[idx[k]] = {"simulation_error": msg}
        for i in reset_now:
            o, rows[i] = self._end_reset(i, started)
            obs[i] = self._flat(o)
        if same_step:
            done = np.flatnonzero(term | trunc).tolist()
            if done:
                self._start_resets([i for i in done if i not in started], started)
                pos = {i: k for k, i in enumerate(idx)}
                for i in done:
                    k = pos[i]
                    final_info = {key: (v[k].item() if v.ndim == 1 else v[k]) for key, v in cols.items()}
                    final_info.update(extras.pop(i, {}))
                    final_obs = self._unflat(obs[i].copy())
                    o, info = self._end_reset(i, started)
                    obs[i] = self._flat(o)
                    rows[i] = dict(info, final_obs=final_obs, final_info=final_info)
            self._autoreset = np.zeros(n, dtype=bool)
        else:
            self._autoreset = term | trunc
        self._last_obs = obs
        return obs, rew, term, trunc, ((idx, cols), rows, extras)

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

    def _check_open(self, what: str) -> None:
        if self.closed:
            from gymnasium.error import ClosedEnvironmentError

            raise ClosedEnvironmentError(f"{what}() on a closed {self!r}: make a new one")

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
        self._ep = share(self.envs)  # the worlds' rows came back as arrays of their own
        self._attach(range(self.num_envs))
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
