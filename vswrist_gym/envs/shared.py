"""What the tasks share: scene helpers (tool geoms, touch sensors, mocap boxes, the task camera), rotations,
the hand's geometry and time profiles. Task modules import from here, never from each other."""

from __future__ import annotations

import mujoco
import numpy as np

from ..kinematics import rot_x, rot_y  # noqa: F401  (re-exported for the task modules)
from ..sim import add_contact_meter, contact_meter_state

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



def sensor_values(worlds: list, adr: int) -> np.ndarray:
    """The sensor value at address ``adr`` of each world's simulator (L,) (its sensors are current after a
    step)."""
    return np.array([e.data.sensordata[adr] for e in worlds], dtype=float)


def smoothstep(x):
    """Minimum-jerk blend 0 -> 1 on x in [0, 1] (a number or an array, element-wise)."""
    x = np.minimum(np.maximum(x, 0.0), 1.0)
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

    def _compensated_payload(self) -> tuple[tuple[float, float], ...]:
        """The parts besides the hand whose weight the controller holds when ``compensate_tool`` is set, as
        ``AnalyticController``'s payload: the PS flange and the task's tool at their nominal (built) masses, each at
        its centre of mass's distance along the PS axis from the coupler centre, read from the compiled model. Both
        are known to whoever designs the task and gives the agent its tool; the tool's random mass factor
        (``randomize.tool_mass``) and the task's loads are not. A centre of mass off the PS axis (an L-shaped tool's
        few mm) is taken at its projection on the axis: its offset's load turns with PS."""
        m = self.model
        coupler = m.body("coupler").id
        out = []
        for name, mass in (("ps", None), ("tool", self._nominal_tool_mass)):
            b = m.body(name).id
            R, p = np.eye(3), np.zeros(3)  # the body's frame in the coupler frame (x: the PS axis)
            chain = []
            while b != coupler:
                chain.append(b)
                b = int(m.body_parentid[b])
            for b in reversed(chain):
                Rb = np.zeros(9)
                mujoco.mju_quat2Mat(Rb, m.body_quat[b])
                p, R = p + R @ m.body_pos[b], R @ Rb.reshape(3, 3)
            mass = float(m.body_mass[chain[0]]) if mass is None else mass
            if mass > 0.0:
                out.append((mass, float((p + R @ m.body_ipos[chain[0]])[0])))
        return tuple(out)

    def tool_point(self, u, ps, p_tool) -> np.ndarray:
        """World position (m) of point ``p_tool`` (tool frame) at posture u (2,), PS angle ps, from the analytic
        kinematics: O_c + R_c Rx(ps) (hand_offset e_x + p_tool). Used to place task objects. Stacks (u (..., 2),
        ps (...), p_tool (..., 3)) give the points of many postures in one pass, each as alone."""
        from ..kinematics import WristKinematics, _mv, rot_x
        if not hasattr(self, "_kin"):
            self._kin = WristKinematics(self.nominal_params)
        T = self._kin.coupler_pose(np.asarray(u, dtype=float), allow_outside=True)
        p = np.array([self.nominal_params.inertia.hand_offset, 0.0, 0.0]) + _mv(rot_x(ps), np.asarray(p_tool, float))
        return T[..., :3, 3] + _mv(T[..., :3, :3], p)

    def chord_points(self, rud: np.ndarray, fe: np.ndarray, ps: np.ndarray, p_tool: np.ndarray,
                     h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """World positions (M, 3) of the tool points ``p_tool`` (M, 3) at postures (rud, fe + h), (rud, fe - h)
        and (rud, fe) of M worlds (``rud``, ``fe``, ``ps``: (M,)), in one pass of ``tool_point`` (each as alone):
        the chord a swing's direction and lever are taken from."""
        M = len(fe)
        p = self.tool_point(np.stack([np.tile(rud, 3), np.concatenate([fe + h, fe - h, fe])], axis=-1),
                            np.tile(ps, 3), np.tile(p_tool, (3, 1)))
        return p[:M], p[M:2 * M], p[2 * M:]

    def _add_tool_geom(self, spec: mujoco.MjSpec, name: str, fromto, radius: float, mass: float,
                       friction: float = 0.5) -> None:
        """A capsule on the ``tool`` body that collides with task objects only (contype 2 / conaffinity 0)."""
        spec.body("tool").add_geom(name=f"task_{name}", type=mujoco.mjtGeom.mjGEOM_CAPSULE, fromto=list(fromto),
                                   size=[radius, 0, 0], mass=mass, contype=2, conaffinity=0,
                                   friction=[friction, 0.005, 0.0001], rgba=[0.55, 0.55, 0.6, 1], group=1,
                                   condim=3, solref=list(CONTACT_SOLREF))

    def _sensor_adr(self, name: str) -> int:
        return int(self.model.sensor_adr[self.model.sensor(name).id])


CONTACT_METER = "contact_meter"  # the name of a task's vswrist.contact plugin instance


class PeriodMeanForce:
    """Mixin (before ``VSWristEnv`` in the bases) for tasks whose contact force is the mean normal force over the
    control period's substeps: the tool's tip chatters against stiff contacts at about 100 Hz, so one substep's
    reading (a touch sensor's) drops to 0 N on many pressed steps. It also reports, once per period, the first
    substep with such a contact (its time, the contact's position, a body's velocity just before any contact
    force acted), for tasks that need an impact's instant (Hammer).

    The measurement runs inside the physics, after the constraint solve of every substep: in the compiled
    physics a ``vswrist.contact`` plugin instance (``sim.add_contact_meter``) accumulates into its plugin state, so
    a period is one ``mj_step(m, d, n)`` call like every other task's (and a batch advances these worlds on its
    threads too); the state is per MjData and part of ``mjSTATE_INTEGRATION``. With the Python reference
    callbacks (no C compiler) there is no plugin and the period runs one substep at a time, reading the same
    quantities from Python (``tests/test_substep_meter.py`` checks that the two agree).

    The task calls ``_add_contact_meter(spec, body, geom1, geom2)`` in ``_scene`` and ``_find_contact_meter()``
    in ``_scene_ids``, and sets ``self._touch_adr`` (the touch sensor read at reset, before any period ran);
    ``_on_first_contact(time, pos, vel)`` sees each period's first counted contact, when the period's force is read
    (``_contact_force_worlds``: in the step's measures, after its clock advanced), with either physics.
    ``_last_substep_force()`` is the other reading, the touch sensor at the end of the period."""

    _meter_names: tuple = ()
    _force_sum, _force_n, _first_contact, _period_ran = 0.0, 0, None, False

    def _add_contact_meter(self, spec: mujoco.MjSpec, body, geom1: str, geom2: str | None = None) -> None:
        """Count contacts of geom ``geom1`` with ``geom2`` (None: with anything); ``body`` (an MjsBody) is the body
        whose velocity ``_on_first_contact`` gets. Adds the plugin instance where the spec runs the compiled
        physics (it names the VS-Wrist plugins); the reference's spec gets nothing."""
        self._meter_names = (body.name, geom1, geom2)
        add_contact_meter(spec, CONTACT_METER, body, geom1, geom2)

    def _find_contact_meter(self) -> None:
        """After (re)compilation: the plugin state's view (None with the reference), geom and body ids."""
        m = self.model
        body, geom1, geom2 = self._meter_names
        self._meter_body = int(m.body(body).id)
        self._meter_geom1 = int(m.geom(geom1).id)
        self._meter_geom2 = -1 if geom2 is None else int(m.geom(geom2).id)
        self._meter = contact_meter_state(m, self.data, CONTACT_METER)
        self._cforce = np.zeros(6)
        self._vel6 = np.zeros(6)

    def _reset_state(self) -> None:
        super()._reset_state()
        self._force_sum, self._force_n, self._first_contact = 0.0, 0, None
        self._period_ran = False

    def _on_first_contact(self, time: float, pos: np.ndarray, vel: np.ndarray) -> None:
        """The period's first substep with a counted contact: ``time`` (s) of ``data.time`` after that substep,
        ``pos`` (3,) of its first counted contact, ``vel`` (3,) the linear velocity (m/s, world frame) of the
        meter's body at the state the substep started from, before any contact force acted."""

    def _advance_physics(self, duration: float, first: bool) -> None:
        if self._meter is not None:
            if first:
                self._meter[:] = 0.0
            self._period_ran = True
            self.sim.step(duration, restart_peak=first)
            return
        # the reference: after mj_step(m, d, 1) the contact list, the solved forces and the body velocities are
        # those of the state the substep started from (what the plugin's advance callback sees); the first contact
        # is kept for the period's reading, as the plugin keeps it in its state
        if first:
            self._force_sum, self._force_n, self._first_contact = 0.0, 0, None
        m, d, f = self.model, self.data, self._cforce
        g1, g2 = self._meter_geom1, self._meter_geom2
        dt = self.sim.timestep
        for k in range(int(round(duration / dt))):
            self.sim.step(dt, restart_peak=first and k == 0)
            for i in range(d.ncon):
                c = d.contact[i]
                a, b = c.geom1, c.geom2
                if not ((a == g1 or b == g1) if g2 < 0 else ((a == g1 and b == g2) or (a == g2 and b == g1))):
                    continue
                if self._first_contact is None:
                    mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_BODY, self._meter_body, self._vel6, 0)
                    self._first_contact = (float(d.time), c.pos.copy(), self._vel6[3:].copy())
                mujoco.mj_contactForce(m, d, i, f)
                self._force_sum += f[0]
            self._force_n += 1

    def _last_substep_force(self) -> float:
        """The touch sensor's reading (N) at the state the physics stands in (sensors are current after a step)."""
        return float(self.data.sensordata[self._touch_adr])

    @classmethod
    def _contact_force_worlds(cls, worlds: list, ep, ids) -> np.ndarray:
        """Mean normal force (N) over the last control period's substeps of each world (at reset, where no period
        has run: the touch sensor's reading). Reads and clears the period's measurements: the compiled meters' states
        copied out at once, then each world's numbers as Python floats (a batch of one, the single env, pays no array
        calls beyond the copy); the reference physics' sums world by world."""
        if worlds[0]._meter is None:
            return np.array([e._reference_period_force() for e in worlds], dtype=float)
        out = []
        for e, m in zip(worlds, np.array([e._meter for e in worlds]).tolist()):
            if not e._period_ran or m[1] == 0.0:
                out.append(e._last_substep_force())
                continue
            e._period_ran = False
            if m[2] != 0.0:
                e._on_first_contact(m[3], np.array(m[4:7]), np.array(m[7:10]))
            e._meter[:] = 0.0
            out.append(m[0] / m[1])
        return np.array(out, dtype=float)

    def _reference_period_force(self) -> float:
        """``_contact_force_worlds`` of one world under the reference physics (no plugin): from its period's sums."""
        if self._force_n == 0:
            return self._last_substep_force()
        if self._first_contact is not None:
            self._on_first_contact(*self._first_contact)
        out = self._force_sum / self._force_n
        self._force_sum, self._force_n, self._first_contact = 0.0, 0, None
        return out

def off_plane(err, steps) -> np.ndarray:
    """How far (rad) RUD and PS left a swing's plane: the largest of their absolute errors in the first ``steps``
    (L,) rows of the worlds' posture errors ``err`` (L, k, 3) (a NaN error counts as none; 0 if no row)."""
    before = np.arange(err.shape[1]) < steps[:, None]
    return np.fmax.reduce(np.abs(err[..., ::2]), axis=(1, 2), where=before[..., None], initial=0.0)
