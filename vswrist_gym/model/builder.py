"""MuJoCo model of the VS-Wrist, generated from a :class:`~vswrist_gym.params.WristParams`.

Structure (every element named; base frame = world frame, X along the forearm):

* ``base``: the forearm housing (static).
* ``motor_A/B/C``: one rotor hinge per leg, coaxial with the leg's first joint, carrying the motor's reflected
  inertia (joint armature). Its angle is the paper's theta. The motors act on the legs **only** through the
  sinh springs (applied every substep by ``vswrist_gym.model.native``: +tau on ``legX_q1``, -tau on ``motor_X``).
* ``legX_link1..3`` + ``legX_q1..q4``: the three legs, four hinges each, following the DH table exactly;
  joint values equal the DH angles (each joint's ``ref`` is its home angle, so ``qpos0`` is the home pose).
  The body after ``q4`` has the coupler frame. Leg A's is the ``coupler`` body; legs B and C end in
  ``legB_end`` / ``legC_end``, welded to the coupler (``close_B``, ``close_C``). Each of the three carries a
  third of the coupler mass, so the welds join three equal pieces of one ring.
* ``ps`` (hinge about the coupler X axis) stands for the PS motor's output and its two opposed universal joints;
  ``hand`` is the paper's 300 g point mass 10 cm along the coupler X axis; ``tool`` is attached at site
  ``tool_mount``; sensors ``tool_force`` / ``tool_torque`` measure the hand-tool interaction.
* Actuators ``motor_A/B/C`` (on the rotors) and ``motor_ps`` (on ``ps``): reference = ``ctrl`` (rad), rate-limited
  first-order low-pass (time constant, speed limit) into the activation (the servo setpoint), held within
  ``kd vmax / kp`` of the motor angle, then a PD position loop ``kp (act - q) - kd qdot`` clamped to the torque
  limit: the loop never commands more than the speed limit and does not wind up when the torque saturates.
  The setpoint dynamics are ``dyntype=user``, computed by the ``vswrist.drive`` plugin (or the reference callback).
* Tendons ``deflection_A/B/C`` = q1 - theta with the mechanical deflection limit as a tendon limit: a damped
  bumper (time constant ``simulation.stop_timeconst``, MuJoCo's default impedance 0.9-0.95).
* Springs and setpoint dynamics, ``physics="plugin"`` (the default): MuJoCo engine plugins named in the
  ``<extension>`` section, so the model is self-contained given the plugin library (``native.load_plugin``).
  One ``vswrist.drive`` instance per motor (``drive_A/B/C``, ``drive_ps``) with its constants as config
  (K, delta0, time_constant, speed_limit, lead; the PS motor has no spring), referenced by the rotor body and
  the leg's first link (the spring joins their joints) or by ``ps``. One ``vswrist.closure`` instance,
  referenced by ``coupler``: it keeps the largest violation of the coupler's welds it sees (one check per
  substep, at no measurable cost) in its plugin state, so ``WristSim.loop_closure_peak`` has the worst over a
  whole ``mj_step(m, d, n)``.
* ``physics="callbacks"`` (the reference physics, ``VSWRIST_NATIVE=0``): custom numeric ``vswrist_spring`` = (K, delta0,
  q1 dof adr x3, motor dof adr x3, q1 qpos adr x3, motor qpos adr x3) carries the spring parameters to the
  process-global Python callbacks, which ignore any model without it; ``vswrist_motor`` tags the model for the
  setpoint dynamics (each actuator's ``dynprm[0:3]`` = time constant, speed limit, lead); ``vswrist_closure`` =
  (userdata slot, coupler body id, legB_end id, legC_end id) for the closure monitor in ``userdata[slot]``.
* ``physics="bare"``: neither (no springs, setpoints frozen): the reference for the speed benchmark.
* Cameras ``front``, ``side``, ``top``; keyframe ``home``.
"""

from __future__ import annotations

from typing import Callable

import mujoco
import numpy as np

