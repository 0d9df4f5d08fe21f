"""``VSWrist/LoadHold-v2`` (and ``-v1``, ``-v0``): hold posture references while an unknown load acts on the hand.

The paper's experiment (1.5 kg at the hand from 0.5 s), generalised: 1-3 piecewise-constant posture references
(smooth 0.6 s transitions), a load of random mass, onset time and direction (its angle from gravity drawn
uniformly up to ``load_cone``) applied at the hand centre. In v1 and v0 the load hangs within 0.6 rad of gravity,
so its mean is a downward force whose sag (about 0.056 rad in RUD at s = +0.5) a fixed posture trim removes; v2
draws the angle over [0, pi], a push or pull of any direction with zero mean, so that only a stiffer wrist, not
a posture offset, keeps the load's error small. Adapting stiffness pays: before the load arrives a soft wrist holds the posture
without preload energy; after it arrives only a stiff wrist keeps the posture error small. In v1 the
observation's ``load_cue`` announces the load ``cue_lead_s`` ahead, so that an agent can be stiff in time; v0 (the
same task, its observation without the cue) leaves the onset to be seen in the posture error, too late to stiffen.

Success: RMS (RUD, FE) error over the last ``success_window`` s below ``success_error`` and mean elastic energy
below ``success_energy``.
"""

from __future__ import annotations

import numpy as np

from ..sim import WristSim
from .base import VSWristEnv
from .episode import episode_history, task_field
from .shared import smoothstep


