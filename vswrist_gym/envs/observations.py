"""Observations: the named terms (with physical bounds), sensor noise, and the flat or dict observation."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..stiffness import spring_stiffness, spring_torque


@dataclass(frozen=True)
class ObsTerm:
    """One named observation term: its size, unit, meaning, a function returning a fresh array, and its bounds
    (the declared space; values are clipped to them, which the bounds are chosen never to need in operation)."""

    name: str
    size: int
    unit: str
    doc: str
    fn: Callable[[], np.ndarray]
    low: float | np.ndarray = -np.inf
    high: float | np.ndarray = np.inf


class ObservationsMixin:
    """The observation side of ``VSWristEnv``: every term a task offers, noise, and the assembled observation."""

    def _obs_terms(self) -> dict[str, ObsTerm]:
        """Every observation term this task offers, with physical bounds (see ``ObsTerm``)."""
        n_act = self.action_space.shape[0]
        p = self.nominal_params
        dl, K2, d0 = p.spring.deflection_limit, 2.0 * p.spring.K, p.spring.delta0
        tau_bound = K2 * math.sinh(1.25 * dl / d0)
        lam_bound = 2.0 * self._lam_hi_max
        sig_bound = 10.0 * K2 / d0 * math.sqrt(1.0 + (tau_bound / K2) ** 2)
        half_pi, two_pi = 0.5 * math.pi, 2.0 * math.pi
        pl, ph = self.posture_map.lo, self.posture_map.hi
        terms = [
            ObsTerm("posture", 3, "rad", "measured RUD, FE, PS (with sensor noise)", self._obs_posture,
                    np.array([-half_pi, -half_pi, -two_pi]), np.array([half_pi, half_pi, two_pi])),
            ObsTerm("posture_rate", 3, "rad/s", "d/dt of the posture (with sensor noise)", self._obs_posture_rate,
                    -100.0, 100.0),
            ObsTerm("motor_angles", 4, "rad", "three PM motors and the PS motor", lambda: self.sim.motor_angles(),
                    -two_pi, two_pi),
            ObsTerm("deflections", 3, "rad", "spring deflections delta = q1 - theta", lambda: self._defl,
                    -math.pi, math.pi),
            ObsTerm("spring_torques", 3, "N m", "spring torques on the legs", self._obs_spring_torques,
                    -tau_bound, tau_bound),
            ObsTerm("stiffness", 3, "N m/rad", "coupler stiffness of the springs as they are, "
                    "J_a^T diag(sigma_s(delta)) J_a at the measured posture (RUD-RUD, RUD-FE, FE-FE; "
                    "paper's formula, no load term)",
                    self._obs_stiffness, -sig_bound, sig_bound),
            ObsTerm("lam", 1, "N m", "internal torque used (stiffness preload)", lambda: self.ctrl.lam,
                    -lam_bound, lam_bound),
            ObsTerm("prev_action", n_act, "-", "previous action", lambda: self._prev_action, -1.0, 1.0),
            ObsTerm("target", 3, "rad", "posture reference (RUD, FE, PS) now", lambda: self._target, pl, ph),
            ObsTerm("tool_wrench", 6, "N, N m", "hand-tool force/torque sensor, base frame (with noise)",
                    self._obs_wrench, np.array([-1e4] * 3 + [-1e3] * 3), np.array([1e4] * 3 + [1e3] * 3)),
            ObsTerm("contact_force", 1, "N", "normal force between the tool and the task's objects (Insertion: the "
                    "hole's walls and chamfers, not the fit plate) (with noise)",
                    self._obs_contact, 0.0, 1e5),
            ObsTerm("phase", 1, "-", "elapsed fraction of the episode",
                    lambda: self._step / self.episode_steps, 0.0, 1.0),
        ]
        out = {t.name: t for t in terms}
        for t in self._task_obs_terms():
            out[t.name] = t
        return out

    def _task_obs_terms(self) -> list[ObsTerm]:
        return []

    # sensor noise: one draw per observation, laid out as posture(3) posture_rate(3) force(3) torque(3) contact(1)

    _NOISE_LAYOUT = ("posture",) * 3 + ("posture_rate",) * 3 + ("force",) * 3 + ("torque",) * 3 + ("force",)

    def _draw_noise_table(self) -> None:
        """The episode's sensor noise, one row per observation (the reset's, then each step's), drawn at reset
        in one call: the same numbers, in the same order, as one draw of 13 per observation, without a
        generator call per step (a batch pays it once per world and episode, not per step)."""
        if self._noise_std is None:
            self._noise = None
            return
        self._noise_rng_state = self.np_random.bit_generator.state
        self._noise = self.np_random.normal(0.0, 1.0, (self.episode_steps + 1, 13)) * self._noise_scale

    def _rewind_unread_noise(self) -> None:
        """Before a reset without a seed: if the last episode ended before its last step (a divergence, the
        closure limit, a reset mid-episode), leave the generator where one draw per observation would have left
        it, so that the next episodes are the same whatever the table drew ahead."""
        if getattr(self, "_noise", None) is not None and self._step < self.episode_steps:
            self.np_random.bit_generator.state = self._noise_rng_state
            self.np_random.normal(0.0, 1.0, (self._step + 1, 13))

    def _draw_noise(self) -> None:
        self._nz = None if self._noise is None else self._noise[self._step]

    def _obs_posture(self):
        return self._posture if self._nz is None else self._posture + self._nz[0:3]

    def _obs_posture_rate(self):
        r = self.sim.posture_rate()
        return r if self._nz is None else r + self._nz[3:6]

    def _obs_wrench(self):
        w = self.sim.tool_wrench()
        return w if self._nz is None else w + self._nz[6:12]

    def _obs_contact(self):
        c = self._contact if self._nz is None else self._contact + self._nz[12]
        return c if c > 0.0 else 0.0  # a touch sensor never reads a pull

    def _obs_spring_torques(self):
        return spring_torque(self._defl, self.params)

    def _obs_stiffness(self):
        """The paper's J_a^T Sigma_s J_a from the measured deflections: the stiffness the springs give now
        (loads included), cheap (closed-form J_a, no Hessian); the ~13 % load term is left out."""
        # the posture is finite here (``step`` ends the episode otherwise), so skip kinematics_at's checks
        ay, az = self._posture_list[0], self._posture_list[1]
        _, Ja = self.ctrl._q1_ja(ay, az)
        s00 = s01 = s11 = 0.0
        for (a, b), sig in zip(Ja, spring_stiffness(self._defl, self.params).tolist()):
            s00 += sig * a * a
            s01 += sig * a * b
            s11 += sig * b * b
        return (s00, s01, s11)

    def _raw_observation(self) -> np.ndarray:
        """All terms written into one new float64 array (so no term is ever a view of simulator memory)."""
        obs = np.empty(self.obs_size)
        for a, b, fn in self._obs_plan:
            obs[a:b] = fn()
        return obs

    def _observation(self):
        self._draw_noise()
        obs = self._raw_observation()
        # np.clip(obs, low, high) without its Python-level dispatch (same values, NaN passes through)
        np.maximum(obs, self._obs_low, out=obs)
        np.minimum(obs, self._obs_high, out=obs)
        obs = obs.astype(np.float32)
        if self.cfg["obs_mode"] == "dict":
            return {t.name: obs[self.obs_slices[t.name]].copy() for t in self.obs_terms}
        return obs