from ..kinematics import LEG_NAMES, WristKinematics, rot_x, rot_z
from ..params import WristParams, load_params
from . import native
from .native import CLOSURE_FIELDS, CLOSURE_TAG, MOTOR_TAG, SPRING_FIELDS, SPRING_TAG  # noqa: F401
from .plugin_lib import CLOSURE_PLUGIN, DRIVE_PLUGIN
PHYSICS = ("plugin", "callbacks", "bare")
LEG_COLORS = ("0.85 0.3 0.25 1", "0.3 0.7 0.35 1", "0.25 0.45 0.85 1")
LINK_RADIUS_1 = 0.03  # m, radius at which the first link bracket is drawn (visual only)
OFFSCREEN_SIZE = (1280, 960)  # px, the offscreen buffer: the largest frame a Renderer of this model can draw

SceneFn = Callable[[mujoco.MjSpec], None]


def _fmt(v) -> str:
    return " ".join(f"{float(x):.17g}" for x in np.ravel(v))


def _quat(R: np.ndarray) -> str:
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(R, dtype=float).ravel())
    return _fmt(q)


def _camera_axes(pos, target, up=(0.0, 0.0, 1.0)) -> str:
    f = np.asarray(target, float) - np.asarray(pos, float)
    f /= np.linalg.norm(f)
    x = np.cross(f, up)
    x /= np.linalg.norm(x)
    y = np.cross(x, f)
    return _fmt(np.concatenate([x, y]))


def _check_physics(physics: str) -> None:
    if physics not in PHYSICS:
        raise ValueError(f"physics must be one of {', '.join(PHYSICS)}, got {physics!r}")


