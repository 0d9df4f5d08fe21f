"""N VS-Wrist worlds behind one ``gymnasium.vector.VectorEnv`` (``gym.make_vec(id, N)``), physics on threads.

Each world is a task environment (its own MjModel/MjData, so domain randomisation that rebuilds a world's model
works per world). One ``step`` of the batch:

1. every action row is checked first (shape ``(N, action_dim)``, real and finite; else ``ValueError`` naming the
   env index), so a bad batch changes nothing;
2. worlds that ended on the previous step are reset (``autoreset_mode`` NEXT_STEP, the default) or, with
   SAME_STEP, right after the step that ended them;
3. before the physics: action clipping and maps, and the analytic controller (modes ``posture_stiffness`` and
   ``residual``: ``AnalyticController.step_batch``) over arrays of worlds; the compliance mode's LM dynamics
   and the ``motor`` mode world by world; then the task's loads, ``_before_physics_worlds`` (over arrays of
   worlds where the task writes them so: Drill, LoadHold; else each world's ``_before_physics``);
4. the physics of all worlds: one control period each, through the batch simulator (``batch_sim.BatchSim``, the compiled
   advance: per world, what ``_advance`` does through ``WristSim``, in one GIL-free C++ call per chunk of worlds). On
   ``threads`` threads, up to ``CHUNKS_PER_THREAD`` chunks per thread (of at least ``MIN_CHUNK_WORLDS`` worlds) are
   stepped by the library's ``threads - 1`` threads and by the calling thread: step 3 of the other chunks runs beside
   the first chunks' physics, and step 5 of most chunks beside the last ones' (``_native_step``), so the Python of some
   worlds runs beside the physics of others. The compiled plugins (``model.native``: springs and motors, the
   loop-closure monitor, and Polish's and Hammer's per-substep contact meter ``vswrist.contact``) keep no global mutable
   state (theirs lives in each MjData's ``plugin_data``/``plugin_state``), and every world has its own MjModel, so
   worlds advance in parallel; no task steps substep by substep from Python. The worlds that reset at this step begin
   their episodes together (``VSWristEnv._reset_begin_worlds``: the kinematics of all their initial postures in one
   pass) and settle (the reset's physics) on a thread pool meanwhile. Actuation latency (its first substeps on the
   previous references) runs inside the compiled call too. Without a C++ compiler each world runs ``_advance`` (the
   bindings' ``mj_step``, which releases the GIL) on a pool of ``threads`` threads; with the Python fallback callbacks
   (no C compiler) each substep re-enters Python, so threads would only contend for the GIL: the batch then steps
   serially;
5. after the physics: every world's simulator is read (posture, deflections, rates, loop closure, the tool wrench: what
   ``batch_sim.gather_plan`` names, copied into one (N, .) array by the compiled advance on the physics threads, or in
   Python without it, and computed over arrays by ``BatchSim``'s reads), its reference (a row of the table its reset
   computed: ``_reference`` is written over arrays of times), its task hooks (``_contact_force``,
   ``_task_reward_terms``, ``_task_info``, task observation terms) and its sensor noise (from its own generator, in the
   single env's order) run world by world; the measures' math, divergence checks, the common reward terms, the
   observation and the info (Gymnasium's vector info: arrays and ``_key`` masks) are computed over arrays, each with the
   single env's operations in the single env's order, so world i of a batch is the single env with seed s + i (to the
   bit on one machine: ``tests/test_batch.py`` checks 1e-9).

Steps 3 and 5 are ``VSWristEnv._begin_step``/``_finish_step`` written over arrays (the "array step"), for every
batch, one world or many; a task may change the step through its hooks, not by overriding one of the
``STEP_METHODS`` the array step implements (such a task is refused when its batch is made). The single env
keeps its scalar step (``gym.make``): the same numbers, and faster for one world.

Seeding follows Gymnasium: ``reset(seed=s)`` seeds world i with ``s + i`` (a list gives one seed per world), so
world i replays ``gym.make(id).reset(seed=s + i)`` step for step (``tests/test_batch.py``).
"""

