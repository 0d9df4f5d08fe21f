"""vswrist-gym: the VS-Wrist variable-stiffness wrist as a MuJoCo simulator and Gymnasium environments.

Importing the package registers the environment ids (``VSWrist/<Task>-vN``) and nothing else: the entry
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
    "VSWrist/LoadHold-v1": "vswrist_gym.envs.load_hold:LoadHoldEnv",
    "VSWrist/LoadHold-v2": "vswrist_gym.envs.load_hold:LoadHoldEnv",
    "VSWrist/Polish-v0": "vswrist_gym.envs.polish:PolishEnv",
    "VSWrist/Polish-v1": "vswrist_gym.envs.polish:PolishEnv",
    "VSWrist/Impact-v0": "vswrist_gym.envs.impact:ImpactEnv",
    "VSWrist/Impact-v1": "vswrist_gym.envs.impact:ImpactEnv",
    "VSWrist/Insertion-v0": "vswrist_gym.envs.insertion:InsertionEnv",
    "VSWrist/Drill-v0": "vswrist_gym.envs.drill:DrillEnv",
    "VSWrist/Drill-v1": "vswrist_gym.envs.drill:DrillEnv",
    "VSWrist/Drill-v2": "vswrist_gym.envs.drill:DrillEnv",
    "VSWrist/Hammer-v0": "vswrist_gym.envs.hammer:HammerEnv",
    "VSWrist/Hammer-v1": "vswrist_gym.envs.hammer:HammerEnv",
    "VSWrist/Throw-v0": "vswrist_gym.envs.throw:ThrowEnv",
}
# What an older version fixes over its task's config files (``id_config`` of ``VSWristEnv``; the caller's config
# still applies on top). The newest version of a task is its config files as they stand. CHANGELOG.md says what
# each version changed.
ENV_KWARGS = {
    "VSWrist/Polish-v0": {"id_config": {"task": {"contact_force": "last_substep"}}},  # the touch sensor's sample
    # without the cue that announces the load's onset (load_cue) or the drill's engagement (engage_cue)
    "VSWrist/LoadHold-v0": {"id_config": {"task": {"load_cone": 0.6}, "observation": [
        "posture", "posture_rate", "motor_angles", "deflections", "spring_torques", "stiffness", "lam", "prev_action",
        "target", "phase"]}},
    # the load within 0.6 rad of gravity (hung on the hand) rather than in any direction
    "VSWrist/LoadHold-v1": {"id_config": {"task": {"load_cone": 0.6}}},
    "VSWrist/Drill-v0": {"id_config": {"compensate_tool": False, "observation": [
        "posture", "posture_rate", "motor_angles", "deflections", "spring_torques", "stiffness", "lam", "prev_action",
        "target", "tool_wrench", "phase"]}},
    # the controller's gravity compensation without the PS flange and the tool (the hand and coupler only)
    "VSWrist/Drill-v1": {"id_config": {"compensate_tool": False}},
    "VSWrist/Impact-v0": {"id_config": {"compensate_tool": False}},
    # the swing from rest near the extension limit (no wind-up), its best constant and success thresholds
    "VSWrist/Hammer-v0": {"id_config": {"residual": {"stiffness_nominal": -0.5}, "task": {
        "fe_start": -0.75, "fe_back": -0.75, "success_speed_ratio": 1.75, "success_radius": 0.015}}},
}


def _split(env_id: str) -> tuple[str, int]:
    short, version = env_id.split("/")[1].rsplit("-v", 1)
    return short, int(version)


# the newest version of each task, in ENV_IDS order: what a short name ('Polish') means everywhere
LATEST = {}
for _id in ENV_IDS:
    _short, _v = _split(_id)
    if _short not in LATEST or _v > _split(LATEST[_short])[1]:
        LATEST[_short] = _id
TASKS = tuple(LATEST)  # ("LoadHold", ...): the short names CLIs take


class TaskNameError(argparse.ArgumentTypeError, ValueError):
    """An unknown task name (a ValueError; argparse prints its message as it is)."""


def _unknown(name: str) -> TaskNameError:
    return TaskNameError(f"unknown task {name!r}; choose one of {', '.join(TASKS)} "
                         f"(or its full id, e.g. {next(iter(ENV_IDS))})")


def task_name(name: str) -> str:
    """A task's short name from either form every command accepts: 'Polish' or a full id 'VSWrist/Polish-v1'
    (any registered version)."""
    short = name.removeprefix("VSWrist/")
    full = f"VSWrist/{short}"
    if full in ENV_IDS:
        short = _split(full)[0]
    if short not in TASKS:
        raise _unknown(name)
    return short


def resolve_id(name: str) -> str:
    """The registered id a task name means: a short name ('Polish') is its task's newest version
    ('VSWrist/Polish-v1'); a full id ('VSWrist/Polish-v0') is itself."""
    short = name.removeprefix("VSWrist/")
    if f"VSWrist/{short}" in ENV_IDS:
        return f"VSWrist/{short}"
    if short in LATEST:  # 'Polish' or 'VSWrist/Polish'
        return LATEST[short]
    raise _unknown(name)


def newest_task_name(name: str) -> str:
    """``task_name`` for the tools that run each task's newest version (bench, probe, pictures, ...): a full id
    of an older version is refused rather than silently replaced by the newest."""
    short = task_name(name)
    if resolve_id(name) != LATEST[short]:
        raise TaskNameError(f"{name} is not the newest version of {short}; this tool runs {LATEST[short]} "
                            f"(give {short!r})")
    return short


def vector_entry_name(env_id: str) -> str:
    """The name in ``vswrist_gym.envs.batch`` of an id's vector entry point ('VSWrist/Polish-v1' ->
    'PolishV1VectorEnv')."""
    short, version = _split(env_id)
    return f"{short}V{version}VectorEnv"


for _id, _entry in ENV_IDS.items():
    if _id not in registry:
        # episodes end by truncation inside the environment (episode_s of simulated time), so no TimeLimit
        # vector_entry_point: gym.make_vec(id, N) steps N worlds in one process, physics on threads
        register(id=_id, entry_point=_entry, kwargs=ENV_KWARGS.get(_id, {}),
                 vector_entry_point=f"vswrist_gym.envs.batch:{vector_entry_name(_id)}")
