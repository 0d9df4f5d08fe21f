"""Mount the exported VS-Wrist on a plain MJCF arm with ``MjSpec`` and step it.

    vswrist export --params paper_knm --out wrist.xml
    python examples/attach_arm.py wrist.xml [PLUGIN_LIBRARY]

The wrist's springs and motors are MuJoCo plugins, so the arm model needs nothing from vswrist-gym but the
plugin library (the path ``vswrist export`` printed; without one this script asks vswrist-gym for it). The
whole wrist is the subtree of its ``base`` body; ``attach_body`` copies it, with its actuators, tendons,
welds, plugin instances and keyframes, onto a site of the arm under a name prefix. MuJoCo keeps the
arm's ``<option>``: the wrist needs a timestep of 1 ms or less and the ``implicitfast`` integrator (the
solver settings below are the wrist's own, so that MuJoCo reports no attach conflict).
"""

from __future__ import annotations

import math
import sys

import mujoco
import numpy as np

ARM = """
<mujoco model="two_link_arm">
  <option timestep="0.001" integrator="implicitfast" solver="Newton" iterations="50" tolerance="1e-10"
          jacobian="dense"/>
  <worldbody>
    <light pos="0 -1 2" dir="0 1 -2"/>
    <geom name="floor" type="plane" size="1 1 0.05" rgba="0.3 0.32 0.35 1"/>
    <body name="upper_arm" pos="0 0 0.6">
      <joint name="shoulder" type="hinge" axis="0 1 0" damping="2"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.035" mass="1.5"/>
      <body name="forearm" pos="0.3 0 0">
        <joint name="elbow" type="hinge" axis="0 1 0" damping="1"/>
        <geom type="capsule" fromto="0 0 0 0.2 0 0" size="0.03" mass="0.8"/>
        <!-- the wrist's base frame: X along the forearm, as in the wrist's own model -->
        <site name="wrist_mount" pos="0.33 0 0"/>
      </body>
    </body>
  </worldbody>
  <actuator>
    <position name="shoulder" joint="shoulder" kp="400" kv="20"/>
    <position name="elbow" joint="elbow" kp="200" kv="10"/>
  </actuator>
</mujoco>
"""

PREFIX = "wrist/"


def build(wrist_xml: str) -> mujoco.MjModel:
    """The arm with the wrist mounted on its ``wrist_mount`` site."""
    arm = mujoco.MjSpec.from_string(ARM)
    wrist = mujoco.MjSpec.from_file(wrist_xml)
    arm.site("wrist_mount").attach_body(wrist.body("base"), PREFIX, "")
    return arm.compile()


def wrist_posture(m: mujoco.MjModel, d: mujoco.MjData) -> np.ndarray:
    """(RUD, FE) of the coupler relative to the wrist's base: the ZYX angles ``WristSim.posture`` reports."""
    base = d.xmat[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, PREFIX + "base")].reshape(3, 3)
    coupler = d.xmat[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, PREFIX + "coupler")].reshape(3, 3)
    R = base.T @ coupler
    return np.array([math.asin(max(-1.0, min(1.0, -R[2, 0]))), math.atan2(R[1, 0], R[0, 0])])


def run(wrist_xml: str, seconds: float = 2.0, key: str = "home_stiff") -> dict:
    """Start from the wrist's keyframe ``key`` (``home_stiff``: home posture, largest preload) with the forearm
    level, then swing the shoulder while the wrist's motors hold their references; returns the wrist posture
    at the start, its largest drift from it (rad) and the spring deflections at the end."""
    m = build(wrist_xml)
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_KEY, PREFIX + key))
    mujoco.mj_forward(m, d)
    start = wrist_posture(m, d)
    shoulder = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, "shoulder")
    drift = 0.0
    for k in range(int(round(seconds / m.opt.timestep))):
        d.ctrl[shoulder] = 0.3 * math.sin(2.0 * math.pi * 0.5 * d.time)  # rad, a slow swing of the arm
        mujoco.mj_step(m, d)
        if k % 10 == 0:
            drift = max(drift, float(np.abs(wrist_posture(m, d) - start).max()))
    joint = lambda name: m.jnt_qposadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, PREFIX + name)]  # noqa: E731
    deflection = np.array([d.qpos[joint(f"leg{n}_q1")] - d.qpos[joint(f"motor_{n}")] for n in "ABC"])
    return {"model": m, "start": start, "drift": drift, "deflection": deflection, "time": float(d.time)}


def main(argv: list[str]) -> int:
    if not argv or argv[0] in ("-h", "--help"):
        print(__doc__)
        return 0 if argv else 2
    if len(argv) > 1:
        mujoco.mj_loadPluginLibrary(argv[1])
    else:
        from vswrist_gym.model import native

        native.load_plugin()
    r = run(argv[0])
    m = r["model"]
    print(f"arm + wrist: {m.nbody} bodies, {m.nu} actuators, {m.nplugin} plugin instances")
    print(f"wrist posture at start (RUD, FE): {np.round(r['start'], 4)} rad")
    print(f"largest drift while the arm swings for {r['time']:.1f} s: {r['drift']:.4f} rad")
    print(f"spring deflections at the end (A, B, C): {np.round(r['deflection'], 4)} rad")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