def model_xml(params: WristParams | str | None = None, physics: str = "plugin", nested: bool = False) -> str:
    """The MJCF text of the wrist. ``physics``: "plugin" (springs and motors as MuJoCo plugins: the text is a
    self-contained model for any program that loads the plugin library), "callbacks" (the reference's fields;
    ``build_model`` fills in their runtime addresses) or "bare" (no springs, frozen setpoints).
    ``nested``: the rotors and legs are children of the static ``base`` rather than of the world, so that the
    whole wrist is one subtree to attach to another model; the physics is the same."""
    _check_physics(physics)
    p = load_params(params)
    kin = WristKinematics(p)
    q_home = kin.joint_angles(np.zeros(2)).reshape(3, 4)
    d = p.geometry.d
    alpha = p.geometry.alpha
    inr, mot, sim = p.inertia, p.motor, p.simulation
    # The PS motor is the PM motor scaled to its torque: reflected inertia and loop gains times
    # ps_torque_limit / torque_limit, so its position loop has the same bandwidth sqrt(kp / J) and damping.
    ps_scale = mot.ps_torque_limit / mot.torque_limit
    solref = f'solref="{sim.constraint_timeconst:.17g} {sim.constraint_dampratio:.17g}"'
    solimp = f'solimp="{sim.constraint_dmin:.17g} {sim.constraint_dmax:.17g} {sim.constraint_width:.17g} 0.5 2"'
    gravity = _fmt(p.environment.gravity)
    m_end = inr.coupler_mass / 3.0
    i_end = inr.coupler_inertia / 3.0

    plugin = physics == "plugin"

    def ref(instance: str, indent: int = 6) -> str:  # a body's reference to a plugin instance
        return f'\n{" " * indent}<plugin instance="{instance}"/>' if plugin else ""

    legs = []
    rotors = []
    for k, (name, eta) in enumerate(zip(LEG_NAMES, p.geometry.eta)):
        qh = q_home[k]
        color = LEG_COLORS[k]
        R_end = rot_x(np.pi - eta)
        axis_end = R_end.T @ np.array([0.0, 0.0, 1.0])
        lm, li = inr.link_mass, inr.link_inertia
        r1 = LINK_RADIUS_1
        if k == 0:
            end_name = "coupler"
            end_inner = f"""{ref("closure", 12)}
            <site name="coupler_site" pos="0 0 0" size="0.004" rgba="1 1 1 1"/>
            <geom name="coupler_ring" type="cylinder" fromto="-0.004 0 0 0.004 0 0" size="0.026" rgba="0.75 0.75 0.78 1"/>
            <body name="ps" pos="0 0 0">
              <joint name="ps" type="hinge" axis="1 0 0" damping="{p.damping.ps_joint:.17g}"
                     armature="{mot.rotor_inertia * ps_scale:.17g}"/>
              <inertial pos="0.02 0 0" mass="{inr.ps_mass:.17g}" diaginertia="{_fmt([inr.ps_inertia] * 3)}"/>{ref("drive_ps", 14)}
              <geom name="ps_flange" type="cylinder" fromto="0.004 0 0 0.03 0 0" size="0.018" rgba="0.6 0.6 0.62 1"/>
              <geom name="ps_shaft" type="capsule" fromto="0.03 0 0 {inr.hand_offset - 0.02:.17g} 0 0" size="0.008"
                    rgba="0.6 0.6 0.62 1"/>
              <body name="hand" pos="{inr.hand_offset:.17g} 0 0">
                <inertial pos="0 0 0" mass="{inr.hand_mass:.17g}" diaginertia="1e-6 1e-6 1e-6"/>
                <site name="hand_site" pos="0 0 0" size="0.005" rgba="1 0.8 0.2 1"/>
                <site name="tool_mount" pos="0 0 0" size="0.004" rgba="0.2 0.8 1 1"/>
                <geom name="hand_palm" type="box" pos="0 0 0" size="0.022 0.035 0.01" rgba="0.93 0.78 0.65 1"
                      contype="1" conaffinity="1"/>
                <geom name="hand_fingers" type="capsule" fromto="0.022 0 0 0.06 0 0" size="0.012"
                      rgba="0.93 0.78 0.65 1" contype="1" conaffinity="1"/>
                <body name="tool" pos="0 0 0">
                  <site name="tool_site" pos="0 0 0" size="0.003"/>
                </body>
              </body>
            </body>"""
        else:
            end_name = f"leg{name}_end"
            end_inner = ""
        legs.append(f"""
    <body name="leg{name}_link1" pos="0 0 0" quat="{_quat(rot_x(eta) @ rot_z(qh[0]))}">
      <joint name="leg{name}_q1" type="hinge" axis="0 0 1" ref="{qh[0]:.17g}"/>
      <inertial pos="0 {-r1 / 2:.17g} {r1 / 2:.17g}" mass="{lm[0]:.17g}" diaginertia="{_fmt([li[0]] * 3)}"/>
      <geom name="leg{name}_link1" type="capsule" fromto="0 0 {r1:.17g} 0 {-r1:.17g} 0" size="0.004" rgba="{color}"/>{ref(f"drive_{name}")}
      <body name="leg{name}_link2" pos="0 0 0" quat="{_quat(rot_x(np.pi / 2) @ rot_z(qh[1]))}">
        <joint name="leg{name}_q2" type="hinge" axis="0 0 1" ref="{qh[1]:.17g}"/>
        <inertial pos="0 0 {(r1 + d) / 2:.17g}" mass="{lm[1]:.17g}" diaginertia="{_fmt([li[1]] * 3)}"/>
        <geom name="leg{name}_link2" type="capsule" fromto="0 0 {r1:.17g} 0 0 {d:.17g}" size="0.004" rgba="{color}"/>
        <body name="leg{name}_link3" pos="0 0 {d:.17g}" quat="{_quat(rot_x(-alpha) @ rot_z(qh[2]))}">
          <joint name="leg{name}_q3" type="hinge" axis="0 0 1" ref="{qh[2]:.17g}"/>
          <inertial pos="0 0 {-d / 2:.17g}" mass="{lm[2]:.17g}" diaginertia="{_fmt([li[2]] * 3)}"/>
          <geom name="leg{name}_link3" type="capsule" fromto="0 0 0 0 0 {-d + 0.012:.17g}" size="0.004"
                rgba="{color}"/>
          <geom name="leg{name}_elbow" type="sphere" size="0.006" rgba="{color}"/>
          <body name="{end_name}" pos="0 0 {-d:.17g}" quat="{_quat(rot_x(np.pi / 2) @ rot_z(qh[3]) @ R_end)}">
            <joint name="leg{name}_q4" type="hinge" axis="{_fmt(axis_end)}" ref="{qh[3]:.17g}"/>
            <inertial pos="0 0 0" mass="{m_end:.17g}" diaginertia="{_fmt([i_end] * 3)}"/>{end_inner}
          </body>
        </body>
      </body>
    </body>""")
        rotors.append(f"""
    <body name="motor_{name}" pos="0 0 0" quat="{_quat(rot_x(eta) @ rot_z(qh[0]))}">
      <joint name="motor_{name}" type="hinge" axis="0 0 1" ref="{qh[0]:.17g}" armature="{mot.rotor_inertia:.17g}"/>
      <inertial pos="0 0 0" mass="0.01" diaginertia="1e-6 1e-6 1e-6"/>
      <geom name="motor_{name}_rotor" type="cylinder" fromto="0 0 -0.036 0 0 -0.028" size="0.012" rgba="{color}"/>
      <geom name="motor_{name}_mark" type="box" pos="0.008 0 -0.037" size="0.006 0.002 0.0015" rgba="1 1 1 1"/>{ref(f"drive_{name}")}
    </body>""")

    damping = p.damping.leg_joint
    tl, vmax, tc = mot.torque_limit, mot.speed_limit, mot.time_constant
    lead = mot.kd * vmax / mot.kp  # following-error limit: the PD loop then commands at most the speed limit

    def actuator(name: str, joint: str, limit: float, scale: float = 1.0) -> str:
        kp, kd = mot.kp * scale, mot.kd * scale
        # the plugin reads the setpoint constants from its instance's config; the reference from dynprm
        dynprm = "" if plugin else f'dynprm="{tc:.17g} {vmax:.17g} {lead:.17g}" '
        return (f'<general name="{name}" joint="{joint}" dyntype="user" {dynprm}'
                f'gaintype="fixed" gainprm="{kp:.17g}" biastype="affine" '
                f'biasprm="0 {-kp:.17g} {-kd:.17g}" forcelimited="true" '
                f'forcerange="{-limit:.17g} {limit:.17g}"/>')

    actuators = [actuator(f"motor_{n}", f"motor_{n}", tl) for n in LEG_NAMES]
    actuators.append(actuator("motor_ps", "ps", mot.ps_torque_limit, ps_scale))
    tendons = [f"""
    <fixed name="deflection_{n}" limited="true" range="{-p.spring.deflection_limit:.17g} {p.spring.deflection_limit:.17g}"
           solreflimit="{sim.stop_timeconst:.17g} 1" solimplimit="0.9 0.95 0.001 0.5 2">
      <joint joint="leg{n}_q1" coef="1"/>
      <joint joint="motor_{n}" coef="-1"/>
    </fixed>""" for n in LEG_NAMES]
    welds = [f'<weld name="close_{n}" body1="coupler" body2="leg{n}_end" relpose="0 0 0 1 0 0 0" {solref} {solimp}/>'
             for n in LEG_NAMES[1:]]
    target = (0.045, 0.0, 0.0)
    cams = {
        "front": (0.32, -0.22, 0.14),
        "side": (0.05, -0.38, 0.06),
        "top": (0.06, -0.01, 0.40),
    }
    cameras = "\n    ".join(
        f'<camera name="{n}" pos="{_fmt(pos)}" xyaxes="{_camera_axes(pos, target, (0, 1, 0) if n == "top" else (0, 0, 1))}"'
        f' fovy="45"/>' for n, pos in cams.items())
    parts = "".join(rotors) + "".join(legs)
    body_tail = (parts.replace("\n", "\n  ") + "\n    </body>") if nested else "\n    </body>" + parts
    if physics == "callbacks":
        spring_data = _fmt([p.spring.K, p.spring.delta0] + [-1.0] * (SPRING_FIELDS - 2))
        fields = f"""
  <size nuserdata="1"/>
  <custom>
    <numeric name="{SPRING_TAG}" data="{spring_data}"/>
    <numeric name="{CLOSURE_TAG}" data="{_fmt([-1.0] * CLOSURE_FIELDS)}"/>
    <numeric name="{MOTOR_TAG}" data="1"/>
  </custom>"""
    elif plugin:
        def config(**kv) -> str:
            return "".join(f'\n        <config key="{k}" value="{v:.17g}"/>' for k, v in kv.items())

        motor = dict(time_constant=tc, speed_limit=vmax, lead=lead)
        drives = [f"""
      <instance name="drive_{n}">{config(K=p.spring.K, delta0=p.spring.delta0, **motor)}
      </instance>""" for n in LEG_NAMES]
        drives.append(f"""
      <instance name="drive_ps">{config(**motor)}
      </instance>""")
        fields = f"""
  <extension>
    <plugin plugin="{DRIVE_PLUGIN}">{''.join(drives)}
    </plugin>
    <plugin plugin="{CLOSURE_PLUGIN}">
      <instance name="closure"/>
    </plugin>
  </extension>"""
    else:
        fields = ""

    return f"""<mujoco model="vswrist_{p.name.replace('*', '_mod')}">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{sim.timestep:.17g}" integrator="implicitfast" gravity="{gravity}" solver="Newton"
          iterations="{int(sim.solver_iterations)}" tolerance="{sim.solver_tolerance:.17g}" jacobian="dense"/>
{fields}
  <visual>
    <global offwidth="{OFFSCREEN_SIZE[0]}" offheight="{OFFSCREEN_SIZE[1]}"/>
    <headlight ambient="0.35 0.35 0.35" diffuse="0.6 0.6 0.6"/>
  </visual>
  <asset>
    <texture name="sky" type="skybox" builtin="gradient" rgb1="0.62 0.7 0.78" rgb2="0.12 0.13 0.16" width="256"
             height="256"/>
    <texture name="floor" type="2d" builtin="checker" rgb1="0.3 0.32 0.35" rgb2="0.24 0.26 0.29" width="256"
             height="256" mark="edge" markrgb="0.38 0.4 0.43"/>
    <material name="floor" texture="floor" texrepeat="10 10" reflectance="0.08"/>
  </asset>
  <default>
    <geom contype="0" conaffinity="0" group="1"/>
    <joint damping="{damping:.17g}"/>
  </default>
  <worldbody>
    <light name="key" pos="0.2 -0.3 0.5" dir="-0.3 0.5 -1" diffuse="0.6 0.6 0.6"/>
    <!-- a floor to see the scene against, drawn only: it collides with nothing (the default contype and
         conaffinity are 0), and it lies below every task object but above where unused ones are parked -->
    <geom name="floor" type="plane" pos="0 0 -0.3" size="1 1 0.05" material="floor" group="0"/>
    {cameras}
    <body name="base">
      <site name="base_site" pos="0 0 0" size="0.004"/>
      <geom name="forearm" type="cylinder" fromto="-0.13 0 0 -0.04 0 0" size="0.035" rgba="0.3 0.3 0.33 1"/>
      <geom name="forearm_cap" type="cylinder" fromto="-0.04 0 0 -0.036 0 0" size="0.03" rgba="0.45 0.45 0.48 1"/>{body_tail}
  </worldbody>
  <tendon>{''.join(tendons)}
  </tendon>
  <equality>
    {chr(10).join('    ' + w for w in welds).strip()}
  </equality>
  <actuator>
    {chr(10).join('    ' + a for a in actuators).strip()}
  </actuator>
  <sensor>
    <force name="tool_force" site="tool_site"/>
    <torque name="tool_torque" site="tool_site"/>
  </sensor>
</mujoco>
"""