from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Mapping, Sequence

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium.error import ResetNeeded
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from ..batch_sim import DIVERGED, OK, BatchSim
from ..sim import DIVERGED_MESSAGE
from ..stiffness import SpringLaw, spring_energy
from .actions import check_action
from .base import VSWristEnv
from .observations import observe
from .rewards import common_reward_terms, step_metrics, weigh, wrap_angle
from .shared import PeriodMeanForce

# chunks of worlds per physics thread in a step (``VSWristVectorEnv._native_step``), each of at least
# MIN_CHUNK_WORLDS worlds: more chunks balance the threads better and shorten the last chunk, whose
# ``_finish`` no physics overlaps; fewer make the first chunk, whose ``_begin`` no physics overlaps, longer to
# compute beside
CHUNKS_PER_THREAD = 4
MIN_CHUNK_WORLDS = 4
# the single env's step methods that the array step computes over arrays (a batch of a task overriding one is
# refused: the batch would not run the override); the hooks it calls per world, or over arrays
# (``_tracking_error``), stay the task's
STEP_METHODS = ("_begin_step", "_finish_step", "_motor_refs", "_measure", "_reward", "_info", "_observation",
                "_draw_noise", "_obs_terms")


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


class BatchMeasures:
    """``observations.observe``'s measures of a batch's live worlds after a step: (N, ...) arrays, and the reads
    of their simulators over arrays from the gathered rows ``G`` (``BatchSim``'s reads)."""

    __slots__ = ("worlds", "bsim", "G", "posture", "deflections", "Q", "law", "contact", "lam", "prev_action",
                 "target", "step", "noise")

    def __init__(self, worlds, bsim, G, P, D, Q, law, contact, lam, prev_action, target, step, noise):
        self.worlds, self.bsim, self.G, self.Q = worlds, bsim, G, Q
        self.posture, self.deflections, self.law, self.contact = P, D, law, contact
        self.lam, self.prev_action, self.target, self.step, self.noise = lam, prev_action, target, step, noise

    def posture_rate(self) -> np.ndarray:
        return self.bsim.read_posture_rate(self.G, self.posture)

    def motor_angles(self) -> np.ndarray:
        return self.bsim.read_motor_angles(self.Q)

    def tool_wrench(self) -> np.ndarray:
        return self.bsim.read_tool_wrench(self.G)

    def jacobian(self) -> np.ndarray:
        # every world's controller has the nominal parameters (randomisation rebuilds the simulator only)
        P = self.posture
        _, (J0, J1), _, _ = self.worlds[0].ctrl.posture_kinematics_batch(P[:, 0], P[:, 1], with_q1=False)
        return np.stack([J0.T, J1.T], axis=-1)

    def task_term(self, term) -> np.ndarray:
        """A task's own term, world by world (it reads each world's state)."""
        name, L = term.name, len(self.worlds)
        return np.array([e._terms[name].fn() for e in self.worlds], dtype=float).reshape(L, term.size)


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
        self._hook_before = (cls._before_physics is not VSWristEnv._before_physics
                             or cls._before_physics_worlds.__func__ is not VSWristEnv._before_physics_worlds.__func__)
        self._hook_contact = cls._contact_force is not VSWristEnv._contact_force
        self._hook_reward = cls._task_reward_terms is not VSWristEnv._task_reward_terms
        self._hook_info = cls._task_info is not VSWristEnv._task_info
        self._obs_size = first.obs_size
        self._obs_names = [t.name for t in first.obs_terms]
        self._obs_slices = dict(first.obs_slices)
        # "c" (compiled per-substep springs and motors) or "python" (the fallback callbacks: no threads)
        self.backend = getattr(first.sim, "backend", "c")
        # The compiled advance (``BatchSim``): one GIL-free call per chunk of worlds, for tasks whose
        # physics is the base class's (or the contact meter's plugin path); else ``_advance`` world by world.
        standard = cls._advance is VSWristEnv._advance and cls._advance_physics in (
            VSWristEnv._advance_physics, PeriodMeanForce._advance_physics)
        self._meter_task = issubclass(cls, PeriodMeanForce)
        self.batch_sim = BatchSim(self.num_envs, first.sim, first.ctrl_dt, first._light_sync,
                                  "tool_wrench" in first.cfg["observation"], self._meter_task,
                                  compiled=self.backend == "c" and standard)
        # CPU seconds inside the worlds' mj_step substeps (the compiled path), summed while not None (benchmarks)
        self.physics_seconds: float | None = None
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

    # ------------------------------------------------------------------ the compiled advance
    def _attach(self, worlds) -> None:
        """The batch simulator's handles of ``worlds`` (after a reset: randomisation may rebuild a simulator)."""
        bsim, meter_task = self.batch_sim, self._meter_task
        for i in worlds:
            e = self.envs[i]
            bsim.attach(i, e.sim, e.ctrl_dt, getattr(e, "_meter", None) if meter_task else None)

    def _native_ready(self, idx: list) -> bool:
        """Whether the compiled advance steps the worlds ``idx`` this period (handles refreshed if stale)."""
        bsim, envs = self.batch_sim, self.envs
        if bsim.lib is None:
            return False
        stale = [i for i in idx if not bsim.attached(i, envs[i].sim)]
        if stale:
            self._attach(stale)
        if not bsim.steps(idx):
            return False
        # actuation latency (drawn at each reset): the first period after a reset has no previous references
        lat = [e._latency for e in (envs[i] for i in idx)]
        if any(lat):
            bsim.set_latency(idx, [int(round(x / envs[i].sim.timestep)) if x > 0.0 and envs[i]._theta_prev is not None
                                   else 0 for i, x in zip(idx, lat)])
        else:
            bsim.set_latency(idx, 0)
        return True

    def _after_native(self, worlds: list, idx: list, status: np.ndarray) -> None:
        """What ``_advance`` leaves on each world and its simulator, from the compiled call's status."""
        meter = self._meter_task
        for e, i, st in zip(worlds, idx, self.batch_sim.settle([e.sim for e in worlds], status)):
            if meter:
                e._period_ran = True
            if st == OK:
                e._failure = None
            elif st == DIVERGED:
                e._failure = DIVERGED_MESSAGE
            else:
                raise mujoco.FatalError(f"env {i}: MuJoCo raised an error inside this world's physics step")

    def _native_step(self, worlds: list, idx: list, acts: np.ndarray, started: dict | None = None, meanwhile=None):
        """The array step's ``_begin`` and the physics of the live worlds through the compiled advance
        (``acts``: their checked actions). On one
        thread: ``_begin``, one call, ``_finish``. On ``threads`` threads: up to ``CHUNKS_PER_THREAD`` x threads
        chunks of worlds, stepped by the library's ``threads - 1`` threads and by this one:

        * ``_begin`` of the first chunk of each pool thread, which starts it; then, while those chunks' physics
          runs, ``_begin`` of the others, which are then released to the pool (``BatchSim.pool``):
          the Python before the physics is one chunk's, not the batch's. Should that second ``_begin`` raise (a
          task hook's bug: the actions were checked before), the first chunks have stepped and the others have
          not, so the batch then needs a ``reset()`` (``ResetNeeded`` otherwise) rather than going on from a
          half-stepped state;
        * this thread steps chunks while more than one per pool thread is left to claim, and only then
          computes the rewards and observations (``_finish``) of the chunks done, in one call while the pool
          steps the last ones, then of those: each ``_finish`` call has a fixed cost (its array calls) that many
          small calls would pay many times over.

        Each world's numbers depend on that world only, so the chunks' results are joined in world order.
        Returns ``_finish``'s results.
        ``started``: with SAME_STEP autoresets, the resets begun (``_start_resets``) of the worlds a finished
        chunk ended, whose settling then runs beside the physics still to come. ``meanwhile()``: Python to run
        while the physics starts (the worlds that reset at this step)."""
        L = len(idx)
        widx = np.asarray(idx, dtype=np.int32)
        status = np.zeros(L, dtype=np.int32)
        seconds = None if self.physics_seconds is None else np.zeros(L)
        bsim = self.batch_sim
        G = np.empty((L, bsim.width))  # the gathered reads (``batch_sim.gather_plan``)
        parts: list = []  # (positions in idx, _finish's results for those worlds)
        A = None  # the clipped actions, once ``_begin`` has run for every world

        def finish(pos: list) -> None:
            ws = [worlds[p] for p in pos]
            self._after_native(ws, [idx[p] for p in pos], status[pos])
            part = self._finish(ws, A[pos], G[pos])
            parts.append((pos, part))
            if started is not None and self._pool is not None:  # SAME_STEP: the ended worlds reset now
                self._start_resets([idx[pos[j]] for j in np.flatnonzero(part[2] | part[3]).tolist()], started)

        def begin(lo: int, hi: int) -> tuple[np.ndarray | None, np.ndarray]:
            """``_begin`` of live worlds lo..hi-1: their clipped actions and motor references (hi - lo, 4)."""
            ws, ids = worlds[lo:hi], idx[lo:hi]
            a, theta = self._begin(ws, acts[lo:hi])
            return a, self._motor_matrix(ws, ids, theta)

        k = min(CHUNKS_PER_THREAD * self.threads, L // MIN_CHUNK_WORLDS)
        if self.threads == 1 or k < 2:
            A, TH = begin(0, L)
            if meanwhile is not None:
                meanwhile()
            bsim.advance(widx, TH, status, seconds, G)
            finish(list(range(L)))
        else:
            bounds = np.linspace(0, L, k + 1).round().astype(np.int32)
            head = int(bounds[self.threads - 1])  # one chunk for each pool thread
            A1, TH1 = begin(0, head)
            TH = np.empty((L, 4))
            TH[:head] = TH1
            pool = bsim.pool(self.threads - 1)
            bsim.submit(pool, widx, TH, status, seconds, bounds, self.threads - 1, G)
            todo = np.ones(k, dtype=bool)
            try:
                if meanwhile is not None:
                    meanwhile()
                try:
                    A2, TH[head:] = begin(head, L)
                except BaseException:
                    self._started = False  # the first chunks stepped, the others did not: reset() first
                    raise
                A = np.concatenate([A1, A2])
                pool.release()
                # the last unclaimed chunk of each pool thread stays for it, so that the first _finish (most of
                # the worlds) runs beside physics
                keep = self.threads - 1
                while todo.any():
                    if pool.run_one(keep) >= 0:  # step chunks while more than `keep` are left to claim
                        continue
                    ready = pool.ready() & todo
                    if ready.any():
                        chunks = np.flatnonzero(ready).tolist()
                        todo[chunks] = False
                        finish([p for c in chunks for p in range(int(bounds[c]), int(bounds[c + 1]))])
                    elif pool.run_one() < 0:  # nothing done yet: step a kept chunk, else wait for one
                        pool.wait(int(np.flatnonzero(todo)[0]))
            finally:
                pool.wait()  # no thread touches a world after we return
        if seconds is not None:
            self.physics_seconds += float(seconds.sum())
        if len(parts) == 1:
            return parts[0][1]
        order = np.concatenate([np.asarray(pos) for pos, _ in parts])
        inv = np.empty(L, dtype=np.intp)
        inv[order] = np.arange(L)

        def join(j: int) -> np.ndarray:
            return np.concatenate([p[j] for _, p in parts])[inv]

        failures = {pos[j]: msg for pos, p in parts for j, msg in p[5].items()}
        return (join(0), join(1), join(2), join(3),
                {key: np.concatenate([p[4][key] for _, p in parts])[inv] for key in parts[0][1][4]}, failures)

    @staticmethod
    def _motor_matrix(worlds: list, idx: list, theta: np.ndarray | None) -> np.ndarray:
        """The live worlds' motor references (L, 4), float64 C-contiguous, checked finite as
        ``WristSim.set_motor_references`` checks them."""
        TH = np.ascontiguousarray(theta if theta is not None else [e._theta for e in worlds], dtype=np.float64)
        if not np.isfinite(TH).all():
            k = int(np.flatnonzero(~np.isfinite(TH).all(axis=1))[0])
            raise ValueError(f"env {idx[k]}: motor references must be 4 finite angles in rad (A, B, C, PS), got "
                             f"{TH[k]!r}")
        return TH

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
        idx = np.flatnonzero(live).tolist()
        worlds = [envs[i] for i in idx]
        same_step = self.autoreset_mode == AutoresetMode.SAME_STEP
        # resets begun, settling on the pool beside the physics: the worlds that ended on the last step (NEXT_STEP)
        # or, with the compiled advance, those that end in a chunk already finished (SAME_STEP)
        started: dict = {}
        reset_now = np.flatnonzero(resetting).tolist()
        native = bool(worlds) and self._native_ready(idx)
        if not native:
            self._start_resets(reset_now, started)
        A = None
        if worlds and not native:
            A, theta = self._begin(worlds, acts[idx])
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
            o, r, te, tr, cols, failures = finished if finished is not None else self._finish(worlds, A)
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

    # ------------------------------------------------------------------ the step's phases over arrays
    def _begin(self, worlds: list, acts: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """Action -> controller -> motor references of the live worlds (``VSWristEnv._begin_step``, over
        arrays where the mode runs the controller with a commanded lam); returns the clipped actions and the
        motor references (L, 4) where the controller computed them over arrays (else None)."""
        A = np.maximum(acts, -1.0)
        np.minimum(A, 1.0, out=A)
        first = worlds[0]
        mode = self._mode
        if mode in ("posture_stiffness", "residual"):
            if mode == "posture_stiffness":
                ref, s = first.posture_map.to_posture(A[:, :3]), A[:, 3]
            else:
                r = first.cfg["residual"]
                target = np.array([e._target for e in worlds])
                ref = first.posture_map.clip(target + r["posture_scale"] * A[:, :3])
                s = r["stiffness_nominal"] + r["stiffness_scale"] * A[:, 3]
            # every world's controller has the nominal parameters (randomisation rebuilds the simulator only)
            theta, lam, u = first.ctrl.step_batch(ref, first.stiffness_map.to_lam_batch(s))
            for e, a, th, (ay, az, ps), lam_k in zip(worlds, A, theta, u.tolist(), lam.tolist()):
                c = e.ctrl
                c._u, c._ps, c.lam = (ay, az), ps, lam_k
                e._a, e._theta = a, th
        else:  # motor (no controller) and posture_compliance (LM dynamics per world)
            theta = None
            for e, a in zip(worlds, A):
                e._a, e._theta = a, e._motor_refs(a)
        if self._hook_before:
            type(first)._before_physics_worlds(worlds, np.array([e._t for e in worlds]))
        return A, theta

    def _finish(self, worlds: list, A: np.ndarray, G: np.ndarray | None = None):
        """``VSWristEnv._finish_step`` of the live worlds: the simulators' reads come gathered in ``G`` (rows of
        ``batch_sim.gather_plan``, filled by the compiled advance; None: gathered here), the task hooks run world by
        world (in the single env's order, so each draws its noise from its own generator as it would alone);
        the measures' math, rewards, observation and info run over arrays."""
        first = worlds[0]
        L = len(worlds)
        dt = first.ctrl_dt
        light = first._light_sync
        bsim = self.batch_sim
        noise = first._noise_std is not None
        failed = [e._failure for e in worlds]
        hook_contact = self._hook_contact
        # world by world, first (the single env's step up to ``_measure``'s contact hook): the step count and
        # time, the task's contact force; and what the arrays below need of each world's state
        contact, K, d0, T, lam, prev, nz_rows, steps = [], [], [], [], [], [], [], []
        for e in worlds:
            e._theta_prev = e._theta
            k = e._step + 1
            e._step = k
            e._t = k * dt
            steps.append(k)
            sp = e.params.spring
            K.append(sp.K)
            d0.append(sp.delta0)
            T.append(e._references[k])
            lam.append(e.ctrl.lam)
            prev.append(e._prev_action)
            if noise:
                nz = e._nz = e._noise[k]  # ``_draw_noise`` (the task's own observation terms may read it)
                nz_rows.append(nz)
            contact.append(e._contact_force() if hook_contact else 0.0)
        sims = [e.sim for e in worlds]
        redo = []
        for k in range(L):
            if failed[k] is not None:  # MuJoCo reset this world's state: bring it up to date as _measure does
                if light:
                    sims[k].sync_kinematics()
                sims[k].posture()
                redo.append(k)
        if G is None:
            G = bsim.gather(sims)
        elif redo:
            G[redo] = bsim.gather([sims[k] for k in redo])
        P, D, Q = bsim.read_posture(G)
        bad = ~(np.isfinite(P).all(axis=1) & np.isfinite(D).all(axis=1))
        failures: dict[int, str] = {k: failed[k] for k in range(L) if failed[k] is not None}
        for k in np.flatnonzero(bad).tolist():
            if k not in failures:
                failures[k] = f"non-finite state at t = {worlds[k]._t:.3f} s"
        closure = bsim.read_closure(G, sims)
        for k in failures:
            # as the single env: end the episode from a clean, finite state (MuJoCo reset the diverged one)
            e = worlds[k]
            closure[k] = math.inf
            e.sim.reset()
            e.sim.apply_wrench(np.zeros(3), np.zeros(3))
            e._measure()
            P[k], D[k], contact[k] = e._posture, e._defl, e._contact
            G[k] = bsim.gather([e.sim])[0]  # what the observation reads: the clean state
            Q[k] = bsim.qpos(G[k:k + 1])[0]
        law = SpringLaw(np.array(K)[:, None], np.array(d0)[:, None])  # each world's own springs
        e3 = spring_energy(D, law)
        energy = e3[:, 0] + e3[:, 1] + e3[:, 2]
        T = np.array(T)
        err = wrap_angle(P - T)
        contact_a = np.array(contact)
        closure_a = np.array(closure)
        steps = np.array(steps)
        lam = np.array(lam)
        prev = np.array(prev)
        terminated = np.zeros(L, dtype=bool)
        terminated[list(failures)] = True
        PA = A.astype(np.float32)
        time_up = ~terminated & (steps >= first.episode_steps)
        exceeded = closure_a > first._closure_warn
        cut = ~terminated & exceeded if first._closure_truncate else np.zeros(L, dtype=bool)
        truncated = time_up | cut
        ends = (terminated | truncated).tolist()

        # world by world: the state the single env keeps, the task's reward terms
        hook_reward = self._hook_reward
        task_raw = []
        peak, sumsq = [], []
        Pl, Dl, El = P.tolist(), D.tolist(), energy.tolist()
        for e, p, d, pl, dl, en, c, cl, tg, er, pa, end in zip(worlds, P, D, Pl, Dl, El, contact, closure, T, err,
                                                                PA, ends):
            e._posture, e._defl, e._posture_list, e._defl_list = p, d, pl, dl
            e._energy, e._contact, e._closure, e._target = en, c, cl, tg
            pk = e._peak_contact
            pk = c if c > pk else pk  # = max(pk, c)
            e._peak_contact = pk
            peak.append(pk)
            sq = e._sum_contact_sq + c * c
            e._sum_contact_sq = sq
            sumsq.append(sq)
            h = e._history
            h["error"].append(er)
            h["energy"].append(en)
            h["contact"].append(c)
            if hook_reward:
                task_raw.append(e._task_reward_terms(er))
            e._prev_action = pa
            e._needs_reset = end
        NZ = np.array(nz_rows) if noise else None

        # reward (the single env's terms, over arrays)
        rterms = common_reward_terms(first._tracking_error(err), energy, A, prev, terminated, first.cfg["scales"])
        if hook_reward:
            for name in first.task_reward_terms:
                rterms[name] = np.array([d[name] for d in task_raw])
        cols, reward = weigh(rterms, first.reward_weights)

        # observation (the single env's terms, over arrays)
        obs = observe(first.obs_terms, BatchMeasures(worlds, bsim, G, P, D, Q, law, contact_a, lam, PA, T, steps, NZ),
                      first._obs_low, first._obs_high)

        # info (the single env's metrics, over arrays)
        success = np.zeros(L, dtype=bool)
        for k in np.flatnonzero(time_up & ~cut).tolist():
            success[k] = bool(worlds[k]._success())
        cols.update(step_metrics(err, contact_a, np.array(peak), np.array(sumsq), steps, energy, lam, closure_a,
                                 first._closure_warn, steps * dt, success))
        if self._hook_info:
            extra = [e._task_info() for e in worlds]
            for key in extra[0]:
                cols[key] = np.array([x[key] for x in extra])
        cols["posture_error_vec"] = err
        return obs, reward, terminated, truncated, cols, failures

    # ------------------------------------------------------------------ batching
    def _flat(self, obs) -> np.ndarray:
        """A world's observation as the flat float32 row (a dict observation concatenated in term order)."""
        if self._dict_obs:
            return np.concatenate([obs[name] for name in self._obs_names])
        return obs

    def _unflat(self, flat: np.ndarray):
        """Flat rows (N, obs_size) or one row as the batch's (or a world's) observation."""
        if self._dict_obs:
            return {name: flat[..., sl].copy() for name, sl in self._obs_slices.items()}
        return flat

    def _vector_info(self, cols_, rows: dict, extras: dict) -> dict:
        """Gymnasium's vector info: each key an array over worlds, with a bool mask ``_key`` of the worlds that
        have it."""
        idx, cols = cols_
        n = self.num_envs
        if not cols and not extras and len(rows) == n:  # world by world: stack the worlds' dicts
            return self._merge_infos([rows[i] for i in range(n)])
        out: dict[str, Any] = {}
        if cols:
            mask = np.zeros(n, dtype=bool)
            mask[idx] = True
            if rows:
                mask[list(rows)] = False
            for key, v in (cols.items() if mask.any() else ()):
                full = np.zeros((n,) + v.shape[1:], dtype=v.dtype)
                full[idx] = v
                if rows:
                    full[list(rows)] = 0  # as Gymnasium's vector info leaves the worlds without the key
                out[key] = full
                out[f"_{key}"] = mask.copy()
        for i in sorted(rows):
            out = self._add_info(out, rows[i], i)
        for i in sorted(extras):
            out = self._add_info(out, extras[i], i)
        return out

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

    def _world_infos(self, cols_, rows: dict, extras: dict) -> list[dict]:
        """The infos as one dict per world, as the single env returns them (for SB3's adapter)."""
        idx, cols = cols_
        infos: list[dict] = [{} for _ in range(self.num_envs)]
        if cols:
            keys = list(cols)
            values = [v.tolist() if v.ndim == 1 else list(v) for v in cols.values()]
            for i, vals in zip(idx, zip(*values)):
                infos[i] = dict(zip(keys, vals))
        for i, extra in extras.items():
            infos[i].update(extra)
        for i, info in rows.items():
            infos[i] = info
        return infos

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
