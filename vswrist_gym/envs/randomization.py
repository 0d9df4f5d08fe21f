"""Domain randomisation at reset: device parameters (rebuild the world's model), tool mass, friction, latency,
sensor noise; each draw from the env's own generator, so world i of a batch draws as ``gym.make`` with seed s + i."""

from __future__ import annotations

import numpy as np

DEVICE_TERMS = ("spring_K", "spring_delta0", "motor_time_constant", "link_mass", "hand_mass", "damping")


class RandomizationMixin:
    """``_randomize``: called by ``reset`` before the task samples its episode."""

    def _randomize(self) -> None:
        rnd = self.cfg["randomize"]
        rng = self.np_random

        def factor(term):
            spec = rnd[term]
            return float(rng.uniform(*spec["range"])) if spec["enabled"] else 1.0

        if any(rnd[t]["enabled"] for t in DEVICE_TERMS):
            p = self.nominal_params
            f = {t: factor(t) for t in DEVICE_TERMS}
            params = p.replace(
                spring={"K": p.spring.K * f["spring_K"], "delta0": p.spring.delta0 * f["spring_delta0"]},
                motor={"time_constant": p.motor.time_constant * f["motor_time_constant"]},
                inertia={"link_mass": [m * f["link_mass"] for m in p.inertia.link_mass],
                         "link_inertia": [i * f["link_mass"] for i in p.inertia.link_inertia],
                         "hand_mass": p.inertia.hand_mass * f["hand_mass"]},
                damping={"leg_joint": p.damping.leg_joint * f["damping"],
                         "ps_joint": p.damping.ps_joint * f["damping"]})
            self._close_renderer()
            self._build_sim(params)
        ft = factor("tool_mass")
        self.model.body_mass[self._tool_body] = self._nominal_tool_mass * ft
        self.model.body_inertia[self._tool_body] = self._nominal_tool_inertia * ft
        ff = factor("friction")
        if self._task_geoms.size:
            self.model.geom_friction[self._task_geoms] = self._nominal_friction * ff
        lat = rnd["latency"]
        # latency in whole physics steps, at most one step short of the control period
        dt = float(self.model.opt.timestep)
        steps = int(round(float(rng.uniform(*lat["range"])) / dt)) if lat["enabled"] else 0
        self._ep.latency[0] = min(steps, self.n_substeps - 1)
        noise = rnd["sensor_noise"]
        self._noise_std = {k: float(noise[k]) for k in ("posture", "posture_rate", "force", "torque")} \
            if noise["enabled"] else None
        if self._noise_std is not None:
            self._noise_scale = np.array([self._noise_std[k] for k in self._NOISE_LAYOUT])