def _resolve_physics(physics: str | None) -> str:
    """None: the plugin, or the reference callbacks under ``VSWRIST_NATIVE=0`` (``native.install``). Makes
    sure what the mode needs is loaded or installed."""

    if physics is None:
        return native.physics(native.install())
    _check_physics(physics)
    if physics == "plugin":
        native.load_plugin()
    return physics


def build_spec(params: WristParams | str | None = None, scene_fn: SceneFn | None = None,
               physics: str | None = None) -> mujoco.MjSpec:
    """An editable MjSpec of the wrist; ``scene_fn(spec)`` may add task bodies/geoms (world or ``tool`` body).
    ``physics`` as ``model_xml``; None: the plugin where a C compiler is available, else the callbacks."""
    p = load_params(params)
    spec = mujoco.MjSpec.from_string(model_xml(p, _resolve_physics(physics)))
    if scene_fn is not None:
        scene_fn(spec)
    return spec


def _fill_runtime_fields(m: mujoco.MjModel, p: WristParams) -> None:
    """Write the joint and body addresses the reference callbacks need into the model's ``vswrist_spring`` and
    ``vswrist_closure`` fields."""
    adr = m.numeric_adr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_NUMERIC, SPRING_TAG)]
    ids_link = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, f"leg{n}_q1") for n in LEG_NAMES]
    ids_motor = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, f"motor_{n}") for n in LEG_NAMES]
    data = [p.spring.K, p.spring.delta0]
    data += [m.jnt_dofadr[j] for j in ids_link] + [m.jnt_dofadr[j] for j in ids_motor]
    data += [m.jnt_qposadr[j] for j in ids_link] + [m.jnt_qposadr[j] for j in ids_motor]
    m.numeric_data[adr:adr + SPRING_FIELDS] = data
    adr = m.numeric_adr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_NUMERIC, CLOSURE_TAG)]
    bodies = ["coupler"] + [f"leg{n}_end" for n in LEG_NAMES[1:]]
    m.numeric_data[adr:adr + CLOSURE_FIELDS] = [0] + [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, b)
                                                      for b in bodies]


