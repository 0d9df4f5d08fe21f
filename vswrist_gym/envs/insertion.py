"""``VSWrist/Insertion-v0``: push a pin into a chamfered hole whose position and axis are off nominal.

The tool is L-shaped: an arm along the hand's X axis and a pin perpendicular to it, pointing down (-Z_b) at
PS = 0, so radial/ulnar deviation drives the pin along its own axis (the pin is inclined so that it is tangent
to its arc of motion half-way into the hole). PS stays at 0: at any other PS the pin leaves the plane of its
RUD path and stands tilted in the hole. The hole (square, radial clearance ``clearance``, chamfered) stands
below the pin at a random nominal FE; its true position is off nominal by up to ``lateral_error`` along Y_b
(which FE corrects) and its axis by up to ``angular_error`` about X_b (which PS corrects). The posture
reference ramps from above the nominal hole to ``overdrive`` rad beyond full depth. At ``fit_depth`` of the
hole the pin meets the fit (a latch or press fit): a plate across the hole on a slide joint whose Coulomb
friction, ``fit_force``, resists being pushed down to the bottom (MuJoCo treats the friction implicitly: the
fit holds still below that force, never pushes back, never rings).

Adapting stiffness pays: at the task's reference the soft wrist cannot push past the fit (its springs give
less than ``fit_force`` at the remaining RUD error; a deeper posture reference can), and the stiff one pays
preload energy all episode and presses the pin against the walls (wall force ~ stiffness x misalignment); soft
while approaching and stiff only while pushing the fit down beats every constant stiffness
(``python -m vswrist_gym.tools.probe --tasks Insertion``).

Contact forces: ``contact_force`` (and the ``jamming`` term) is the normal force of the walls and chamfers on
the tool; the fit plate has its own sensor, ``bottom_force``.

Depth: how far the pin's end is below the hole entrance along the hole axis while it is inside the hole
(laterally within the clearance).

Success (what an insertion means: the pin seated, the assembly unharmed, the preload not held all episode):
at the last step the pin's end is inside the hole between ``success_depth`` x ``hole_depth`` and the bottom
(``SEAT_SLACK`` past it at most: deeper, the pin is beside or under the hole, not in it), the wall force never
exceeded ``success_wall_force`` over the episode, and the mean elastic energy stays below ``success_energy``.
Flailing reaches the depth (it swings the pin under the hole or rams it through the fit with wall forces of
hundreds of N), so depth alone would reward it (``python -m vswrist_gym.tools.probe --success``).
"""

from __future__ import annotations

import mujoco
import numpy as np

from .base import VSWristEnv
from .config import EnvConfigError
from .episode import ONE, episode_history, task_field
from .rewards import FORCE_CAP
from .shared import (CONTACT_SOLREF, FINGER_END, add_mocap_box_body, frame_from_z, quat_from_matrix, rot_x, rot_y,
                     sensor_values)

WALL = 0.008      # m, half thickness of the walls around the hole
PLATE = 0.02      # m, half extent of the walls beyond the hole
SEAT_SLACK = 0.002  # m, how far past the hole bottom a seated pin's end may read: the soft contact and joint
                   # limit let a pin pressed on the bottom sink 0.8 mm at most (100 episodes of each of the
                   # probe's schedules, 2026-12-02); random actions drive it 2 mm and more past, beside or under


