"""Rewards and ``info``: the common reward terms, the weighted sum, and the metrics every task reports."""

from __future__ import annotations

import math

import numpy as np

from ..stiffness import spring_energy

COMMON_REWARD_TERMS = ("tracking", "energy", "action_rate", "termination")
FORCE_CAP = 10.0  # force penalties saturate at FORCE_CAP x scales.force: one violent contact sample (rigid
                  # contacts driven by stiff servos reach kN for a step) must not swamp a whole episode


def _sum_sq(x: np.ndarray) -> float:
    """float(np.sum(x ** 2)) for the short vectors of the reward (numpy sums fewer than 8 terms in order)."""
    s = 0.0
    for v in (x * x).tolist():
        s += v
    return s


def wrap_angle(x):
    """Angle difference wrapped to [-pi, pi)."""
    return (np.asarray(x) + np.pi) % (2.0 * np.pi) - np.pi


class RewardsMixin:
    """The reward (unweighted terms, weights from config, their sum) and the ``info`` metrics of a step."""

    def _reward(self, err: np.ndarray, a: np.ndarray, failure: str | None) -> tuple[dict, float]:
        """The weighted terms ``reward_<name>`` and their sum (added in order, as the info reports them)."""
        sc = self.cfg["scales"]
        raw = {
            "tracking": -math.sqrt(_sum_sq(self._tracking_error(err))) / sc["tracking"],
            "energy": -self._energy / sc["energy"],
            "action_rate": -_sum_sq(a - self._prev_action) / a.size,
            "termination": -1.0 if failure is not None else 0.0,
        }
        raw.update(self._task_reward_terms(err))
        weighted = {f"reward_{k}": w * raw[k] for k, w in self.reward_weights.items()}
        reward = 0.0
        for v in weighted.values():
            reward += v
        return weighted, reward

    def _info(self, weighted: dict, final: bool, err: np.ndarray | None = None) -> dict:
        if err is None:
            err = wrap_angle(self._posture - self._target)
        n = max(self._step, 1)
        info = dict(weighted)
        info.update(
            posture_error=math.sqrt(float(err @ err)),
            contact_force=float(self._contact),
            peak_contact_force=float(self._peak_contact),
            rms_contact_force=float(math.sqrt(self._sum_contact_sq / n)),
            elastic_energy=self._energy,
            lam=float(self.ctrl.lam),
            loop_closure=self._closure,
            closure_exceeded=self._closure > self._closure_warn,
            time=self._t,
            is_success=bool(self._success()) if final else False,
        )
        extra = self._task_info()
        if extra:
            info.update(extra)
        return info

    def elastic_energy(self) -> float:
        """Energy stored in the three springs (J): sum of 2 K delta0 (cosh(delta/delta0) - 1), the integral of
        the spring law, with the simulator's (possibly randomised) spring parameters."""
        e0, e1, e2 = spring_energy(self.sim.deflections(), self.params).tolist()
        return e0 + e1 + e2
