"""The analytic baseline: the paper's controller behind a stable-baselines3 policy interface.

The environment already runs ``AnalyticController`` (exact IK + internal torque) under its
``posture_stiffness`` action mode; the baseline agent just commands the task's posture target with a fixed
stiffness, or with a stiffness schedule over episode time. It reads the target from the observation
(``env.unwrapped.obs_slices["target"]``, rad) and builds the action with ``env.unwrapped.reference_to_action``,
so that evaluation treats it exactly like a trained policy::

    agent = AnalyticAgent(env, stiffness=0.5)                                   # fixed command in [-1, 1]
    agent = AnalyticAgent(env, schedule=[(0.0, -1.0), (0.5, 1.0)])              # piecewise constant in time
    agent = AnalyticAgent.from_config(env, {"schedule": {"times": [0, 0.5], "values": [-1, 1]}})
    action, state = agent.predict(obs, state=None, episode_start=None, deterministic=True)

Observations may be flat arrays, dicts (``obs_mode: dict``) or batches of either (vectorised envs: one
row per env, with ``episode_start`` restarting each env's schedule clock).
"""

from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np


def _check_stiffness(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)) \
            or not math.isfinite(value) or not -1.0 <= float(value) <= 1.0:
        raise ValueError(f"{name} must be a stiffness command in [-1, 1], got {value!r}")
    return float(value)


class AnalyticAgent:
    """Fixed-stiffness (``stiffness``) or scheduled (``schedule``: (time_s, stiffness) breakpoints, held
    piecewise constant from each breakpoint on) analytic baseline. ``dt``: the env's control period (s),
    read from ``env.unwrapped.ctrl_dt`` when not given; it turns step counts into schedule time."""

    def __init__(self, env, stiffness: float = 0.0, schedule: Sequence[tuple[float, float]] | None = None,
                 dt: float | None = None):
        base = self._base_env(env)
        self._slices = base.obs_slices
        if "target" not in self._slices:
            raise ValueError(f"the environment observation has no 'target' term (terms: {sorted(self._slices)}); "
                             "the analytic agent needs the posture reference")
        self._to_action = base.reference_to_action
        self.stiffness = _check_stiffness("stiffness", stiffness)
        self.schedule: list[tuple[float, float]] | None = None
        if schedule is not None:
            pts = []
            for i, item in enumerate(schedule):
                try:
                    t, s = item
                except (TypeError, ValueError):
                    raise ValueError(f"schedule[{i}] must be a pair (time_s, stiffness), got {item!r}") from None
                if isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t) or t < 0:
                    raise ValueError(f"schedule[{i}] time must be a finite number of seconds >= 0, got {t!r}")
                pts.append((float(t), _check_stiffness(f"schedule[{i}] stiffness", s)))
            if not pts or any(b[0] <= a[0] for a, b in zip(pts, pts[1:])):
                raise ValueError("schedule must be a non-empty list of (time_s, stiffness) with increasing times")
            self.schedule = pts
        dt = getattr(base, "ctrl_dt", None) if dt is None else dt
        if self.schedule is not None and (dt is None or not math.isfinite(dt) or dt <= 0):
            raise ValueError(f"a schedule needs the control period dt > 0 (s), got {dt!r}")
        self.dt = None if dt is None else float(dt)
        self._steps: np.ndarray | None = None

    @staticmethod
    def _base_env(env):
        for candidate in (getattr(env, "unwrapped", None), env):
            if candidate is not None and hasattr(candidate, "obs_slices") and hasattr(candidate, "reference_to_action"):
                return candidate
        envs = getattr(env, "envs", None)                      # SB3 DummyVecEnv
        if envs:
            return AnalyticAgent._base_env(envs[0])
        raise ValueError("the analytic agent needs a VS-Wrist environment exposing obs_slices and "
                         "reference_to_action (env.unwrapped)")

    @classmethod
    def from_config(cls, env, cfg: Mapping[str, Any] | None):
        """From a config mapping: ``{"stiffness": s}`` or ``{"schedule": {"times": [...], "values": [...]}}``."""
        cfg = dict(cfg or {})
        unknown = set(cfg) - {"stiffness", "schedule", "dt"}
        if unknown:
            raise ValueError(f"unknown analytic agent setting(s) {sorted(unknown)}; allowed: stiffness, schedule, dt")
        schedule = cfg.get("schedule")
        if schedule is not None:
            if not isinstance(schedule, Mapping) or set(schedule) != {"times", "values"} \
                    or len(schedule["times"]) != len(schedule["values"]):
                raise ValueError("schedule must be a mapping {times: [...], values: [...]} of equal lengths")
            schedule = list(zip(schedule["times"], schedule["values"]))
        return cls(env, stiffness=cfg.get("stiffness", 0.0), schedule=schedule, dt=cfg.get("dt"))

    def stiffness_at(self, t: float) -> float:
        """The stiffness command at episode time t (s)."""
        if self.schedule is None:
            return self.stiffness
        s = self.schedule[0][1]
        for t_k, s_k in self.schedule:
            if t + 1e-9 >= t_k:
                s = s_k
        return s

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        """SB3-style: (action, state). Batched observations give batched actions; ``state`` is unused."""
        if isinstance(observation, Mapping):
            target = np.asarray(observation["target"], dtype=float)
        else:
            target = np.asarray(observation, dtype=float)[..., self._slices["target"]]
        batched = target.ndim == 2
        targets = target if batched else target[None]
        n = targets.shape[0]
        if self._steps is None or self._steps.shape[0] != n:
            self._steps = np.zeros(n, dtype=int)
        if episode_start is not None:
            starts = np.broadcast_to(np.asarray(episode_start, dtype=bool).reshape(-1), (n,))
            self._steps[starts] = 0
        actions = []
        for i in range(n):
            t = 0.0 if self.dt is None else self._steps[i] * self.dt
            actions.append(self._to_action(targets[i], self.stiffness_at(t)))
        self._steps += 1
        actions = np.asarray(actions, dtype=np.float32)
        return (actions if batched else actions[0]), state

    def reset(self) -> None:
        """Restart the schedule clock (also done per env by ``episode_start``)."""
        self._steps = None
