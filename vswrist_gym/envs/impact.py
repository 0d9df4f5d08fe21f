"""``VSWrist/Impact-v1`` (and ``-v0``): follow a flexion/extension motion during which the tool may meet an obstacle.

The tool is heavy (``tool_mass``). In v1 the controller's gravity compensation holds its nominal weight
(``compensate_tool``), as it holds the hand's: the task gives the agent this tool, so its weight is known, and
left uncompensated it sags the wrist by about 0.06 rad in RUD at the softest stiffness, a static error that a
fixed posture offset removes and no stiffness schedule should be credited with. v0 (the same task without it)
leaves that sag. The reference moves FE from ``fe_start``
to ``fe_end`` (minimum jerk, ``move_s``) and back, at a random RUD and PS. In most episodes
(``obstacle_probability``) a wall stands across the tool's path at a random fraction of the way; the agent is
not told where. Adapting stiffness pays: a stiff wrist tracks the free motion closely (the tool's weight and
inertia), a soft one keeps the contact force low once the reference pushes into the wall, and the force/torque
sensor tells when contact begins.

Success: peak contact force below ``success_force`` and RMS posture error over the steps without contact
below ``success_error``.
"""

from __future__ import annotations

import numpy as np

from .base import VSWristEnv
from .episode import episode_history, task_field
from .rewards import FORCE_CAP, squared_norms
from .shared import FINGER_END, add_mocap_box_body, quat_from_matrix, sensor_values, smoothstep

WALL_HALF = (0.01, 0.03, 0.035)  # m: thickness (along the motion), along the tool, across


