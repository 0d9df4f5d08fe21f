"""Rewards and ``info``: the common reward terms, the weighted sum, and the metrics every task reports.

The terms, their weighted sum and the metrics are functions over arrays: of N worlds ((N, ...) arrays, a
batch's) or of one world (its rows without the batch axis, the single env's), so that the single env and the
batch compute them with the same code.
"""

from __future__ import annotations

import numpy as np

from ..stiffness import stored_energy

COMMON_REWARD_TERMS = ("tracking", "energy", "action_rate", "termination")
FORCE_CAP = 10.0  # force penalties saturate at FORCE_CAP x scales.force: one violent contact sample (rigid
                  # contacts driven by stiff servos reach kN for a step) must not swamp a whole episode


def row_sum_sq(x: np.ndarray):
    """Sum of squares along the last axis. NumPy adds fewer than 8 terms in order, one world's row as a batch's
    (``tests/test_fast_paths.py`` holds it), so that the two give the same bits."""
    return np.add.reduce(x * x, axis=-1)


def wrap_angle(x):
    """Angle difference wrapped to [-pi, pi)."""
    return (np.asarray(x) + np.pi) % (2.0 * np.pi) - np.pi


def common_reward_terms(tracked, energy, action, prev_action, terminated, scales: dict) -> dict:
    """The unweighted common terms: ``tracked`` the posture error the task counts (..., k) (rad), ``energy``
    the springs' elastic energy (...) (J), ``action``/``prev_action`` (..., action dim), ``terminated`` (...)
    whether the physics diverged at this step."""
    return {
        "tracking": -np.sqrt(row_sum_sq(tracked)) / scales["tracking"],
        "energy": -energy / scales["energy"],
        "action_rate": -row_sum_sq(action - prev_action) / action.shape[-1],
        "termination": terminated * -1.0 + 0.0,  # -1 where it diverged, else 0 (+ 0.0: not -0.0)
    }


def weigh(raw: dict, weights: dict) -> tuple[dict, np.ndarray | float]:
    """The weighted terms ``reward_<name>`` and their sum, added in the weights' order (as ``info`` reports
    them, so that they sum exactly to the reward)."""
    weighted = {f"reward_{k}": w * raw[k] for k, w in weights.items()}
    reward = 0.0  # (0.0 + x is x, -0.0 included: the sum of a batch's zeros and x is the same)
    for v in weighted.values():
        reward = reward + v
    return weighted, reward


def squared_norms(err: np.ndarray):
    """err . err of each world (..., k): NumPy's dot product (its BLAS kernel's order and rounding, which an in-order
    sum of squares may miss by an ulp), which ``vecdot`` runs row by row as ``@`` runs it on one row."""
    return err @ err if err.ndim == 1 else np.vecdot(err, err)


def step_metrics(err, contact, peak_contact, sum_contact_sq, step, energy, lam, closure, closure_warn, time,
                 success) -> dict:
    """The metrics of ``info`` (see ``envs.base``) from the step's arrays: posture error (..., 3) (rad), the
    contact force now, its peak and sum of squares over the episode (N, N, N^2), the step count, elastic energy
    (J), lam (N m), the period's loop-closure peak, its warning level, the time (s) and the success flag."""
    return {
        "posture_error": np.sqrt(squared_norms(err)),
        "contact_force": contact,
        "peak_contact_force": peak_contact,
        "rms_contact_force": np.sqrt(sum_contact_sq / (step + (step == 0))),  # over max(step, 1) steps
        "elastic_energy": energy,
        "lam": lam,
        "loop_closure": closure,
        "closure_exceeded": closure > closure_warn,
        "time": time,
        "is_success": success,
    }


_FLAGS = ("closure_exceeded", "is_success")  # the metrics that are bools


class RewardsMixin:
    """The reward (unweighted terms, weights from config, their sum) and the ``info`` metrics of one world's
    step, through the functions above."""

    def _step_reward(self, err, energy, action, prev_action, terminated, task_terms: dict) -> tuple[dict, object]:
        """The weighted terms ``reward_<name>`` and their sum, of one world's step (its rows, ``self`` the world) or
        of a batch's worlds ((N, ...) arrays, ``self`` any of them): the common terms over the part of the posture
        error ``err`` the task counts, and the task's own (``task_terms``: {name: value}, its hook's values)."""
        raw = common_reward_terms(self._tracking_error(err), energy, action, prev_action, terminated,
                                  self.cfg["scales"])
        raw.update(task_terms)
        return weigh(raw, self.reward_weights)

    def _info(self, weighted: dict, final: bool, err: np.ndarray | None = None) -> dict:
        ep = self._ep
        if err is None:
            err = wrap_angle(ep.posture[0] - ep.target[0])
        info = dict(weighted)
        # this world's row, as Python numbers
        metrics = step_metrics(err, ep.contact.item(0), ep.peak_contact.item(0), ep.sum_contact_sq.item(0),
                               ep.step.item(0), ep.energy.item(0), ep.lam.item(0), ep.closure.item(0),
                               self._closure_warn, ep.t.item(0), bool(self._success()) if final else False)
        for k, v in metrics.items():  # one world's info holds Python numbers
            info[k] = bool(v) if k in _FLAGS else float(v)
        extra = self._task_info()
        if extra:
            info.update(extra)
        return info

    def elastic_energy(self) -> float:
        """Energy stored in the three springs (J): sum of 2 K delta0 (cosh(delta/delta0) - 1), the integral of
        the spring law, with the simulator's (possibly randomised) spring parameters."""
        return float(stored_energy(self.sim.deflections(), self.params))
