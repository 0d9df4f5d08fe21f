"""A batch's physics: one control period of its live worlds, on threads (``VSWristVectorEnv``'s mixin).

Through the batch simulator (``batch_sim.BatchSim``, the compiled advance: per world, what ``VSWristEnv._advance``
does through ``WristSim``, in one GIL-free C++ call per chunk of worlds). On ``threads`` threads, up to
``CHUNKS_PER_THREAD`` chunks per thread (of at least ``MIN_CHUNK_WORLDS`` worlds) are stepped by the library's
``threads - 1`` threads and by the calling thread: the array step's ``_begin`` of the other chunks runs beside the
first chunks' physics, and its ``_finish`` of most chunks beside the last ones' (``_native_step``), so the Python of
some worlds runs beside the physics of others. The compiled plugins (``model.native``: springs and motors, the
loop-closure monitor, and Polish's and Hammer's per-substep contact meter ``vswrist.contact``) keep no global mutable
state (theirs lives in each MjData's ``plugin_data``/``plugin_state``), and every world has its own MjModel, so worlds
advance in parallel. Actuation latency (its first substeps on the previous references) runs inside the compiled
call too, and so does Throw's search for the release to the substep (its watch: ``_watch_worlds`` writes each
world's row before its chunk's physics, ``_after_watch_worlds`` reads it before its ``_finish``). Under the reference
physics (``VSWRIST_NATIVE=0``: the Python callbacks) each world runs ``_advance`` instead, and each substep re-enters
Python, so threads would only contend for the GIL: the batch then steps serially.
"""

from __future__ import annotations

import mujoco
import numpy as np

from ..batch_sim import DIVERGED, OK
from ..sim import DIVERGED_MESSAGE
from .episode import held_substeps

# chunks of worlds per physics thread in a step (``VSWristVectorEnv._native_step``), each of at least
# MIN_CHUNK_WORLDS worlds: more chunks balance the threads better and shorten the last chunk, whose
# ``_finish`` no physics overlaps; fewer make the first chunk, whose ``_begin`` no physics overlaps, longer to
# compute beside. 16 chunks on 2 threads stepped 32 and 64 worlds 4-8 % faster than 8 on the 2-core dev machine
# (``experiments/batched_speed/chunk_count.py``; Hammer's 32 worlds as fast)
CHUNKS_PER_THREAD = 8
MIN_CHUNK_WORLDS = 2


class PhysicsMixin:
    """The physics of ``VSWristVectorEnv``'s live worlds, and the array step (``ArrayStepMixin``) around it."""

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
        ep = self._ep
        bsim.set_latency(idx, held_substeps(ep.latency[idx], ep.step[idx]))
        return True

    def _after_native(self, worlds: list, idx: list, status: np.ndarray) -> None:
        """What ``_advance`` leaves on each world and its simulator, from the compiled call's status."""
        self.batch_sim.settle([e.sim for e in worlds], status)
        odd = np.flatnonzero((status != OK) & (status != DIVERGED)).tolist()
        if odd:
            raise mujoco.FatalError(f"env {idx[odd[0]]}: MuJoCo raised an error inside this world's physics step")
        diverged = status == DIVERGED
        self._ep.put(idx, diverged=diverged)
        for k in np.flatnonzero(diverged).tolist():
            worlds[k]._sim_error = DIVERGED_MESSAGE
        if self._meter_task:
            for e in worlds:
                e._period_ran = True

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

        task = type(worlds[0])
        watch = bsim.watch if self._watch else None

        def finish(pos: list) -> None:
            ws = [worlds[p] for p in pos]
            self._after_native(ws, [idx[p] for p in pos], status[pos])
            if watch is not None:
                task._after_watch_worlds(ws, self._ep, widx[pos], watch[widx[pos]])
            part = self._finish(ws, widx[pos], G[pos])
            parts.append((pos, part))
            if started is not None and self._pool is not None:  # SAME_STEP: the ended worlds reset now
                self._start_resets([idx[pos[j]] for j in np.flatnonzero(part[2] | part[3]).tolist()], started)

        def begin(lo: int, hi: int) -> np.ndarray:
            """``_begin`` of live worlds lo..hi-1 (and their watches' rows): their motor references (hi - lo, 4)."""
            TH = self._motor_matrix(idx[lo:hi], self._begin(worlds[lo:hi], widx[lo:hi], acts[lo:hi]))
            if watch is not None:
                watch[widx[lo:hi]] = task._watch_worlds(worlds[lo:hi], self._ep, widx[lo:hi])
            return TH

        k = min(CHUNKS_PER_THREAD * self.threads, L // MIN_CHUNK_WORLDS)
        if self.threads == 1 or k < 2:
            TH = begin(0, L)
            if meanwhile is not None:
                meanwhile()
            bsim.advance(widx, TH, status, seconds, G)
            finish(list(range(L)))
        else:
            bounds = np.linspace(0, L, k + 1).round().astype(np.int32)
            head = int(bounds[self.threads - 1])  # one chunk for each pool thread
            TH = np.empty((L, 4))
            TH[:head] = begin(0, head)
            pool = bsim.pool(self.threads - 1)
            bsim.submit(pool, widx, TH, status, seconds, bounds, self.threads - 1, G)
            todo = np.ones(k, dtype=bool)
            try:
                if meanwhile is not None:
                    meanwhile()
                try:
                    TH[head:] = begin(head, L)
                except BaseException:
                    self._started = False  # the first chunks stepped, the others did not: reset() first
                    raise
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
    def _motor_matrix(idx: list, theta: np.ndarray) -> np.ndarray:
        """The live worlds' (``idx``) motor references ``theta`` (L, 4), float64 C-contiguous, checked finite as
        ``WristSim.set_motor_references`` checks them."""
        TH = np.ascontiguousarray(theta, dtype=np.float64)
        if not np.isfinite(TH).all():
            k = int(np.flatnonzero(~np.isfinite(TH).all(axis=1))[0])
            raise ValueError(f"env {idx[k]}: motor references must be 4 finite angles in rad (A, B, C, PS), got "
                             f"{TH[k]!r}")
        return TH
