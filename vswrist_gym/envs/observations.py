"""Observations: the named terms (with physical bounds), sensor noise, and the flat or dict observation.

Each common term is a function over arrays (``ObsTerm.of``): from a step's ``measures`` of N worlds ((N, ...)
arrays, a batch's) or of one world (its rows without the batch axis, the single env's) to the term's values
(..., size). The single env and the batch assemble their observations with the same functions (``observe``), so
the two cannot drift apart.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..stiffness import spring_stiffness, spring_torque


@dataclass(frozen=True)
class ObsTerm:
    """One named observation term: its size, unit, meaning, how it is computed, and its bounds (the declared
    space; values are clipped to them, which the bounds are chosen never to need in operation).

    ``of(measures) -> (..., size)``: the term over arrays of worlds (see ``observe``); ``fn() -> (size,)``: one
    world's value, for a task's own terms, which read its env's state (a batch calls it world by world)."""

    name: str
    size: int
    unit: str
    doc: str
    fn: Callable[[], np.ndarray] | None
    low: float | np.ndarray = -np.inf
    high: float | np.ndarray = np.inf
    of: Callable | None = None


def _noisy(x, noise, a: int, b: int):
    """A measurement with its sensor noise, columns a..b-1 of the step's draws ``noise`` (..., 13) (None: no
    noise)."""
    return x if noise is None else x + noise[..., a:b]


def column(x) -> np.ndarray:
    """Values of one number per world as the term's single column (..., 1)."""
    return np.asarray(x, dtype=float)[..., None]


def flag_column(flag) -> np.ndarray:
    """A condition per world (a bool or a bool array) as the term's column of 1.0 or 0.0 (..., 1)."""
    return column(flag * 1.0)


def _touch(force, noise) -> np.ndarray:
    """A touch sensor's reading with its noise (column 12 of the draws), as the term's column (..., 1): it never
    reads a pull (negative values, NaN too, read 0)."""
    f = force if noise is None else force + noise[..., 12]
    return (np.fmax(f, 0.0) + 0.0)[..., None]  # fmax: NaN reads 0; + 0.0: so does -0.0


_PAIRS = np.array([0, 0, 1]), np.array([0, 1, 1])  # J_a's columns in the products J0 J0, J0 J1, J1 J1


def coupler_stiffness(Ja, sigma) -> np.ndarray:
    """The paper's J_a^T diag(sigma_s) J_a as (RUD-RUD, RUD-FE, FE-FE) (..., 3), from J_a (..., 3 legs, 2) and
    the springs' stiffnesses ``sigma`` (..., 3 legs): each leg's sigma J_i J_j, summed leg by leg in order."""
    x = (sigma[..., :, None] * Ja).take(_PAIRS[0], -1) * Ja.take(_PAIRS[1], -1)  # (..., 3 legs, 3)
    return np.add.reduce(x, axis=-2)


