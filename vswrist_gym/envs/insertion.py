"""``VSWrist/Insertion-v0``: push a pin into a chamfered hole whose position and axis are off nominal.

The tool is L-shaped: an arm along the hand's X axis and a pin perpendicular to it, pointing down (-Z_b) at
PS = 0, so radial/ulnar deviation drives the pin along its own axis (the pin is inclined so that it is tangent
to its arc of motion half-way into the hole). The hole (square, radial clearance ``clearance``, chamfered) stands
below the pin; its true position is off nominal by up to ``lateral_error`` along Y_b (fixed by FE) and its
axis by up to ``angular_error`` about X_b (fixed by PS). The posture reference ramps from above the nominal
hole to ``overdrive`` rad beyond full depth at the nominal FE and PS of the hole. Past ``fit_depth`` of the
hole a fit (latch, press fit) resists with ``fit_force``. Adapting stiffness pays: a soft wrist lets the chamfer
and walls steer the pin into the true hole without jamming; only a stiff one pushes it past the fit.

Depth: how far the pin tip is below the hole entrance along the hole axis while it is inside the hole
(laterally within the clearance). Success: the largest depth reaches ``success_depth`` x ``hole_depth``.
"""

from __future__ import annotations

import numpy as np

from ._contact import add_mocap_box_body, frame_from_z, quat_from_matrix, rot_x, rot_y
from .base import FORCE_CAP, VSWristEnv
from .config import EnvConfigError
from .drill import FINGER_END

WALL = 0.008      # m, half thickness of the walls around the hole
PLATE = 0.02      # m, half extent of the walls beyond the hole


class InsertionEnv(VSWristEnv):
    task = "insertion"
    task_id = "VSWrist/Insertion-v0"
    summary = "insert a pin into a chamfered hole with lateral and angular misalignment; depth against jamming"
    success_text = "the pin tip reaches {success_depth:.0%} of the hole depth"
    task_spec = {
        "tool_length": ("number", 0.0, 0.3),
        "pin_length": ("number", 0.005, 0.1),
        "pin_radius": ("number", 0.001, 0.02),
        "clearance": ("number", 0.0001, 0.02),
        "hole_depth": ("number", 0.002, 0.1),
        "chamfer": ("number", 0.0, 0.05),
        "hole_fe": ("interval", -1.5, 1.5),
        "hole_ps": ("interval", -np.pi, np.pi),
        "start_rud": ("number", -1.5, 1.5),
        "entry_rud": ("number", -1.5, 1.5),
        "overdrive": ("number", 0.0, 1.0),
        "lateral_error": ("number", 0.0, 0.05),
        "angular_error": ("number", 0.0, 1.0),
        "approach_s": ("number", 0.02, 600.0),
        "success_depth": ("number", 0.0, 1.0),
        "friction": ("number", 0.0, 5.0),
        "fit_force": ("interval", 0.0, 1000.0),
        "fit_depth": ("number", 0.0, 1.0),
    }
    task_reward_terms = ("depth", "jamming")

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
        boxes.append(((w + 2 * WALL, w + 2 * WALL, WALL), (0.0, 0.0, -D - WALL), None))
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
        body = add_mocap_box_body(spec, "task_hole", boxes, rgba=(0.45, 0.5, 0.6, 1), friction=self.tp["friction"])
        ext = w + 2 * WALL + 0.01
        self._add_touch_sensor(spec, body, "hole_touch", (ext, ext, D / 2 + c + 0.01), pos=(0, 0, -D / 2 + c / 2))

    def _scene_ids(self) -> None:
        self._touch_adr = self._sensor_adr("hole_touch")
        self._mocap = int(self.model.body("task_hole").mocapid[0])
        self._tip_local = self._pin_a + self.tp["pin_length"] * self._pin_v

    # ------------------------------------------------------------------ episode
    def _task_reset(self, rng):
        self._fe = float(rng.uniform(*self.tp["hole_fe"]))
        self._ps = float(rng.uniform(*self.tp["hole_ps"]))
        self._lat = float(rng.uniform(-1, 1)) * self.tp["lateral_error"]
        self._ang = float(rng.uniform(-1, 1)) * self.tp["angular_error"]
        self._rud_end = self._rud_at_depth(1.0, self._pin_a, self._pin_v) + self.tp["overdrive"]
        self._depth = 0.0
        self._max_depth = 0.0
        self._fit = float(rng.uniform(*self.tp["fit_force"]))
        return np.array([self.tp["start_rud"], self._fe]), self._ps, float(rng.uniform(-1.0, 1.0))

    def _after_reset(self) -> None:
        u_entry = np.array([self.tp["entry_rud"], self._fe])
        u_deep = np.array([self._rud_at_depth(1.0, self._pin_a, self._pin_v), self._fe])
        entrance = self.tool_point(u_entry, self._ps, self._tip_local)
        bottom = self.tool_point(u_deep, self._ps, self._tip_local)
        axis_in = (bottom - entrance) / np.linalg.norm(bottom - entrance)
        R = frame_from_z(-axis_in)
        # misalignment: shift along Y_b, tilt about X_b through the entrance
        R = rot_x(self._ang) @ R
        entrance = entrance + np.array([0.0, self._lat, 0.0])
        self._hole = (entrance, R)
        self.data.mocap_pos[self._mocap] = entrance
        self.data.mocap_quat[self._mocap] = quat_from_matrix(R)

    def _reference(self, t: float) -> np.ndarray:
        s = min(t / self.tp["approach_s"], 1.0)
        rud = self.tp["start_rud"] + s * (self._rud_end - self.tp["start_rud"])
        return np.array([rud, self._fe, self._ps])

    def _before_physics(self, t: float) -> None:
        """Past ``fit_depth`` the fit resists insertion with ``fit_force`` along the hole axis, applied to the hand
        (a latch or press fit; the force acts at the hand centre, a simplification of where the pin feels it)."""
        D = self.tp["hole_depth"]
        engage = min(max((self._depth - self.tp["fit_depth"] * D) / (0.1 * D), 0.0), 1.0)  # ramps in over 0.1 D
        self.sim.apply_wrench(engage * self._fit * self._hole[1][:, 2], np.zeros(3))

    def _contact_force(self) -> float:
        return float(self.data.sensordata[self._touch_adr])

    def pin_depth(self) -> float:
        """Depth (m) of the pin tip below the hole entrance along the hole axis, 0 unless inside the hole."""
        entrance, R = self._hole
        tip = self._tool_tip_world()
        rel = R.T @ (tip - entrance)
        w = self.tp["pin_radius"] + self.tp["clearance"]
        inside = abs(rel[0]) <= w + 1e-3 and abs(rel[1]) <= w + 1e-3
        return float(min(max(-rel[2], 0.0), self.tp["hole_depth"])) if inside else 0.0

    def _tool_tip_world(self) -> np.ndarray:
        b = self.sim.tool_id
        return self.data.xpos[b] + self.data.xmat[b].reshape(3, 3) @ self._tip_local

    def _task_reward_terms(self, err) -> dict:
        self._depth = self.pin_depth()
        self._max_depth = max(self._max_depth, self._depth)
        return {"depth": self._depth / self.tp["hole_depth"],
                "jamming": -min(self._contact / self.cfg["scales"]["force"], FORCE_CAP)}

    def _tracking_error(self, err):
        return err[1:]  # the RUD reference is driven past the hole bottom on purpose

    def _success(self) -> bool:
        return self._max_depth >= self.tp["success_depth"] * self.tp["hole_depth"]
