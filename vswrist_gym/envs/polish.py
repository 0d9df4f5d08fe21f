"""``VSWrist/Polish-v1``: press a polishing tool on a surface of uncertain height and tilt while sweeping.

The tool (a capsule, tip radius ``tool_radius``) sweeps sinusoidally in flexion/extension over a flat surface
below it (normal along +Z_b, radial/ulnar deviation presses the tool down). The posture reference presses
``press`` rad beyond the nominal surface; the true surface is off by up to ``height_error`` and tilted by up to
``tilt`` about X_b, so its height changes along the sweep. The episode has 1-3 passes, each with its own target
normal force (observation term ``force_target``); the normal force (touch sensor on the surface) must stay
within ``force_tolerance`` of it. Adapting stiffness pays: the force is roughly stiffness x penetration of the
reference, so every target force needs its own stiffness, and friction drag along the sweep costs FE tracking
on a soft wrist (Phan et al. 2020: human polishers stiffen the wrist as the force level rises).

Success: the force is in band in at least ``success_fraction`` of the steps after ``settle_s``.

``VSWrist/Polish-v1`` (``task.contact_force: period_mean``) reads the normal force as the mean over the control
period's physics substeps of the contact force the surface exerts on the tool, not one sample: while the tool
slides with friction its tip chatters at about 100 Hz by tens of micrometres, and the near-rigid contact then lets
go for single 1 ms substeps (gone without friction or without the sweep; docs/environments.md), so the touch
sensor's end-of-period sample read 0 N on 15-25 % of the steps while the period's mean stays at 5-8 N.
``VSWrist/Polish-v0`` (``last_substep``) keeps that sample, so that results made with it stay reproducible; the
two differ in nothing else.
"""

from __future__ import annotations

import bisect

import mujoco
import numpy as np

from .base import VSWristEnv
from .shared import FINGER_END, PeriodMeanForce, add_mocap_box_body, quat_from_matrix, rot_x, smoothstep

SURFACE_HALF = (0.06, 0.16, 0.01)  # m, half sizes of the surface slab
# task.contact_force -> the id whose force reading it is (CHANGELOG.md)
CONTACT_FORCE_IDS = {"period_mean": "VSWrist/Polish-v1", "last_substep": "VSWrist/Polish-v0"}