class LoadHoldEnv(VSWristEnv):
    task = "load_hold"
    reads_sensors = False  # the load is known to the task; it reads poses only (see VSWristEnv.reads_sensors)

    @property
    def summary(self) -> str:
        text = "track posture references while an unknown load (mass, onset, direction) hangs on the hand"
        if self.tp["load_cone"] >= np.pi:
            text = "track posture references while an unknown load (mass, onset, any direction) acts on the hand"
        return text + "; `load_cue` announces it 0.5 s ahead" if "load_cue" in self.cfg["observation"] else text

    @property
    def task_id(self) -> str:
        """v1 announces the load in its observation (``load_cue``); v0 is the same task without the cue; v2 is v1
        with the load in any direction (``load_cone`` pi)."""
        if "load_cue" not in self.cfg["observation"]:
            return "VSWrist/LoadHold-v0"
        return "VSWrist/LoadHold-v2" if self.tp["load_cone"] >= np.pi else "VSWrist/LoadHold-v1"

    success_text = ("RMS RUD/FE error over the last {success_window:g} s < {success_error:g} rad and mean "
                    "elastic energy < {success_energy:g} J")
    task_spec = {
        "target_fraction": ("number", 0.0, 1.0),
        "ps_range": ("interval", -np.pi, np.pi),
        "n_targets": ("int_interval", 1, 10),
        "load_mass": ("interval", 0.0, 10.0),
        "load_onset": ("interval", 0.0, 600.0),
        "load_cone": ("number", 0.0, np.pi),
        "success_error": ("number", 0.0, 10.0),
        "success_window": ("number", 0.0, 600.0),
        "success_energy": ("number", 0.0, 1e6),
    }
    blend_s = 0.6  # s, minimum-jerk transition between references (slower would hide the load's effect)
    # s: the ``load_cue`` term turns on this long before the load arrives, the time the stiffness command needs to
    # cross its whole range at the rules' slew limit (probe.SLEW, 4 /s), so that a policy reading it can be stiff
    # when the load comes and soft (no preload energy) until shortly before
    cue_lead_s = 0.5

    @property
    def task_state(self) -> dict:
        """The episode's draws: its references (``n_targets`` of the rows of ``targets``, rad, and the times at
        which each next one begins, ``switch``, s) and its load (``mass``, kg; ``onset``, s; ``load_force``, N)."""
        n = self.tp["n_targets"][1]
        return {"targets": ((n, 3), float), "switch": ((n - 1,), float), "n_targets": ((), np.int64),
                "mass": ((), float), "onset": ((), float), "load_force": ((3,), float)}

    _mass, _onset, _load_force = task_field("mass"), task_field("onset"), task_field("load_force")

    def _task_obs_terms(self):
        from .observations import ObsTerm, flag_column
        lead = self.cue_lead_s
        return [ObsTerm("load_cue", 1, "-", f"1 from {lead:g} s before the load arrives on (the announced load: "
                        "LoadHold-v1 on), else 0", None, 0.0, 1.0,
                        lambda m: flag_column(m.time + 1e-12 >= m.state("onset") - lead))]

    def _sample_posture(self, rng) -> np.ndarray:
        f = self.tp["target_fraction"]
        lo, hi = self.posture_map.lo, self.posture_map.hi
        mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
        u = mid[:2] + f * half[:2] * rng.uniform(-1.0, 1.0, 2)
        return np.append(u, rng.uniform(*self.tp["ps_range"]))

    def _task_reset(self, rng):
        n = int(rng.integers(self.tp["n_targets"][0], self.tp["n_targets"][1] + 1))
        targets = np.array([self._sample_posture(rng) for _ in range(n)])
        targets[1:, 2] = targets[0, 2]  # one PS angle per episode: the load acts on RUD/FE, and PS steps are slow
        T = self.cfg["episode_s"]
        switch = np.sort(rng.uniform(0.2 * T, 0.8 * T, n - 1)) if n > 1 else np.zeros(0)
        mass = float(rng.uniform(*self.tp["load_mass"]))
        onset = float(rng.uniform(*self.tp["load_onset"]))
        g = np.asarray(self.params.environment.gravity, dtype=float)
        gn = np.linalg.norm(g)
        down = g / gn if gn > 0 else np.array([0.0, 0.0, -1.0])
        # a direction within load_cone of gravity: tilt 'down' by a random angle about a random perpendicular axis
        perp = np.cross(down, rng.normal(size=3))
        perp /= np.linalg.norm(perp)
        ang = rng.uniform(0.0, self.tp["load_cone"])
        direction = np.cos(ang) * down + np.sin(ang) * np.cross(perp, down)
        ts = self._ep.task  # this world's row (its unused targets stay zeros)
        ts.targets[0, :n], ts.switch[0, :n - 1] = targets, switch
        ts.put(0, n_targets=n, mass=mass, onset=onset, load_force=mass * max(gn, 9.81) * direction)
        return targets[0, :2], float(targets[0, 2]), float(rng.uniform(-1.0, 1.0))

    def _reference(self, t) -> np.ndarray:
        t = np.asarray(t, dtype=float)[..., None]
        ts = self._ep.task
        n = ts.n_targets.item(0)
        targets = ts.targets[0, :n]
        ref = np.broadcast_to(targets[0], t.shape[:-1] + (3,))
        for k, start in enumerate(ts.switch[0, :n - 1]):
            step = smoothstep((t - start) / self.blend_s) * (targets[k + 1] - targets[k])
            ref = np.where(t > start, ref + step, ref)
        return np.array(ref)

    @classmethod
    def _before_physics_worlds(cls, worlds: list, ep, ids) -> None:
        on = load_on(ep.t[ids], ep.task.onset[ids])
        if on.size:
            WristSim.apply_wrenches([worlds[k].sim for k in on.tolist()], load_wrench(ep.task.load_force[ids][on]))

    def load_info(self) -> dict:
        """The episode's hidden load (for analysis, not for the agent): mass kg, onset s, force N."""
        return {"mass": self._mass, "onset": self._onset, "force": self._load_force.copy()}

    @classmethod
    def _success_worlds(cls, worlds: list, ep, ids) -> np.ndarray:
        tp = worlds[0].tp
        err, energy, _ = episode_history(ep, ids)
        return hold_success(err, energy, worlds[0]._window(tp["success_window"]), tp["success_error"],
                            tp["success_energy"])


def load_on(t, onset) -> np.ndarray:
    """The worlds (indices) whose load acts in the control period that starts at their time ``t``: from the first
    period that starts at or after their ``onset``."""
    return np.flatnonzero(t + 1e-12 >= onset)


def load_wrench(force) -> np.ndarray:
    """The wrenches (M, 6) of load forces ``force`` (M, 3) at the hand centre (no torque)."""
    return np.concatenate([force, np.zeros_like(force)], axis=1)


def hold_success(err, energy, window: int, max_error: float, max_energy: float) -> np.ndarray:
    """Whether each world held its references (L,): the RMS (RUD, FE) error over the last ``window`` steps of its
    errors ``err`` (L, k, 3) below ``max_error`` and its mean stored energy ``energy`` (L, k) below ``max_energy``."""
    e = err[:, -window:, :2]
    rms = np.sqrt(np.mean(np.sum(e ** 2, axis=2), axis=1))
    return (rms < max_error) & (np.mean(energy, axis=1) < max_energy)
