"""``vswrist video``: write one episode of an agent on a task as an MP4 (offscreen rendering).

Agents:

* ``reference`` (default): commands the task's posture reference (the ``target`` observation term) with a
  constant stiffness command ``--stiffness`` in [-1, 1], through ``reference_to_action``;
* ``adaptive``: as ``reference``, but soft (-1) until the tool/hand feels a load, then stiff (+1);
* ``random``: uniform random actions;
* ``analytic`` or ``analytic:STIFFNESS``: the analytic baseline, as ``vswrist evaluate`` runs it;
* ``pretrained:<Task>[:<track>]``: a policy shipped in the package (``vswrist_gym.pretrained``), as a trained run;
* a trained run: a ``vswrist train`` run directory or an RL Zoo experiment folder (``logs/ppo/VSWrist-Polish-v1_1``),
  or a model file inside either: its deterministic policy with its own normalisation statistics, on the
  environment built with its own ``env_kwargs`` (action mode). A run from another task, a model file outside a run
  folder, or an environment whose settings differ from the run's is a one-line error, never a wrong video.

Rendering follows the package's rule (``vswrist_gym/__init__.py``): EGL on Linux without a display, unless
``MUJOCO_GL`` is set.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from pathlib import Path

import numpy as np

from vswrist_gym import TASKS, resolve_id
from vswrist_gym.agents.evaluate import CHECKPOINT_CHOICES, CHECKPOINT_HELP
from vswrist_gym.agents.hparams import ALGO_NAMES

logger = logging.getLogger(__name__)


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



def stateful_policy(agent):
    """obs -> action for one episode, carrying the agent's recurrent state (ppo_lstm) from step to step and
    flagging the first step as an episode start, as the evaluation protocol does; stateless agents ignore both."""
    memory = {"state": None, "start": np.ones((1,), dtype=bool)}

    def policy(obs):
        action, memory["state"] = agent.predict(obs, state=memory["state"], episode_start=memory["start"],
                                                deterministic=True)
        memory["start"] = np.zeros((1,), dtype=bool)
        return action
    return policy

def check_video_args(args) -> None:
    """Everything the command line fixes, before an environment is built: the seed's range, the frame size and
    that --out can be written (its folder exists or can be made, is writable, and --out is not a folder)."""
    from vswrist_gym.agents.fileio import RunDirError, check_writable
    from vswrist_gym.agents.run_config import check_seed
    from vswrist_gym.envs.config import OFFSCREEN_SIZE

    check_seed(args.seed)
    for name, value, top in (("--width", args.width, OFFSCREEN_SIZE[0]), ("--height", args.height, OFFSCREEN_SIZE[1])):
        if not 16 <= value <= top:
            raise ValueError(f"{name} must be an integer in [16, {top}] pixels, got {value}")
    out = Path(args.out)
    if out.is_dir():
        raise ValueError(f"--out {out} is a folder; give a file name such as episode.mp4")
    try:
        check_writable(out.parent, "--out's folder")
    except RunDirError as exc:
        raise ValueError(str(exc)) from None
    if out.exists() and not os.access(out, os.W_OK):
        raise ValueError(f"--out {out} exists and is not writable")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="vswrist video", description=__doc__.split("\n\n")[0])
    ap.add_argument("--task", required=True, type=resolve_id,
                    help=f"{', '.join(TASKS)} (the newest version), or a full id")
    ap.add_argument("--agent", default="reference",
                    help="reference | adaptive | random | analytic[:S] | pretrained:TASK[:TRACK] | RUN_DIR | "
                         "RL Zoo folder | model file in one")
    ap.add_argument("--algo", choices=ALGO_NAMES, help="check that a trained agent is of this algorithm")
    ap.add_argument("--checkpoint", choices=CHECKPOINT_CHOICES, default="newest", help=CHECKPOINT_HELP)
    ap.add_argument("--out", required=True, help="output .mp4 file")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--stiffness", type=float, default=0.0, help="stiffness command of the reference agent")
    ap.add_argument("--camera", default=None, help="camera name (default: the task's render.camera)")
    ap.add_argument("--width", type=int, default=480)
    ap.add_argument("--height", type=int, default=360)
    ap.add_argument("--no-baseline", action="store_true",
                    help="do not run the best constant stiffness on the same episode beside a trained agent")
    args = ap.parse_args(argv)
    if not -1.0 <= args.stiffness <= 1.0:
        ap.error("--stiffness must be in [-1, 1]")
    if not args.out.endswith(".mp4"):
        ap.error("--out must name an .mp4 file")
    try:
        check_video_args(args)
    except ValueError as exc:
        print(f"vswrist video: error: {exc}", file=sys.stderr)
        return 2
    import gymnasium as gym
    import imageio

    import vswrist_gym  # noqa: F401
    from vswrist_gym.envs.config import EnvConfigError

    render = {"width": args.width, "height": args.height}
    if args.camera:
        render["camera"] = args.camera
    env_id = args.task
    builtin = args.agent in ("reference", "adaptive", "random")
    kwargs: dict = {}
    if not builtin:
        from vswrist_gym.agents.evaluate import AgentSpec
        from vswrist_gym.agents.hparams import ConfigError
        from vswrist_gym.agents.fileio import RunDirError

        try:
            spec = AgentSpec(args.agent, checkpoint=args.checkpoint)
            spec.check_task(env_id)
            if args.algo and spec.trained is not None and spec.trained.cfg.algo != args.algo:
                raise RunDirError(f"{args.agent} is a {spec.trained.cfg.algo.upper()} run, not {args.algo.upper()}")
        except (ConfigError, RunDirError) as exc:
            print(f"vswrist video: error: {exc}", file=sys.stderr)
            return 2
        if spec.trained is not None and spec.trained.note:
            logger.warning(spec.trained.note)
        kwargs = dict(spec.env_kwargs)  # the run's own settings (action mode), rendering added to them
    config = dict(kwargs.pop("config", None) or {})
    config["render"] = {**(config.get("render") or {}), **render}
    try:
        env = gym.make(env_id, render_mode="rgb_array", config=config, **kwargs)
    except EnvConfigError as exc:  # --camera, --width, --height: the environment's render settings
        print(f"vswrist video: error: {exc}", file=sys.stderr)
        return 2
    if args.agent == "reference":
        policy = reference_agent(env, args.stiffness)
    elif args.agent == "adaptive":
        policy = adaptive_agent(env)
    elif args.agent == "random":
        env.action_space.seed(args.seed)
        policy = lambda obs: env.action_space.sample()  # noqa: E731
    else:
        try:
            agent = spec.make(env)  # checks the environment against the run: spaces and settings
        except (ConfigError, RunDirError) as exc:
            env.close()
            print(f"vswrist video: error: {exc}", file=sys.stderr)
            return 2
        policy = stateful_policy(agent)

    obs, info = env.reset(seed=args.seed)
    fps = env.unwrapped.metadata["render_fps"]
    total, done = 0.0, False
    out = Path(args.out)
    # written under a temporary name and renamed at the end: a failed or interrupted video never replaces a file
    tmp = out.with_name(f".{out.stem}.partial.mp4")
    from vswrist_gym.agents.progress import bar

    try:
        with imageio.get_writer(tmp, fps=fps, codec="libx264", quality=7, macro_block_size=8) as writer, \
                bar(total=env.unwrapped.episode_steps + 1, desc="video: frames", unit="frame") as shown:
            writer.append_data(env.render())
            shown.update()
            while not done:
                obs, r, term, trunc, info = env.step(policy(obs))
                total += r
                done = term or trunc
                writer.append_data(env.render())
                shown.update()
        os.replace(tmp, out)
    except OSError as exc:
        print(f"vswrist video: error: writing {out}: {exc}", file=sys.stderr)
        return 1
    finally:
        tmp.unlink(missing_ok=True)
        env.close()
    print(f"{args.out}: {args.task}, agent {args.agent}, seed {args.seed}: return {total:.2f}, "
          f"success {info['is_success']}, peak contact force {info['peak_contact_force']:.2f} N")
    if not builtin and spec.kind == "trained" and not args.no_baseline:
        from vswrist_gym.agents.baseline import best_constant_episode

        best = best_constant_episode(env_id, args.seed, env_kwargs=spec.env_kwargs)
        if best is not None:
            print(f"best constant stiffness on the same episode: {best[0]}, return {best[1]:.2f}; "
                  f"difference (agent - best constant) {total - best[1]:+.2f}")
    return 0


if __name__ == "__main__":
    from vswrist_gym.cli import run_tool

    raise SystemExit(run_tool(main))