class InsertionEnv(VSWristEnv):
    task = "insertion"
    task_id = "VSWrist/Insertion-v0"
    summary = "insert a pin into a chamfered hole with lateral and angular misalignment; depth against jamming"
    success_text = ("at the end the pin's end seated between {success_depth:.0%} of the hole depth and the bottom, "
                    "peak wall force <= {success_wall_force:g} N and mean elastic energy < {success_energy:g} J")
    task_spec = {
        "tool_length": ("number", 0.0, 0.3),
        "pin_length": ("number", 0.005, 0.1),
        "pin_radius": ("number", 0.001, 0.02),
        "clearance": ("number", 0.0001, 0.02),
        "hole_depth": ("number", 0.002, 0.1),
        "chamfer": ("number", 0.0, 0.05),
        "hole_fe": ("interval", -1.5, 1.5),
        "start_rud": ("number", -1.5, 1.5),
        "entry_rud": ("number", -1.5, 1.5),
        "overdrive": ("number", 0.0, 1.0),
        "lateral_error": ("number", 0.0, 0.05),
        "angular_error": ("number", 0.0, 1.0),
        "approach_s": ("number", 0.02, 600.0),
        "success_depth": ("number", 0.0, 1.0),
        "success_wall_force": ("number", 0.0, 1e5),
        "success_energy": ("number", 0.0, 1e6),
        "friction": ("number", 0.0, 5.0),
        "fit_force": ("interval", 0.0, 1000.0),
        "fit_depth": ("number", 0.0, 1.0),
    }
    task_reward_terms = ("depth", "jamming")
    PS = 0.0  # rad, the PS reference: the RUD path of the pin tip lies in the plane of the pin only at PS = 0
    # the episode's draws: the hole's nominal FE (``fe``, rad), its true pose's offsets from nominal (``lat``, m
    # along Y_b; ``ang``, rad about X_b) and the fit's force (``fit``, N); the hole as placed (``entrance``, m, and
    # its axes ``hole_R``, Z out of the hole)
    task_state = {"fe": ((), float), "lat": ((), float), "ang": ((), float), "fit": ((), float),
                  "entrance": ((3,), float), "hole_R": ((3, 3), float)}
    _fe, _lat, _ang, _fit, _entrance, _hole_R = map(task_field, task_state)

    def _validate_task(self) -> None:
        if self.tp["entry_rud"] <= self.tp["start_rud"]:
            raise EnvConfigError("'task.entry_rud' must be above 'task.start_rud' (RUD drives the pin down)")

    # ------------------------------------------------------------------ geometry
    def _pin_geometry(self) -> tuple[np.ndarray, np.ndarray]:
        """Pin base and unit direction in the tool frame: tangent to the pin tip's arc half-way into the hole."""
        a = np.array([FINGER_END + self.tp["tool_length"], 0.0, 0.0])
        v = np.array([0.0, 0.0, -1.0])
        h = self.tp["pin_length"]
        rud_mid = self._rud_at_depth(0.5, a, v)
        for _ in range(4):
            eps = 1e-4
            p1 = self.tool_point(np.array([rud_mid + eps, 0.0]), 0.0, a + h * v)
            p0 = self.tool_point(np.array([rud_mid - eps, 0.0]), 0.0, a + h * v)
            d = (p1 - p0) / np.linalg.norm(p1 - p0)
            R = self._kin.coupler_pose(np.array([rud_mid, 0.0]), allow_outside=True)[:3, :3]
            v = R.T @ d
            rud_mid = self._rud_at_depth(0.5, a, v)
        return a, v

    def _rud_at_depth(self, frac: float, a, v) -> float:
        """RUD (nominal FE, PS = 0) at which the pin tip is ``frac`` of the hole depth past the entrance."""
        h = self.tp["pin_length"]
        e = self.tp["entry_rud"]
        tip = lambda rud: self.tool_point(np.array([rud, 0.0]), 0.0, a + h * v)  # noqa: E731
        speed = np.linalg.norm(tip(e + 1e-4) - tip(e - 1e-4)) / 2e-4  # m/rad
        return e + frac * self.tp["hole_depth"] / speed

    def _scene(self, spec) -> None:
        from ..kinematics import WristKinematics
        self._kin = WristKinematics(self.nominal_params)
        self._pin_a, self._pin_v = self._pin_geometry()
        self._rud_deep = self._rud_at_depth(1.0, self._pin_a, self._pin_v)  # RUD of the pin tip at the hole bottom
        tip = self._pin_a + self.tp["pin_length"] * self._pin_v
        r = self.tp["pin_radius"]
        self._add_tool_geom(spec, "arm", [0.02, 0, 0, *self._pin_a], 0.006, 0.05, self.tp["friction"])
        self._add_tool_geom(spec, "pin", [*self._pin_a, *tip], r, 0.01, self.tp["friction"])
        w = r + self.tp["clearance"]
        D = self.tp["hole_depth"]
        c = self.tp["chamfer"]
        boxes = []
        # hole frame: Z out of the hole (up), origin at the entrance centre; walls, bottom, chamfers
        for sgn in (1.0, -1.0):
            boxes.append(((WALL, w + 2 * WALL, D / 2), (sgn * (w + WALL), 0.0, -D / 2), None))
            boxes.append(((w, WALL, D / 2), (0.0, sgn * (w + WALL), -D / 2), None))
        if c > 0:
            half = c / np.sqrt(2.0)
            t = 0.006  # half thickness: thick enough that the pin cannot sink through on impact
            for sgn in (1.0, -1.0):
                n = np.array([-sgn, 0.0, 1.0]) / np.sqrt(2.0)
                mid = np.array([sgn * (w + c / 2), 0.0, c / 2]) - t * n
                boxes.append(((half, w + c, t), tuple(mid), rot_y(-sgn * np.pi / 4)))
                n = np.array([0.0, -sgn, 1.0]) / np.sqrt(2.0)
                mid = np.array([0.0, sgn * (w + c / 2), c / 2]) - t * n
                boxes.append(((w + c, half, t), tuple(mid), rot_x(sgn * np.pi / 4)))
        rgba = (0.45, 0.5, 0.6, 1)
        body = add_mocap_box_body(spec, "task_hole", boxes, rgba=rgba, friction=self.tp["friction"])
        ext = w + 2 * WALL + 0.01
        self._add_touch_sensor(spec, body, "hole_touch", (ext, ext, D / 2 + c + 0.01), pos=(0, 0, -D / 2 + c / 2))
        # the fit: a plate across the hole at fit_depth on a slide joint along the hole axis whose Coulomb friction
        # (frictionloss, set per episode) is the fit force; its lower limit is the hole bottom. MuJoCo's solver
        # treats the friction implicitly, so the fit resists without pushing back or ringing.
        d_fit = self.tp["fit_depth"] * D
        plate = add_mocap_box_body(spec, "task_hole_fit_mount", [], rgba=rgba)
        fit = plate.add_body(name="task_hole_fit", pos=[0.0, 0.0, -d_fit])
        fit.add_joint(name="task_hole_fit", type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[0, 0, 1], range=[d_fit - D, 0.0],
                      limited=mujoco.mjtLimited.mjLIMITED_TRUE, armature=0.01, damping=1.0,
                      solref_limit=list(CONTACT_SOLREF), solref_friction=[0.002, 1.0],
                      solimp_friction=[0.9999, 0.9999, 0.001, 0.5, 2.0])
        fit.add_geom(name="task_hole_fit_plate", type=mujoco.mjtGeom.mjGEOM_BOX, size=[w, w, WALL / 2],
                     pos=[0.0, 0.0, -WALL / 2], mass=0.01, contype=0, conaffinity=2, condim=3,
                     friction=[self.tp["friction"], 0.005, 0.0001], solref=list(CONTACT_SOLREF),
                     rgba=[0.7, 0.55, 0.3, 1], group=1)
        self._add_touch_sensor(spec, fit, "bottom_touch", (w + 1e-3, w + 1e-3, WALL))

    def _scene_ids(self) -> None:
        self._touch_adr = self._sensor_adr("hole_touch")
        self._bottom_adr = self._sensor_adr("bottom_touch")
        self._mocaps = [int(self.model.body(b).mocapid[0]) for b in ("task_hole", "task_hole_fit_mount")]
        j = self.model.joint("task_hole_fit")
        self._fit_jnt, self._fit_dof, self._fit_qadr = int(j.id), int(j.dofadr[0]), int(j.qposadr[0])
        self._tip_local = self._pin_a + self.tp["pin_length"] * self._pin_v

    # ------------------------------------------------------------------ episode
    def _task_reset(self, rng):
        fe = float(rng.uniform(*self.tp["hole_fe"]))
        lat = float(rng.uniform(-1, 1)) * self.tp["lateral_error"]
        ang = float(rng.uniform(-1, 1)) * self.tp["angular_error"]
        fit = float(rng.uniform(*self.tp["fit_force"]))
        self._ep.task.put(0, fe=fe, lat=lat, ang=ang, fit=fit)
        self.model.dof_frictionloss[self._fit_dof] = fit  # before the settling steps of reset
        return np.array([self.tp["start_rud"], fe]), self.PS, float(rng.uniform(-1.0, 1.0))

    def _after_reset(self) -> None:
        u_entry = np.array([self.tp["entry_rud"], self._fe])
        u_deep = np.array([self._rud_deep, self._fe])
        entrance = self.tool_point(u_entry, self.PS, self._tip_local)
        bottom = self.tool_point(u_deep, self.PS, self._tip_local)
        axis_in = (bottom - entrance) / np.linalg.norm(bottom - entrance)
        R = frame_from_z(-axis_in)
        # misalignment: shift along Y_b, tilt about X_b through the entrance
        R = rot_x(self._ang) @ R
        entrance = entrance + np.array([0.0, self._lat, 0.0])
        self._ep.task.put(0, entrance=entrance, hole_R=R)
        for m in self._mocaps:
            self.data.mocap_pos[m] = entrance
            self.data.mocap_quat[m] = quat_from_matrix(R)

    def _reference(self, t) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        s = np.minimum(t / self.tp["approach_s"], 1.0)
        rud_end = self._rud_deep + self.tp["overdrive"]
        rud = self.tp["start_rud"] + s * (rud_end - self.tp["start_rud"])
        return np.stack([rud, np.full_like(t, self._fe), np.full_like(t, self.PS)], axis=-1)

    @classmethod
    def _contact_force_worlds(cls, worlds: list, ep, ids) -> np.ndarray:
        """Normal force (N) of the walls and chamfers on the tool: the jamming force (the fit plate is apart)."""
        return sensor_values(worlds, worlds[0]._touch_adr)

    def bottom_force(self) -> float:
        """Normal force (N) of the fit plate (which ends at the hole bottom) on the pin."""
        return float(self.data.sensordata[self._bottom_adr])

    def fit_travel(self) -> float:
        """How far the fit plate has been pushed, as a fraction of its travel (1 = the hole bottom)."""
        lo = self.model.jnt_range[self._fit_jnt, 0]
        return float(self.data.qpos[self._fit_qadr] / lo)

    def _task_obs_terms(self):
        from .observations import ObsTerm, column
        adr = self._bottom_adr
        return [ObsTerm("bottom_force", 1, "N", "normal force of the fit plate (at the hole bottom once pushed down) "
                        "on the pin (no sensor noise)", None, 0.0, 1e5, lambda m: column(m.sensor(adr)))]

    def pin_depth(self) -> float:
        """Depth (m) of the pin's end (its rounded tip) below the hole entrance along the hole axis, 0 unless the
        pin is inside the hole; ``hole_depth`` when it rests on the bottom."""
        return clipped_depth(*self._tip_in_hole_worlds([self], self._ep, ONE), self.tp["hole_depth"]).item(0)

    def seated(self) -> bool:
        """Whether the pin is in the hole now, its end between ``success_depth`` of the depth and the bottom."""
        return bool(is_seated(*self._tip_in_hole_worlds([self], self._ep, ONE), self.tp)[0])

    @classmethod
    def _tip_in_hole_worlds(cls, worlds: list, ep, ids) -> tuple[np.ndarray, np.ndarray]:
        """``tip_in_hole`` of ``worlds`` as their simulators stand."""
        tp = worlds[0].tp
        r = tp["pin_radius"]
        tips = tool_points(worlds, worlds[0]._tip_local)  # centres of the rounded ends, pin_radius short of them
        return tip_in_hole(tips, ep.task.entrance[ids], ep.task.hole_R[ids], r, r + tp["clearance"])

    @classmethod
    def _task_reward_terms_worlds(cls, worlds: list, ep, ids, err) -> dict:
        tp = worlds[0].tp
        depth = clipped_depth(*cls._tip_in_hole_worlds(worlds, ep, ids), tp["hole_depth"])
        return {"depth": depth / tp["hole_depth"],
                "jamming": -np.minimum(ep.contact[ids] / worlds[0].cfg["scales"]["force"], FORCE_CAP)}

    def _tracking_error(self, err):
        return err[..., 1:]  # the RUD reference is driven past the hole bottom on purpose

    @classmethod
    def _success_worlds(cls, worlds: list, ep, ids) -> np.ndarray:
        # peak_contact is the largest wall force of the episode (contact_force is the walls' and chamfers')
        tp = worlds[0].tp
        _, energy, _ = episode_history(ep, ids)
        return (is_seated(*cls._tip_in_hole_worlds(worlds, ep, ids), tp)
                & (ep.peak_contact[ids] <= tp["success_wall_force"]) & (np.mean(energy, axis=1) < tp["success_energy"]))


