"""The task hooks of a VS-Wrist environment (``VSWristEnv``'s mixin): their defaults and what each must do.

A task (a subclass of ``VSWristEnv``; its class docstring says how to write one) overrides these; the base and
the batch call them. Each is written for one world (``self``), except the class methods, which take the worlds
that act together (a batch's, or the single env as a batch of one).
"""

from __future__ import annotations

import mujoco
import numpy as np


class TaskHooks:
    """The hooks' defaults: nothing to add, check or place; no loads, no contact, the whole posture error
    tracked, no extra reward terms or info; ``_task_reset``, ``_reference`` and ``_success`` must be given."""

    def _validate_task(self) -> None:
        """Cross-checks of the task section beyond per-field ranges (override in tasks)."""

    def _scene_ids(self) -> None:
        """Look up the task's model elements after (re)compilation (override in tasks)."""

    def _scene(self, spec: mujoco.MjSpec) -> None:
        """Add task geometry to the model before compilation."""

    def _task_reset(self, rng: np.random.Generator) -> tuple[np.ndarray, float, float]:
        """Sample the episode; return the initial posture u (2,), PS angle and stiffness command."""
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

    def _before_physics(self, t: float) -> None:
        """Apply external loads for the coming control period. A task that writes its loads over arrays of worlds
        (``_before_physics_worlds``) leaves this to the base, which runs that for a batch of one."""
        cls = type(self)
        if cls._before_physics_worlds.__func__ is not TaskHooks._before_physics_worlds.__func__:
            cls._before_physics_worlds([self], np.array([t]))

    @classmethod
    def _before_physics_worlds(cls, worlds: list, t: np.ndarray) -> None:
        """``_before_physics`` of ``worlds`` (of this task) at their times ``t`` (N,), over arrays; the default
        calls each world's ``_before_physics``."""
        for e, tk in zip(worlds, t.tolist()):
            e._before_physics(tk)

    def _contact_force(self) -> float:
        """Contact force (N) after a step; the simulator's sensors are current (``posture()`` synced them)."""
        return 0.0

    def _tracking_error(self, err: np.ndarray) -> np.ndarray:
        """The part of the posture error (RUD, FE, PS; the last axis) that the tracking reward counts. Index the
        last axis only (``err[..., 1:]``): a batch passes all its worlds' errors (N, 3) at once."""
        return err

    def _task_reward_terms(self, err: np.ndarray) -> dict[str, float]:
        return {}

    def _task_info(self) -> dict:
        """Task-specific ``info`` entries of every step and reset (numbers or bools, the same keys each time)."""
        return {}

    def _success(self) -> bool:
        raise NotImplementedError
