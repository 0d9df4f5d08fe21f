"""``VSWrist/Drill-v2`` (and ``-v1``, ``-v0``): hold the tool's posture against an oscillating torque and an axial
thrust while the PS motor turns the tool.

The drill bit is a capsule on the tool. While the drill is engaged (random onset and duration) the hand feels
a torque A sin(2 pi f t + phi) about a random axis perpendicular to the tool and a thrust F along the tool
towards the wrist (the reaction of the workpiece); the PS reference turns at constant speed. Adapting
stiffness pays: the disturbance acts for only part of the episode, and preload energy is worth paying only
while it does. In v1 the observation's ``engage_cue`` announces the engagement ``cue_lead_s`` ahead and stays on
until the drill releases; v0 (the same task, its observation without the cue) leaves the engagement to be seen in
the tool wrench and the posture error, too late to stiffen. In v2 (v1 with ``compensate_tool``) the controller's
gravity compensation also holds the drill's nominal weight, known to whoever hands the agent the drill: v1 and v0
leave it uncompensated, a static RUD error of about 0.009 rad at s = +0.5 that a fixed posture offset removes.

Success: RMS (RUD, FE) error while engaged below ``success_error`` and mean elastic energy below
``success_energy``.
"""

from __future__ import annotations

import numpy as np

from ..sim import WristSim
from .base import VSWristEnv
from .episode import episode_history, task_field
from .shared import FINGER_END