def home_motor_angles(params: WristParams | str | None = None) -> np.ndarray:
    """Motor angles (4,) at home with no preload: q1 of each leg, PS = 0."""
    kin = WristKinematics(params)
    return np.append(kin.joint_angles(np.zeros(2))[0::4], 0.0)


def build_model(params: WristParams | str | None = None, scene_fn: SceneFn | None = None,
                physics: str | None = None) -> mujoco.MjModel:
    """Compile the wrist (plus whatever ``scene_fn`` adds) with its ``home`` keyframe (and, for the reference
    callbacks, their runtime fields). ``physics`` as ``build_spec``."""
    p = load_params(params)
    physics = _resolve_physics(physics)
    spec = build_spec(p, scene_fn, physics)
    theta = home_motor_angles(p)
    ctrl = np.zeros(len(spec.actuators))
    ctrl[:4] = theta
    n_act_states = 4 + sum(a.dyntype != mujoco.mjtDyn.mjDYN_NONE for a in spec.actuators[4:])
    act = np.zeros(n_act_states)
    act[:4] = theta
    key = spec.add_key()
    key.name = "home"
    key.ctrl = ctrl
    key.act = act

    with native.compiling():  # the reference callbacks must not run inside the compiler
        m = spec.compile()
    if physics == "callbacks":
        _fill_runtime_fields(m, p)
        native.ensure_callbacks()
    return m