def observe(terms: list, measures, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """The observation of the worlds ``measures`` describes (float32 (..., size)): every term in order, clipped
    to the bounds (NaN passes through). ``measures`` holds the step's arrays (``posture``, ``deflections``,
    ``law``, ``contact``, ``lam``, ``prev_action``, ``target``, ``step``, ``time``, ``noise``), the worlds' fields
    of the task's state ``state(name)`` (``episode.TaskState``) and, for a field that is a table over the episode's
    control instants, its entry at the step ``state_at_step(name)``, the simulator's reads that only some terms need
    (``posture_rate()``, ``motor_angles()``, ``tool_wrench()``, ``jacobian()``: J_a (..., 3 legs, 2); ``sensor(adr)``:
    the sensors' value at address ``adr``) and ``task_term(term)``, a task's own per-world term (``ObsTerm.fn``) over
    its worlds."""
    raw = np.concatenate([t.of(measures) if t.of is not None else measures.task_term(t) for t in terms], axis=-1)
    return np.minimum(np.maximum(raw, low), high).astype(np.float32)


class WorldMeasures:
    """``observe``'s measures of one env (no batch axis): its step's state, and its simulator's reads."""

    __slots__ = ("env", "posture", "deflections", "law", "contact", "lam", "prev_action", "target", "step",
                 "time", "noise")

    def __init__(self, env):
        self.env = env
        ep = env._ep  # this world's row of the episode state
        self.posture, self.deflections, self.law = ep.posture[0], ep.defl[0], env.params
        self.contact, self.lam, self.prev_action = ep.contact.item(0), ep.lam.item(0), ep.prev_action[0]
        self.target, self.step, self.time, self.noise = ep.target[0], ep.step.item(0), ep.t.item(0), env._nz

    def state(self, name: str):
        return getattr(self.env._ep.task, name)[0]

    def state_at_step(self, name: str):
        return getattr(self.env._ep.task, name)[0, self.step]

    def sensor(self, adr: int):
        return self.env.data.sensordata[adr]

    def posture_rate(self) -> np.ndarray:
        return self.env.sim.posture_rate()

    def motor_angles(self) -> np.ndarray:
        return self.env.sim.motor_angles()

    def tool_wrench(self) -> np.ndarray:
        return self.env.sim.tool_wrench()

    def jacobian(self) -> np.ndarray:
        # the posture is finite here (``step`` ends the episode otherwise), so skip kinematics_at's checks
        p = self.posture
        ay, az = p.item(0), p.item(1)
        return np.array(self.env.ctrl._q1_ja(ay, az)[1])

    def task_term(self, term: ObsTerm) -> np.ndarray:
        return np.asarray(term.fn(), dtype=float).reshape(term.size)


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
        steps = self.episode_steps
        terms = [
            ObsTerm("posture", 3, "rad", "measured RUD, FE, PS (with sensor noise)", None,
                    np.array([-half_pi, -half_pi, -two_pi]), np.array([half_pi, half_pi, two_pi]),
                    lambda m: m.posture if m.noise is None else m.posture + m.noise[..., 0:3]),
            ObsTerm("posture_rate", 3, "rad/s", "d/dt of the posture (with sensor noise)", None, -100.0, 100.0,
                    lambda m: _noisy(m.posture_rate(), m.noise, 3, 6)),
            ObsTerm("motor_angles", 4, "rad", "three PM motors and the PS motor", None, -two_pi, two_pi,
                    lambda m: m.motor_angles()),
            ObsTerm("deflections", 3, "rad", "spring deflections delta = q1 - theta", None, -math.pi, math.pi,
                    lambda m: m.deflections),
            ObsTerm("spring_torques", 3, "N m", "spring torques on the legs", None, -tau_bound, tau_bound,
                    lambda m: spring_torque(m.deflections, m.law)),
            # the stiffness the springs give now (loads included), cheap (closed-form J_a, no Hessian); the ~13 %
            # load term is left out
            ObsTerm("stiffness", 3, "N m/rad", "coupler stiffness of the springs as they are, "
                    "J_a^T diag(sigma_s(delta)) J_a at the measured posture (RUD-RUD, RUD-FE, FE-FE; "
                    "paper's formula, no load term)", None, -sig_bound, sig_bound,
                    lambda m: coupler_stiffness(m.jacobian(), spring_stiffness(m.deflections, m.law))),
            ObsTerm("lam", 1, "N m", "internal torque used (stiffness preload)", None, -lam_bound, lam_bound,
                    lambda m: column(m.lam)),
            ObsTerm("prev_action", n_act, "-", "previous action", None, -1.0, 1.0, lambda m: m.prev_action),
            ObsTerm("target", 3, "rad", "posture reference (RUD, FE, PS) now", None, pl, ph, lambda m: m.target),
            ObsTerm("tool_wrench", 6, "N, N m", "hand-tool force/torque sensor, base frame (with noise)", None,
                    np.array([-1e4] * 3 + [-1e3] * 3), np.array([1e4] * 3 + [1e3] * 3),
                    lambda m: _noisy(m.tool_wrench(), m.noise, 6, 12)),
            ObsTerm("contact_force", 1, "N", "normal force between the tool and the task's objects (Insertion: the "
                    "hole's walls and chamfers, not the fit plate) (with noise)", None, 0.0, 1e5,
                    lambda m: _touch(m.contact, m.noise)),
            ObsTerm("phase", 1, "-", "elapsed fraction of the episode", None, 0.0, 1.0,
                    lambda m: column(m.step / steps)),
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
            return
        self._noise_rng_state = self.np_random.bit_generator.state
        self._ep.noise[0] = self.np_random.normal(0.0, 1.0, (self.episode_steps + 1, 13)) * self._noise_scale

    def _rewind_unread_noise(self) -> None:
        """Before a reset without a seed: if the last episode ended before its last step (a divergence, the
        closure limit, a reset mid-episode), leave the generator where one draw per observation would have left
        it, so that the next episodes are the same whatever the table drew ahead."""
        if getattr(self, "_noise", None) is not None and self._step < self.episode_steps:
            self.np_random.bit_generator.state = self._noise_rng_state
            self.np_random.normal(0.0, 1.0, (self._step + 1, 13))

    def _draw_noise(self) -> None:
        """The current observation's row of the noise table (a batch takes its worlds' rows at once)."""
        if self._noise_std is not None:
            ep = self._ep
            ep.nz[0] = ep.noise[0, ep.step.item(0)]

    def _raw_observation(self) -> np.ndarray:
        """This world's observation before clipping and rounding to float32 (float64, every term in order)."""
        m = WorldMeasures(self)
        return np.concatenate([t.of(m) if t.of is not None else m.task_term(t) for t in self.obs_terms])

    def _obs_stiffness(self) -> np.ndarray:
        """This world's ``stiffness`` term now."""
        return self._terms["stiffness"].of(WorldMeasures(self))

    def _observation(self):
        self._draw_noise()
        obs = observe(self.obs_terms, WorldMeasures(self), *self._obs_bounds)
        if self.cfg["obs_mode"] == "dict":
            return {t.name: obs[self.obs_slices[t.name]].copy() for t in self.obs_terms}
        return obs
