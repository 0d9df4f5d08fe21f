"""The task hooks of a VS-Wrist environment (``VSWristEnv``'s mixin): their defaults and what each must do.

A task (a subclass of ``VSWristEnv``; its class docstring says how to write one) overrides these; the base and
the batch call them. The per-step hooks and the success come in two forms, so that a task states its logic once:

* over arrays of worlds, the class methods ``<hook>_worlds(worlds, ep, ids, ...)``: ``worlds`` the envs that act
  together (each holding its own simulator), ``ep`` the ``EpisodeState`` whose rows ``ids`` (an array of indices,
  or ``episode.ONE``) are theirs, in order; they read the worlds' state there (the task's own in ``ep.task``,
  declared by ``task_state``) and return (L, ...) arrays, or write the rows ``ids``. A batch calls them once for
  its live worlds, the single env with itself as a batch of one (``ONE``);
* for one world (``self``): ``_before_physics``, ``_contact_force``, ``_task_reward_terms``, ``_task_info``,
  ``_success``, whose defaults run the task's form over arrays on this world, and which a task not yet written
  over arrays overrides instead (the array form's default then asks each world in turn).

A task overrides one form of each hook, never both.
"""

from __future__ import annotations

from functools import cache

import mujoco
import numpy as np

from .episode import ONE


@cache  # the single env asks at every step
def over_arrays(cls, hook: str) -> bool:
    """Whether task ``cls`` writes ``hook`` (a ``..._worlds`` class method) over arrays of worlds itself."""
    return getattr(cls, hook).__func__ is not getattr(TaskHooks, hook).__func__


class TaskHooks:
    """The hooks' defaults: nothing to add, check or place; no loads, no contact, the whole posture error
    tracked, no extra reward terms or info; ``_task_reset``, ``_reference`` and a form of ``_success`` must be
    given."""

    # the task's own episode state ({name: (the shape of one world's value, dtype)}: ``episode.TaskState``)
    task_state: dict = {}

    def _validate_task(self) -> None:
        """Cross-checks of the task section beyond per-field ranges (override in tasks)."""

    def _scene_ids(self) -> None:
        """Look up the task's model elements after (re)compilation (override in tasks)."""

    def _scene(self, spec: mujoco.MjSpec) -> None:
        """Add task geometry to the model before compilation."""

    def _task_reset(self, rng: np.random.Generator) -> tuple[np.ndarray, float, float]:
        """Sample the episode (this world's row of the task state, ``self._ep.task``, is zeros until it writes
        it); return the initial posture u (2,), PS angle and stiffness command."""
        raise NotImplementedError

    def _after_reset(self) -> None:
        """Place task objects once the simulator is at its initial state."""

    def _reference(self, t: float) -> np.ndarray:
        raise NotImplementedError

    @classmethod
    def _reset_worlds(cls, worlds: list) -> None:
        """The part of the episode's set-up a task computes over the worlds that reset together, after each one's
        ``_reset_begin`` (its draws and initial state) and before its ``_reset_finish``; Python state only (a batch
        runs it while those worlds settle). The single env calls it with itself. Default: nothing."""

    # ------------------------------------------------------------------ the step's hooks
    def _before_physics(self, t: float) -> None:
        """Apply external loads for the coming control period (``t``: its start, s)."""
        if over_arrays(type(self), "_before_physics_worlds"):
            self._before_physics_worlds([self], self._ep, ONE)

    @classmethod
    def _before_physics_worlds(cls, worlds: list, ep, ids) -> None:
        """The loads of ``worlds`` for the coming period, which starts at their times ``ep.t[ids]``
        (``WristSim.apply_wrenches``); the default asks each world."""
        for e, tk in zip(worlds, ep.t[ids].tolist()):
            e._before_physics(tk)

    def _contact_force(self) -> float:
        """Contact force (N) after a step; the simulator's sensors are current (``posture()`` synced them)."""
        if over_arrays(type(self), "_contact_force_worlds"):
            return self._contact_force_worlds([self], self._ep, ONE).item(0)
        return 0.0

    @classmethod
    def _contact_force_worlds(cls, worlds: list, ep, ids) -> np.ndarray:
        """The contact forces (L,) (N) of ``worlds`` after a step; the default asks each world."""
        return np.array([e._contact_force() for e in worlds], dtype=float)

    def _tracking_error(self, err: np.ndarray) -> np.ndarray:
        """The part of the posture error (RUD, FE, PS; the last axis) that the tracking reward counts. Index the
        last axis only (``err[..., 1:]``): a batch passes all its worlds' errors (N, 3) at once."""
        return err

    def _task_reward_terms(self, err: np.ndarray) -> dict[str, float]:
        """The task's unweighted reward terms of a step with posture error ``err`` (3,): {name: value}."""
        if over_arrays(type(self), "_task_reward_terms_worlds"):
            terms = self._task_reward_terms_worlds([self], self._ep, ONE, err[None])
            return {name: v.item(0) for name, v in terms.items()}
        return {}

    @classmethod
    def _task_reward_terms_worlds(cls, worlds: list, ep, ids, err: np.ndarray) -> dict[str, np.ndarray]:
        """The task's unweighted reward terms {name: (L,)} of ``worlds``' step, with posture errors ``err`` (L, 3);
        the step's measures and record are in their rows. The default asks each world."""
        raw = [e._task_reward_terms(er) for e, er in zip(worlds, err)]
        return {name: np.array([d[name] for d in raw]) for name in cls.task_reward_terms}

    def _task_info(self) -> dict:
        """Task-specific ``info`` entries of every step and reset (numbers or bools, the same keys each time)."""
        if over_arrays(type(self), "_task_info_worlds"):
            return {k: v.item(0) for k, v in self._task_info_worlds([self], self._ep, ONE).items()}
        return {}

    @classmethod
    def _task_info_worlds(cls, worlds: list, ep, ids) -> dict[str, np.ndarray]:
        """``_task_info`` of ``worlds`` as {key: (L,)}; the default asks each world."""
        extra = [e._task_info() for e in worlds]
        return {key: np.array([x[key] for x in extra]) for key in extra[0]}

    @classmethod
    def _watch_worlds(cls, worlds: list, ep, ids) -> np.ndarray:
        """For a task whose physics (``_advance_physics``) watches every substep for an event: the compiled
        advance's watch of it, rows (L, ``batch_sim.WATCH_SIZE``) written by ``batch_sim.watch_rows`` from the
        worlds' state at the period's start, after the actions; the watch then does to the substep, and to the bit,
        what ``_advance_physics`` does (Throw: its search for the release), and ``_after_watch_worlds`` takes its
        outcome. The default, never called: no watch."""
        raise NotImplementedError

    @classmethod
    def _after_watch_worlds(cls, worlds: list, ep, ids, rows: np.ndarray) -> None:
        """What the compiled advance's watch (``rows``, after the period) found, into the worlds' state, as
        ``_advance_physics`` writes it, before the step's clock moves on."""
        raise NotImplementedError

    def _success(self) -> bool:
        """Whether the episode succeeded (decided at its last step, from its history and the task's state)."""
        if over_arrays(type(self), "_success_worlds"):
            return bool(self._success_worlds([self], self._ep, ONE)[0])
        raise NotImplementedError

    @classmethod
    def _success_worlds(cls, worlds: list, ep, ids) -> np.ndarray:
        """``_success`` of ``worlds`` (L,) bool; the default asks each world."""
        return np.array([bool(e._success()) for e in worlds], dtype=bool)
