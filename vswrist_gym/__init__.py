"""vswrist-gym: the VS-Wrist variable-stiffness wrist as a MuJoCo simulator and Gymnasium environments.

Importing the package registers the environment ids (``VSWrist/<Task>-v0``) and nothing else: the entry
points are strings, so MuJoCo, the simulator and torch are imported only when an environment is made.
"""

import argparse
import os
import sys
from importlib.metadata import PackageNotFoundError, version as _dist_version

from gymnasium.envs.registration import register, registry

try:
    __version__ = _dist_version("vswrist-gym")  # pyproject.toml's version, as installed
except PackageNotFoundError:  # a source tree on sys.path that was never installed
    __version__ = "0+unknown"

# MuJoCo picks its OpenGL back end once, when `mujoco` is first imported. On a Linux machine without a
# display its default (GLFW) aborts the process at the first offscreen render, so default to EGL there.
# Set MUJOCO_GL yourself (or import vswrist_gym before mujoco) to choose another.
if sys.platform.startswith("linux") and "MUJOCO_GL" not in os.environ and not (
        os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
    os.environ["MUJOCO_GL"] = "egl"

ENV_IDS = {
    "VSWrist/LoadHold-v0": "vswrist_gym.envs.load_hold:LoadHoldEnv",
    "VSWrist/Polish-v0": "vswrist_gym.envs.polish:PolishEnv",
    "VSWrist/Impact-v0": "vswrist_gym.envs.impact:ImpactEnv",
    "VSWrist/Insertion-v0": "vswrist_gym.envs.insertion:InsertionEnv",
    "VSWrist/Drill-v0": "vswrist_gym.envs.drill:DrillEnv",
    "VSWrist/Hammer-v0": "vswrist_gym.envs.hammer:HammerEnv",
}

TASKS = tuple(i.split("/")[1].removesuffix("-v0") for i in ENV_IDS)  # ("LoadHold", ...): the short names CLIs take


class TaskNameError(argparse.ArgumentTypeError, ValueError):
    """An unknown task name (a ValueError; argparse prints its message as it is)."""


def task_name(name: str) -> str:
    """A task's short name from either form every command accepts: 'Polish' or its full id 'VSWrist/Polish-v0'."""
    short = name.removeprefix("VSWrist/")
    full = f"VSWrist/{short}"
    if full in ENV_IDS:
        short = short.rsplit("-v", 1)[0]
    if short not in TASKS:
        raise TaskNameError(f"unknown task {name!r}; choose one of {', '.join(TASKS)} "
                                         f"(or its full id, e.g. {next(iter(ENV_IDS))})")
    return short

for _id, _entry in ENV_IDS.items():
    if _id not in registry:
        # episodes end by truncation inside the environment (episode_s of simulated time), so no TimeLimit
        # vector_entry_point: gym.make_vec(id, N) steps N worlds in one process, physics on threads
        register(id=_id, entry_point=_entry,
                 vector_entry_point=f"vswrist_gym.envs.batch:{_id.split('/')[1].removesuffix('-v0')}VectorEnv")