class PolishEnv(PeriodMeanForce, VSWristEnv):
    task = "polish"
    summary = "sweep a polishing tool over a surface of uncertain height and tilt, holding a target force per pass"
    success_text = ("normal force within {force_tolerance:g} N of the pass's target force in "
                    ">= {success_fraction:.0%} of the steps after {settle_s:g} s")
    task_spec = {
        "tool_length": ("number", 0.0, 0.3),
        "tool_radius": ("number", 0.001, 0.05),
        "contact_rud": ("interval", -1.5, 1.5),
        "press": ("number", 0.0, 1.0),
        "height_error": ("number", 0.0, 0.1),
        "tilt": ("number", 0.0, 1.0),
        "sweep_amplitude": ("interval", 0.0, 1.5),
        "sweep_period": ("interval", 0.05, 600.0),
        "ps_range": ("interval", -np.pi, np.pi),
        "force_target": ("interval", 0.0, 1e4),
        "force_tolerance": ("number", 0.0, 1e4),
        "passes": ("int_interval", 1, 20),
        "success_fraction": ("number", 0.0, 1.0),
        "settle_s": ("number", 0.0, 600.0),
        "friction": ("number", 0.0, 5.0),
        "contact_force": ("choice", tuple(CONTACT_FORCE_IDS), None),
    }
    task_reward_terms = ("force_band",)
    _pass_start = np.zeros(1)
    _forces = np.zeros(1)
    approach_s = 0.3

    def _validate_task(self) -> None:
        rom = load_rom(self)
        hi = self.tp["contact_rud"][1] + self.tp["press"]
        if hi > rom.rud_max:
            from .config import EnvConfigError
            raise EnvConfigError(f"'task.contact_rud' + 'task.press' = {hi:g} rad exceeds the RUD range of motion "
                                 f"({rom.rud_max:g} rad)")

    def _scene(self, spec) -> None:
        self._tip_x = FINGER_END + self.tp["tool_length"]
        r = self.tp["tool_radius"]
        self._add_tool_geom(spec, "polisher", [0.02, 0, 0, self._tip_x, 0, 0], r, 0.06, self.tp["friction"])
        body = add_mocap_box_body(spec, "task_surface", [(SURFACE_HALF, (0, 0, -SURFACE_HALF[2]), None)],
                                  friction=self.tp["friction"])
        hx, hy, hz = SURFACE_HALF
        self._add_touch_sensor(spec, body, "surface_touch", (hx, hy, hz + 0.01), pos=(0, 0, -hz + 0.01))
        self._add_contact_meter(spec, body, "task_task_surface_0")

    def _scene_ids(self) -> None:
        self._touch_adr = self._sensor_adr("surface_touch")
        self._mocap = int(self.model.body("task_surface").mocapid[0])
        self._surface_geom = int(self.model.geom("task_task_surface_0").id)
        self._find_contact_meter()

    @property
    def task_id(self) -> str:
        return CONTACT_FORCE_IDS[self.tp["contact_force"]]

    def _contact_force(self) -> float:
        mean = super()._contact_force()  # the period's mean; restarts its sums either way
        if self.tp["contact_force"] == "last_substep":
            return self._last_substep_force()
        return mean

    def _task_reset(self, rng):
        self._rud_c = float(rng.uniform(*self.tp["contact_rud"]))
        self._amp = float(rng.uniform(*self.tp["sweep_amplitude"]))
        self._period = float(rng.uniform(*self.tp["sweep_period"]))
        self._sweep_phase = float(rng.uniform(0, 2 * np.pi))
        self._ps = float(rng.uniform(*self.tp["ps_range"]))
        self._dz = float(rng.uniform(-1, 1)) * self.tp["height_error"]
        self._tilt = float(rng.uniform(-1, 1)) * self.tp["tilt"]
        rom = load_rom(self)
        self._amp = min(self._amp, rom.fe_max - 0.05, -rom.fe_min - 0.05)
        self._u_start = np.array([self._rud_c - 0.15, self._fe(0.0)])
        self._in_band: list[bool] = []
        n = int(rng.integers(self.tp["passes"][0], self.tp["passes"][1] + 1))
        T = self.cfg["episode_s"]
        self._pass_start = np.concatenate([[0.0], np.sort(rng.uniform(0.25 * T, 0.8 * T, n - 1))])
        self._forces = rng.uniform(*self.tp["force_target"], n)
        return self._u_start, self._ps, float(rng.uniform(-1.0, 1.0))

    def _fe(self, t: float) -> float:
        return self._amp * np.sin(2 * np.pi * t / self._period + self._sweep_phase)

    def _after_reset(self) -> None:
        # nominal contact point: the lowest point of the tool tip at RUD = contact_rud, FE = 0
        tip = self.tool_point(np.array([self._rud_c, 0.0]), self._ps, np.array([self._tip_x, 0.0, 0.0]))
        p0 = tip - np.array([0.0, 0.0, self.tp["tool_radius"]]) + np.array([0.0, 0.0, self._dz])
        R = rot_x(self._tilt)
        self.data.mocap_pos[self._mocap] = p0
        self.data.mocap_quat[self._mocap] = quat_from_matrix(R)
        self._surface = (p0, R[:, 2])

    def _reference(self, t) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        rud_goal = self._rud_c + self.tp["press"]
        rud = self._u_start[0] + smoothstep(t / self.approach_s) * (rud_goal - self._u_start[0])
        return np.stack([rud, self._fe(t), np.full_like(t, self._ps)], axis=-1)

    def _task_obs_terms(self):
        from .observations import ObsTerm
        return [ObsTerm("force_target", 1, "N", "target normal force of the current pass", self.force_target,
                        0.0, 1e4)]

    def force_target(self) -> float:
        """Target normal force (N) of the pass under way."""
        k = bisect.bisect_right(self._pass_start, self._t) - 1  # = np.searchsorted(..., side="right") - 1
        return float(self._forces[max(k, 0)])

    def force_band(self) -> tuple[float, float]:
        f, tol = self.force_target(), self.tp["force_tolerance"]
        return max(f - tol, 0.0), f + tol

    def _task_reward_terms(self, err) -> dict:
        lo, hi = self.force_band()
        f = self._contact
        self._in_band.append(lo <= f <= hi)
        out = max(lo - f, 0.0, f - hi)
        return {"force_band": -out / self.cfg["scales"]["force"]}

    def _tracking_error(self, err):
        return err[..., 1:]  # RUD is pressed into the surface on purpose: track FE and PS

    def _success(self) -> bool:
        k = self._window(self.tp["settle_s"])
        band = self._in_band[k:]
        return bool(band) and float(np.mean(band)) >= self.tp["success_fraction"]


def load_rom(env):
    return env.nominal_params.range_of_motion