class ImpactEnv(VSWristEnv):
    task = "impact"

    @property
    def task_id(self) -> str:
        """v1 compensates the tool's nominal weight (``compensate_tool``); v0 is the same task without."""
        return "VSWrist/Impact-v1" if self.cfg["compensate_tool"] else "VSWrist/Impact-v0"

    summary = "follow an FE motion that may meet an unexpected obstacle; keep the peak force low while tracking"
    success_text = ("peak contact force < {success_force:g} N and RMS posture error without contact "
                    "< {success_error:g} rad")
    task_spec = {
        "tool_length": ("number", 0.0, 0.3),
        "tool_radius": ("number", 0.001, 0.05),
        "tool_mass": ("number", 0.001, 5.0),
        "rud_range": ("interval", -1.5, 1.5),
        "fe_start": ("interval", -1.5, 1.5),
        "fe_end": ("interval", -1.5, 1.5),
        "move_s": ("interval", 0.05, 600.0),
        "obstacle_probability": ("number", 0.0, 1.0),
        "obstacle_fraction": ("interval", 0.0, 1.0),
        "ps_range": ("interval", -np.pi, np.pi),
        "success_force": ("number", 0.0, 1e5),
        "success_error": ("number", 0.0, 10.0),
    }
    task_reward_terms = ("force",)
    contact_threshold = 0.5  # N: a step counts as "in contact" above this force
    # the episode's draws: the motion (RUD, FE from fe0 to fe1 in ``move`` s and back, PS: rad) and the wall
    # (whether it stands, at which fraction of the way)
    task_state = {"rud": ((), float), "fe0": ((), float), "fe1": ((), float), "move": ((), float),
                  "ps": ((), float), "obstacle": ((), bool), "frac": ((), float)}
    _rud, _fe0, _fe1, _move, _ps, _obstacle, _frac = map(task_field, task_state)

    def _scene(self, spec) -> None:
        self._tip_x = FINGER_END + self.tp["tool_length"]
        self._add_tool_geom(spec, "stick", [0.02, 0, 0, self._tip_x, 0, 0], self.tp["tool_radius"],
                            self.tp["tool_mass"])
        body = add_mocap_box_body(spec, "task_wall", [(WALL_HALF, (0, 0, 0), None)], rgba=(0.7, 0.35, 0.3, 1))
        hx, hy, hz = WALL_HALF
        self._add_touch_sensor(spec, body, "wall_touch", (hx + 0.01, hy + 0.01, hz + 0.01))

    def _scene_ids(self) -> None:
        self._touch_adr = self._sensor_adr("wall_touch")
        self._mocap = int(self.model.body("task_wall").mocapid[0])

    def _task_reset(self, rng):
        tp = self.tp
        rud = float(rng.uniform(*tp["rud_range"]))
        fe0 = float(rng.uniform(*tp["fe_start"]))
        fe1 = float(rng.uniform(*tp["fe_end"]))
        if rng.random() < 0.5:
            fe0, fe1 = fe1, fe0
        move = float(rng.uniform(*tp["move_s"]))
        ps = float(rng.uniform(*tp["ps_range"]))
        obstacle = bool(rng.random() < tp["obstacle_probability"])
        frac = float(rng.uniform(*tp["obstacle_fraction"]))
        self._ep.task.put(0, rud=rud, fe0=fe0, fe1=fe1, move=move, ps=ps, obstacle=obstacle, frac=frac)
        return np.array([rud, fe0]), ps, float(rng.uniform(-1.0, 1.0))

    def _after_reset(self) -> None:
        if not self._obstacle:
            self.data.mocap_pos[self._mocap] = (0.0, 0.0, -5.0)
            return
        fe = self._fe0 + self._frac * (self._fe1 - self._fe0)
        sign = np.sign(self._fe1 - self._fe0)
        tip = lambda f: self.tool_point(np.array([self._rud, f]), self._ps, np.array([self._tip_x, 0, 0]))  # noqa
        d = tip(fe + 1e-4 * sign) - tip(fe - 1e-4 * sign)
        d /= np.linalg.norm(d)
        axis = tip(fe) - self.tool_point(np.array([self._rud, fe]), self._ps, np.zeros(3))
        axis -= (axis @ d) * d
        axis /= np.linalg.norm(axis)
        R = np.column_stack([d, axis, np.cross(d, axis)])
        centre = tip(fe) - 0.02 * axis + (self.tp["tool_radius"] + WALL_HALF[0]) * d
        self.data.mocap_pos[self._mocap] = centre
        self.data.mocap_quat[self._mocap] = quat_from_matrix(R)

    def _reference(self, t) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        back = max(self.cfg["episode_s"] - self._move, 1e-6)
        s = np.where(t <= self._move, smoothstep(t / self._move), 1.0 - smoothstep((t - self._move) / back))
        return np.stack([np.full_like(t, self._rud), self._fe0 + s * (self._fe1 - self._fe0),
                         np.full_like(t, self._ps)], axis=-1)

    @classmethod
    def _contact_force_worlds(cls, worlds: list, ep, ids) -> np.ndarray:
        return sensor_values(worlds, worlds[0]._touch_adr)

    @classmethod
    def _task_reward_terms_worlds(cls, worlds: list, ep, ids, err) -> dict:
        return {"force": force_penalty(ep.contact[ids], worlds[0].cfg["scales"]["force"])}

    @classmethod
    def _success_worlds(cls, worlds: list, ep, ids) -> np.ndarray:
        tp = worlds[0].tp
        err, _, contact = episode_history(ep, ids)
        rms = np.array([free_rms(e, c, cls.contact_threshold) for e, c in zip(err, contact)])
        return (ep.peak_contact[ids] < tp["success_force"]) & (rms < tp["success_error"])


def force_penalty(contact, scale: float):
    """The ``force`` term of contact forces ``contact`` (N): minus the square of the force in ``scale``s, capped at
    ``FORCE_CAP`` (float_power: C's pow, the squaring of one world's Python number)."""
    return -np.float_power(np.minimum(contact / scale, FORCE_CAP), 2.0)


def free_rms(err, contact, threshold: float) -> float:
    """One world's RMS posture error (rad) over the steps of its episode without contact (``contact`` at most
    ``threshold``), from its posture errors ``err`` (k, 3) and contact forces ``contact`` (k,); 0 if none."""
    sq = squared_norms(err[contact <= threshold])
    return float(np.sqrt(np.mean(sq))) if sq.size else 0.0