def export_xml(params: WristParams | str | None = None) -> str:
    """A self-contained MJCF of the wrist for other MuJoCo programs: ``model_xml(physics="plugin",
    nested=True)`` (the whole wrist is the subtree of ``base``, to attach elsewhere) with two keyframes at the
    home posture, at rest: ``home`` (no preload, as ``build_model``'s) and ``home_stiff`` (the largest internal
    preload the motor torque and deflection limits allow there, the stiffest wrist). Loads wherever the
    plugin library is loaded (``native.load_plugin()``, ``mujoco.mj_loadPluginLibrary``)."""
    from ..stiffness import lambda_range, motor_references

    p = load_params(params)
    u = np.zeros(2)
    theta = home_motor_angles(p)
    theta_stiff = np.append(motor_references(u, lambda_range(u, p)[1], p), 0.0)
    layout = mujoco.MjModel.from_xml_string(model_xml(p, "bare", nested=True))  # qpos addresses only
    qpos = layout.qpos0.copy()
    for name, angle in zip(LEG_NAMES, theta_stiff):
        qpos[layout.jnt_qposadr[mujoco.mj_name2id(layout, mujoco.mjtObj.mjOBJ_JOINT, f"motor_{name}")]] = angle
    key = f"""  <keyframe>
    <key name="home" ctrl="{_fmt(theta)}" act="{_fmt(theta)}"/>
    <key name="home_stiff" qpos="{_fmt(qpos)}" ctrl="{_fmt(theta_stiff)}" act="{_fmt(theta_stiff)}"/>
  </keyframe>
</mujoco>
"""
    return model_xml(p, "plugin", nested=True).rstrip().removesuffix("</mujoco>") + key