class DrillEnv(VSWristEnv):
    task = "drill"

    @property
    def summary(self) -> str:
        text = "hold the posture against an oscillating torque and an axial thrust while the PS motor turns the tool"
        return f"{text}; `engage_cue` announces the drill 0.5 s ahead" if "engage_cue" in self.cfg["observation"] \
            else text

    @property
    def task_id(self) -> str:
        """v1 announces the drill in its observation (``engage_cue``); v0 is the same task without the cue; v2 is
        v1 with the drill's nominal weight compensated (``compensate_tool``)."""
        if "engage_cue" not in self.cfg["observation"]:
            return "VSWrist/Drill-v0"
        return "VSWrist/Drill-v2" if self.cfg["compensate_tool"] else "VSWrist/Drill-v1"

    success_text = ("RMS RUD/FE error while engaged < {success_error:g} rad and mean elastic energy "
                    "< {success_energy:g} J")
    task_spec = {
        "tool_length": ("number", 0.0, 0.3),
        "tool_radius": ("number", 0.001, 0.05),
        "target_fraction": ("number", 0.0, 1.0),
        "ps_speed": ("interval", 0.0, 10.0),
        "torque_amplitude": ("interval", 0.0, 100.0),
        "torque_frequency": ("interval", 0.0, 25.0),
        "axial_force": ("interval", 0.0, 1000.0),
        "engage_s": ("interval", 0.0, 600.0),
        "engaged_for": ("interval", 0.0, 600.0),
        "success_error": ("number", 0.0, 10.0),
        "success_energy": ("number", 0.0, 1e6),
    }

    # s: the ``engage_cue`` term turns on this long before the drill engages (the spindle spinning up), the time the
    # stiffness command needs to cross its whole range at the rules' slew limit (probe.SLEW, 4 /s)
    cue_lead_s = 0.5

    # the episode's draws: the posture held (``u``, RUD and FE, rad) and the PS turn (start ``ps0``, rad; speed
    # ``ps_speed``, rad/s), the drill's engagement (``t_on`` to ``t_off``, s), its torque (``amp``, N m;
    # ``freq``, Hz; ``phase``, rad; about ``axis``, a unit vector of the coupler frame) and ``thrust`` (N); and
    # whether the drill is engaged in the period under way (``engaged``)
    task_state = {"u": ((2,), float), "ps0": ((), float), "ps_speed": ((), float), "t_on": ((), float),
                  "t_off": ((), float), "amp": ((), float), "freq": ((), float), "phase": ((), float),
                  "axis": ((3,), float), "thrust": ((), float), "engaged": ((), bool)}
    _u, _ps0, _ps_speed, _t_on, _t_off = map(task_field, ("u", "ps0", "ps_speed", "t_on", "t_off"))

    def _task_obs_terms(self):
        from .observations import ObsTerm, flag_column
        lead = self.cue_lead_s

        def engage_cue(m):
            t = m.time + 1e-12
            return flag_column((m.state("t_on") - lead <= t) & (t < m.state("t_off")))

        return [ObsTerm("engage_cue", 1, "-", f"1 from {lead:g} s before the drill engages until it releases (the "
                        "announced drill: Drill-v1 on), else 0", None, 0.0, 1.0, engage_cue)]

    def _scene(self, spec) -> None:
        L = FINGER_END + self.tp["tool_length"]
        self._add_tool_geom(spec, "drill_bit", [0.02, 0, 0, L, 0, 0], self.tp["tool_radius"], 0.08)

    def _task_reset(self, rng):
        f = self.tp["target_fraction"]
        lo, hi = self.posture_map.lo, self.posture_map.hi
        mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
        u = mid[:2] + f * half[:2] * rng.uniform(-1.0, 1.0, 2)
        T = self.cfg["episode_s"]
        speed = float(rng.uniform(*self.tp["ps_speed"])) * (1.0 if rng.random() < 0.5 else -1.0)
        sweep = abs(speed) * T
        room = max(0.0, (hi[2] - lo[2]) - sweep)
        start = lo[2] + rng.uniform(0.0, room) if room > 0 else lo[2]
        ps0 = start if speed > 0 else hi[2] - (start - lo[2])
        t_on = float(rng.uniform(*self.tp["engage_s"]))
        t_off = t_on + float(rng.uniform(*self.tp["engaged_for"]))
        amp = float(rng.uniform(*self.tp["torque_amplitude"]))
        freq = float(rng.uniform(*self.tp["torque_frequency"]))
        phase = float(rng.uniform(0.0, 2 * np.pi))
        axis_angle = float(rng.uniform(0.0, 2 * np.pi))
        thrust = float(rng.uniform(*self.tp["axial_force"]))
        self._ep.task.put(0, u=u, ps0=ps0, ps_speed=speed, t_on=t_on, t_off=t_off, amp=amp, freq=freq, phase=phase,
                          axis=(0.0, np.cos(axis_angle), np.sin(axis_angle)), thrust=thrust)
        return u, ps0, float(rng.uniform(-1.0, 1.0))

    ramp_s = 1.0  # s, the PS speed ramps up smoothly (constant acceleration) over this time

    def _ps_travel(self, t):
        r = self.ramp_s
        return self._ps_speed * np.where(t < r, 0.5 * t * t / r, t - 0.5 * r)

    def _reference(self, t) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        lo, hi = self.posture_map.lo[2], self.posture_map.hi[2]
        ps = np.minimum(np.maximum(self._ps0 + self._ps_travel(t), lo), hi)
        return np.stack([np.full_like(t, self._u[0]), np.full_like(t, self._u[1]), ps], axis=-1)

    @classmethod
    def _before_physics_worlds(cls, worlds: list, ep, ids) -> None:
        # the wrench is held over the period: sample it at the period's middle
        ts = ep.task
        tc = ep.t[ids] + 0.5 * worlds[0].ctrl_dt
        on = (ts.t_on[ids] <= tc) & (tc < ts.t_off[ids])
        ts.put(ids, engaged=on)
        load = (ts.amp[ids], ts.freq[ids], ts.phase[ids], ts.thrust[ids], ts.axis[ids])
        if on.all():  # every world engaged (the single env, while it drills): no selection
            wrench = drill_wrench(cls._coupler_frames(worlds), tc, *load)
        else:
            wrench = np.zeros((len(worlds), 6))
            if on.any():
                k = np.flatnonzero(on)
                wrench[k] = drill_wrench(cls._coupler_frames([worlds[j] for j in k.tolist()]), tc[k],
                                         *(x[k] for x in load))
        WristSim.apply_wrenches([e.sim for e in worlds], wrench)

    @staticmethod
    def _coupler_frames(ws: list) -> np.ndarray:
        """The coupler frames (M, 3, 3) of the worlds ``ws``, as their simulators stand."""
        for e in ws:
            if e.sim._stale:  # poses are current after a step; not after a diverged one's reset
                e.sim._forward()
        return np.array([e.sim._coupler_xmat for e in ws]).reshape(-1, 3, 3)

    @classmethod
    def _contact_force_worlds(cls, worlds: list, ep, ids) -> np.ndarray:
        """The thrust of the workpiece on the bit (N) while engaged."""
        ts = ep.task
        return np.where(ts.engaged[ids], ts.thrust[ids], 0.0)

    def _tracking_error(self, err):
        return err[..., :2]  # PS is the tool turning; the disturbance acts on RUD/FE

    @classmethod
    def _success_worlds(cls, worlds: list, ep, ids) -> np.ndarray:
        tp = worlds[0].tp
        err, energy, _ = episode_history(ep, ids)
        t = (np.arange(err.shape[1]) + 1) * worlds[0].ctrl_dt
        rms = np.array([engaged_rms(e, t, t_on, t_off)
                        for e, t_on, t_off in zip(err, ep.task.t_on[ids].tolist(), ep.task.t_off[ids].tolist())])
        return (rms < tp["success_error"]) & (np.mean(energy, axis=1) < tp["success_energy"])


def drill_wrench(R, tc, amp, freq, phase, thrust, axis) -> np.ndarray:
    """The drill's wrench (M, 6) on worlds whose coupler frames are ``R`` (M, 3, 3), at times ``tc`` (s): the
    thrust (N) along -X_c and the torque amp sin(2 pi freq tc + phase) (N m) about ``axis`` (M, 3, coupler
    frame)."""
    torque = (amp * np.sin(2 * np.pi * freq * tc + phase))[:, None] * np.matmul(R, axis[:, :, None])[:, :, 0]
    return np.concatenate([-thrust[:, None] * R[:, :, 0], torque], axis=1)


def engaged_rms(err, t, t_on: float, t_off: float) -> float:
    """One world's RMS (RUD, FE) error (rad) over the steps at times ``t`` (s) while its drill was engaged (after
    ``t_on``, up to ``t_off``), from its posture errors ``err`` (k, 3); 0 if none."""
    on = (t > t_on) & (t <= t_off)
    return float(np.sqrt(np.mean(np.sum(err[on, :2] ** 2, axis=1)))) if on.any() else 0.0