def tool_points(worlds: list, p_tool) -> np.ndarray:
    """World positions (L, 3) of the point ``p_tool`` (3,) of the tool frame of each world's simulator as it
    stands (its poses are current after a step)."""
    b = worlds[0].sim.tool_id
    X = np.array([e.data.xpos[b] for e in worlds])
    R = np.array([e.data.xmat[b] for e in worlds]).reshape(-1, 3, 3)
    return X + np.matmul(R, p_tool)


def tip_in_hole(tips, entrance, R, r: float, w: float) -> tuple[np.ndarray, np.ndarray]:
    """Depth (m, not clipped: past the bottom or above the entrance as it is) of the pin's ends below the hole
    entrances along the hole axes, and whether each pin is laterally within its hole (half width ``w`` + 1 mm),
    from the centres ``tips`` (L, 3) of the pins' rounded ends (radius ``r``) and the holes' ``entrance`` (L, 3)
    and axes ``R`` (L, 3, 3), Z out of the hole."""
    rel = np.matmul((tips - entrance)[:, None, :], R)  # (L, 1, 3): R^T (tip - entrance) of each world
    lateral = np.abs(rel)
    return r - rel[:, 0, 2], np.maximum(lateral[:, 0, 0], lateral[:, 0, 1]) <= w + 1e-3


def clipped_depth(depth, inside, hole_depth: float) -> np.ndarray:
    """The pins' depth (m) from ``tip_in_hole``: within [0, ``hole_depth``] inside the hole, 0 outside."""
    return np.where(inside, np.minimum(np.maximum(depth, 0.0), hole_depth), 0.0)


def is_seated(depth, inside, tp) -> np.ndarray:
    """Whether each pin is seated, from ``tip_in_hole``: in its hole, its end between ``success_depth`` of the
    hole depth and the bottom (``SEAT_SLACK`` past it at most)."""
    D = tp["hole_depth"]
    return inside & (tp["success_depth"] * D <= depth) & (depth <= D + SEAT_SLACK)
