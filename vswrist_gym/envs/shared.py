"""What the tasks share: scene helpers (tool geoms, touch sensors, mocap boxes, the task camera), rotations,
the hand's geometry and time profiles. Task modules import from here, never from each other."""

from __future__ import annotations

import mujoco
import numpy as np

from ..kinematics import rot_x, rot_y  # noqa: F401  (re-exported for the task modules)

FINGER_END = 0.06  # m, where the hand's fingers end along the tool X axis (model geometry)


# Contact of the tool with task objects (MuJoCo solref: time constant s, damping ratio). With MuJoCo's default
# (0.02, 1) the tool sinks deep into thin objects on impact and single samples of the touch sensor reach
# hundreds to thousands of N; 10 ms, critically damped, keeps penetration and force readings sane (measured:
# Impact/Insertion peaks 34/81 N instead of 494/1656 N in the same episodes).
CONTACT_SOLREF = (0.01, 1.0)


def quat_from_matrix(R: np.ndarray) -> np.ndarray:
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(R, dtype=float).ravel())
    return q


def frame_from_z(z: np.ndarray, y_hint=(0.0, 1.0, 0.0)) -> np.ndarray:
    """Rotation matrix whose Z column is ``z`` and whose Y column is as close as possible to ``y_hint``."""
    z = np.asarray(z, float) / np.linalg.norm(z)
    y = np.asarray(y_hint, float) - np.dot(y_hint, z) * z
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    return np.column_stack([x, y, z])


def add_mocap_box_body(spec: mujoco.MjSpec, name: str, boxes, rgba=(0.55, 0.45, 0.35, 1.0),
                       friction: float = 0.5) -> mujoco.MjsBody:
    """A mocap body (placed per episode) with box geoms that collide with the tool only.

    ``boxes``: list of (half sizes (3,), position (3,), rotation (3x3) or None) in the body frame.
    Geom names start with ``task_`` so that friction randomisation finds them.
    """
    body = spec.worldbody.add_body(name=name, mocap=True, pos=[0.0, 0.0, -5.0])
    for i, (size, pos, R) in enumerate(boxes):
        kw = {} if R is None else {"quat": list(quat_from_matrix(R))}
        body.add_geom(name=f"task_{name}_{i}", type=mujoco.mjtGeom.mjGEOM_BOX, size=list(size), pos=list(pos),
                      contype=0, conaffinity=2, condim=3, friction=[friction, 0.005, 0.0001], rgba=list(rgba),
                      solref=list(CONTACT_SOLREF),
                      group=1, **kw)
    return body



def smoothstep(x: float) -> float:
    """Minimum-jerk blend 0 -> 1 on x in [0, 1]."""
    x = min(max(x, 0.0), 1.0)
    return x * x * x * (10.0 + x * (-15.0 + 6.0 * x))


class SceneMixin:
    """Scene helpers of ``VSWristEnv`` for tasks: geometry before compilation, look-ups and poses after."""

    def _full_scene(self, spec: mujoco.MjSpec) -> None:
        """The task's geometry plus a camera ``task_view`` that frames the hand, the tool and the task objects."""
        self._scene(spec)
        pos, target = np.array([0.42, -0.32, 0.16]), np.array([0.17, 0.0, -0.03])
        f = (target - pos) / np.linalg.norm(target - pos)
        x = np.cross(f, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        y = np.cross(x, f)
        q = np.zeros(4)
        mujoco.mju_mat2Quat(q, np.column_stack([x, y, -f]).ravel())  # a camera looks along its -Z
        spec.worldbody.add_camera(name="task_view", pos=list(pos), quat=list(q), fovy=45.0)

    def _window(self, seconds: float) -> int:
        return max(1, int(round(seconds / self.ctrl_dt)))

    def _add_touch_sensor(self, spec: mujoco.MjSpec, body, name: str, size, pos=(0.0, 0.0, 0.0), quat=None) -> None:
        kw = {"quat": quat} if quat is not None else {}
        body.add_site(name=f"{name}_site", type=mujoco.mjtGeom.mjGEOM_BOX, size=list(size), pos=list(pos),
                      rgba=[0, 0, 0, 0], group=5, **kw)
        spec.add_sensor(name=name, type=mujoco.mjtSensor.mjSENS_TOUCH, objtype=mujoco.mjtObj.mjOBJ_SITE,
                        objname=f"{name}_site")

    def tool_point(self, u, ps: float, p_tool) -> np.ndarray:
        """World position (m) of point ``p_tool`` (tool frame) at posture u (2,), PS angle ps, from the analytic
        kinematics: O_c + R_c Rx(ps) (hand_offset e_x + p_tool). Used to place task objects."""
        from ..kinematics import WristKinematics, rot_x
        if not hasattr(self, "_kin"):
            self._kin = WristKinematics(self.nominal_params)
        T = self._kin.coupler_pose(np.asarray(u, dtype=float), allow_outside=True)
        p = np.array([self.nominal_params.inertia.hand_offset, 0.0, 0.0]) + rot_x(ps) @ np.asarray(p_tool, float)
        return T[:3, 3] + T[:3, :3] @ p

    def _add_tool_geom(self, spec: mujoco.MjSpec, name: str, fromto, radius: float, mass: float,
                       friction: float = 0.5) -> None:
        """A capsule on the ``tool`` body that collides with task objects only (contype 2 / conaffinity 0)."""
        spec.body("tool").add_geom(name=f"task_{name}", type=mujoco.mjtGeom.mjGEOM_CAPSULE, fromto=list(fromto),
                                   size=[radius, 0, 0], mass=mass, contype=2, conaffinity=0,
                                   friction=[friction, 0.005, 0.0001], rgba=[0.55, 0.55, 0.6, 1], group=1,
                                   condim=3, solref=list(CONTACT_SOLREF))

    def _sensor_adr(self, name: str) -> int:
        return int(self.model.sensor_adr[self.model.sensor(name).id])


class PeriodMeanForce:
    """Mixin (before ``VSWristEnv`` in the bases) for tasks whose contact force is the mean normal force over the
    control period's substeps: the tool's tip chatters against stiff contacts at about 100 Hz, so one substep's
    reading (a touch sensor's) drops to 0 N on many pressed steps. The physics then runs one substep at a time.

    The task sets ``self._cforce = np.zeros(6)`` and ``self._touch_adr`` (read at reset, before any period ran)
    and defines ``_is_force_contact(c)``; ``_on_force_contact(i, c)`` sees each counted contact first."""

    def _is_force_contact(self, c) -> bool:
        raise NotImplementedError

    def _on_force_contact(self, i: int, c) -> None:
        """Called for each counted contact of a substep, before its force is summed."""

    def _advance_physics(self, duration: float, first: bool) -> None:
        # after mj_step the contact arrays hold that substep's contacts and their solved forces
        if first:
            self._force_sum, self._force_n = 0.0, 0
        m, d, f = self.model, self.data, self._cforce
        dt = self.sim.timestep
        for k in range(int(round(duration / dt))):
            self.sim.step(dt, restart_peak=first and k == 0)
            for i in range(d.ncon):
                c = d.contact[i]
                if self._is_force_contact(c):
                    self._on_force_contact(i, c)
                    mujoco.mj_contactForce(m, d, i, f)
                    self._force_sum += f[0]
            self._force_n += 1

    def _contact_force(self) -> float:
        """Mean normal force (N) over the last control period's substeps (at reset, where no period has run: the
        touch sensor's reading)."""
        if self._force_n == 0:
            return float(self.data.sensordata[self._touch_adr])
        out = self._force_sum / self._force_n
        self._force_sum, self._force_n = 0.0, 0
        return out
