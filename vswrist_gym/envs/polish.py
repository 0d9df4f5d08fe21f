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

import mujoco
import numpy as np

from .base import VSWristEnv
from .episode import at_step, episode_history, task_field
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
    approach_s = 0.3
    start_above = 0.15  # rad: the episode starts this much RUD short of the contact posture, above the surface

    @property
    def task_state(self) -> dict:
        """The episode's draws: the contact posture (``rud_c``, rad), the sweep (``amp``, rad; ``period``, s;
        ``sweep_phase``, rad), ``ps`` (rad), the surface's offsets from nominal (``dz``, m; ``tilt``, rad about X_b),
        and the passes' target forces as a table over the episode's control instants (``force_target``, N: the
        target of the pass under way at k ctrl_dt, computed at reset as the posture references are)."""
        return {"rud_c": ((), float), "amp": ((), float), "period": ((), float), "sweep_phase": ((), float),
                "ps": ((), float), "dz": ((), float), "tilt": ((), float),
                "force_target": ((self.episode_steps + 1,), float)}

    _rud_c, _amp, _period, _sweep_phase, _ps, _dz, _tilt = map(
        task_field, ("rud_c", "amp", "period", "sweep_phase", "ps", "dz", "tilt"))

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

    @classmethod
    def _contact_force_worlds(cls, worlds: list, ep, ids) -> np.ndarray:
        mean = super()._contact_force_worlds(worlds, ep, ids)  # the period's mean; restarts its sums either way
        if worlds[0].tp["contact_force"] == "last_substep":
            return np.array([e._last_substep_force() for e in worlds], dtype=float)
        return mean

    def _task_reset(self, rng):
        tp = self.tp
        rud_c = float(rng.uniform(*tp["contact_rud"]))
        amp = float(rng.uniform(*tp["sweep_amplitude"]))
        period = float(rng.uniform(*tp["sweep_period"]))
        sweep_phase = float(rng.uniform(0, 2 * np.pi))
        ps = float(rng.uniform(*tp["ps_range"]))
        dz = float(rng.uniform(-1, 1)) * tp["height_error"]
        tilt = float(rng.uniform(-1, 1)) * tp["tilt"]
        rom = load_rom(self)
        amp = min(amp, rom.fe_max - 0.05, -rom.fe_min - 0.05)
        n = int(rng.integers(tp["passes"][0], tp["passes"][1] + 1))
        T = self.cfg["episode_s"]
        pass_start = np.concatenate([[0.0], np.sort(rng.uniform(0.25 * T, 0.8 * T, n - 1))])
        forces = rng.uniform(*tp["force_target"], n)
        targets = pass_targets(pass_start, forces, np.arange(self.episode_steps + 1) * self.ctrl_dt)
        self._ep.task.put(0, rud_c=rud_c, amp=amp, period=period, sweep_phase=sweep_phase, ps=ps, dz=dz, tilt=tilt,
                          force_target=targets)
        return np.array([rud_c - self.start_above, self._fe(0.0)]), ps, float(rng.uniform(-1.0, 1.0))

    def _fe(self, t: float) -> float:
        return self._amp * np.sin(2 * np.pi * t / self._period + self._sweep_phase)

    def _after_reset(self) -> None:
        # nominal contact point: the lowest point of the tool tip at RUD = contact_rud, FE = 0
        tip = self.tool_point(np.array([self._rud_c, 0.0]), self._ps, np.array([self._tip_x, 0.0, 0.0]))
        p0 = tip - np.array([0.0, 0.0, self.tp["tool_radius"]]) + np.array([0.0, 0.0, self._dz])
        self.data.mocap_pos[self._mocap] = p0
        self.data.mocap_quat[self._mocap] = quat_from_matrix(rot_x(self._tilt))

    def _reference(self, t) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        rud_goal = self._rud_c + self.tp["press"]
        rud0 = self._rud_c - self.start_above
        rud = rud0 + smoothstep(t / self.approach_s) * (rud_goal - rud0)
        return np.stack([rud, self._fe(t), np.full_like(t, self._ps)], axis=-1)

    def _task_obs_terms(self):
        from .observations import ObsTerm, column
        return [ObsTerm("force_target", 1, "N", "target normal force of the current pass", None, 0.0, 1e4,
                        lambda m: column(m.state_at_step("force_target")))]

    def force_target(self) -> float:
        """Target normal force (N) of the pass under way."""
        return self._ep.task.force_target.item(0, self._step)

    def force_band(self) -> tuple[float, float]:
        """The band (lo, hi) (N) the normal force must stay in now."""
        lo, hi = target_band(self.force_target(), self.tp["force_tolerance"])
        return float(lo), float(hi)

    @classmethod
    def _task_reward_terms_worlds(cls, worlds: list, ep, ids, err) -> dict:
        lo, hi = target_band(at_step(ep, ids, ep.task.force_target), worlds[0].tp["force_tolerance"])
        f = ep.contact[ids]
        return {"force_band": -np.maximum(np.maximum(lo - f, 0.0), f - hi) / worlds[0].cfg["scales"]["force"]}

    def _tracking_error(self, err):
        return err[..., 1:]  # RUD is pressed into the surface on purpose: track FE and PS

    @classmethod
    def _success_worlds(cls, worlds: list, ep, ids) -> np.ndarray:
        tp = worlds[0].tp
        _, _, f = episode_history(ep, ids)
        # history row j is step j + 1, whose target is the table's entry j + 1
        lo, hi = target_band(ep.task.force_target[ids, 1:f.shape[1] + 1], tp["force_tolerance"])
        band = ((lo <= f) & (f <= hi))[:, worlds[0]._window(tp["settle_s"]):]
        if band.shape[1] == 0:
            return np.zeros(len(band), dtype=bool)
        return np.mean(band, axis=1) >= tp["success_fraction"]


def pass_targets(pass_start, forces, t) -> np.ndarray:
    """The target force (N) at times ``t`` (s) of one episode whose passes start at ``pass_start`` (sorted, the first
    at 0) with target forces ``forces``: the last pass that started at or before t."""
    return forces[np.searchsorted(pass_start, t, side="right") - 1]


def target_band(target, tolerance: float):
    """The band (lo, hi) (N) the normal force must stay in around ``target`` (N), never below 0."""
    return np.maximum(target - tolerance, 0.0), target + tolerance


def load_rom(env):
    return env.nominal_params.range_of_motion
