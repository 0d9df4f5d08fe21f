"""``vswrist video``: write one episode of an agent on a task as an MP4 (offscreen rendering).

Agents:

* ``reference`` (default): commands the task's posture reference (the ``target`` observation term) with a
  constant stiffness command ``--stiffness`` in [-1, 1], through ``reference_to_action``;
* ``adaptive``: as ``reference``, but soft (-1) until the tool/hand feels a load, then stiff (+1);
* ``random``: uniform random actions;
* a path to a stable-baselines3 ``.zip`` (``--algo ppo|sac``): its deterministic policy (raw observations; a
  model trained with observation normalisation needs its statistics, which this command does not load).

Rendering follows the package's rule (``vswrist_gym/__init__.py``): EGL on Linux without a display, unless
``MUJOCO_GL`` is set.
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

from vswrist_gym import TASKS


def reference_agent(env, stiffness: float):
    u = env.unwrapped
    sl = u.obs_slices["target"]

    def act(obs):
        return u.reference_to_action(np.asarray(obs)[sl], stiffness)
    return act


def adaptive_agent(env, threshold: float = 0.05):
    """Soft until the posture error (or a contact) shows a load, then stiff: the simplest adaptive rule."""
    u = env.unwrapped
    st, sp = u.obs_slices["target"], u.obs_slices["posture"]
    state = {"stiff": False}

    def act(obs):
        obs = np.asarray(obs)
        err = np.linalg.norm((obs[sp] - obs[st])[:2])
        contact = obs[u.obs_slices["contact_force"]][0] if "contact_force" in u.obs_slices else 0.0
        if err > threshold or contact > 1.0:
            state["stiff"] = True
        return u.reference_to_action(obs[st], 1.0 if state["stiff"] else -1.0)
    return act


def task_name(name: str) -> str:
    """A task's short name from either form that ``train`` and ``evaluate`` accept: 'Polish' or 'VSWrist/Polish-v0'."""
    short = name.removeprefix("VSWrist/").removesuffix("-v0")
    if short not in TASKS:
        raise argparse.ArgumentTypeError(f"unknown task {name!r}; choose one of {', '.join(TASKS)} "
                                         f"(or its full id, e.g. VSWrist/{TASKS[0]}-v0)")
    return short


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="vswrist video", description=__doc__.split("\n\n")[0])
    ap.add_argument("--task", required=True, type=task_name, help=f"{', '.join(TASKS)}, or a full id")
    ap.add_argument("--agent", default="reference", help="reference | adaptive | random | path/to/model.zip")
    ap.add_argument("--algo", default="ppo", choices=("ppo", "sac"), help="algorithm of a .zip agent")
    ap.add_argument("--out", required=True, help="output .mp4 file")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--stiffness", type=float, default=0.0, help="stiffness command of the reference agent")
    ap.add_argument("--camera", default=None, help="camera name (default: the task's render.camera)")
    ap.add_argument("--width", type=int, default=480)
    ap.add_argument("--height", type=int, default=360)
    args = ap.parse_args(argv)
    if not -1.0 <= args.stiffness <= 1.0:
        ap.error("--stiffness must be in [-1, 1]")
    if not args.out.endswith(".mp4"):
        ap.error("--out must name an .mp4 file")
    import gymnasium as gym
    import imageio

    import vswrist_gym  # noqa: F401

    render = {"width": args.width, "height": args.height}
    if args.camera:
        render["camera"] = args.camera
    env = gym.make(f"VSWrist/{args.task}-v0", render_mode="rgb_array", config={"render": render})
    if args.agent == "reference":
        policy = reference_agent(env, args.stiffness)
    elif args.agent == "adaptive":
        policy = adaptive_agent(env)
    elif args.agent == "random":
        env.action_space.seed(args.seed)
        policy = lambda obs: env.action_space.sample()  # noqa: E731
    elif args.agent.endswith(".zip") and os.path.exists(args.agent):
        import stable_baselines3 as sb3
        model = {"ppo": sb3.PPO, "sac": sb3.SAC}[args.algo].load(args.agent, device="cpu")
        policy = lambda obs: model.predict(obs, deterministic=True)[0]  # noqa: E731
    else:
        print(f"vswrist video: unknown agent {args.agent!r} (reference, adaptive, random or an existing .zip)",
              file=sys.stderr)
        return 2

    obs, info = env.reset(seed=args.seed)
    fps = env.unwrapped.metadata["render_fps"]
    total, done = 0.0, False
    with imageio.get_writer(args.out, fps=fps, codec="libx264", quality=7, macro_block_size=8) as writer:
        writer.append_data(env.render())
        while not done:
            obs, r, term, trunc, info = env.step(policy(obs))
            total += r
            done = term or trunc
            writer.append_data(env.render())
    env.close()
    print(f"{args.out}: {args.task}, agent {args.agent}, seed {args.seed}: return {total:.2f}, "
          f"success {info['is_success']}, peak contact force {info['peak_contact_force']:.2f} N")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
