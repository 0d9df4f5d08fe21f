"""Helpers shared by the contact tasks: rotations and boxes on mocap bodies placed per episode."""

from __future__ import annotations

import mujoco
import numpy as np

from ..kinematics import rot_x, rot_y  # noqa: F401  (re-exported for the task modules)


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

