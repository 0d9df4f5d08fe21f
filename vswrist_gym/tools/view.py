"""``vswrist view``: MuJoCo's interactive viewer on a running episode of a task.

    vswrist view --task Polish                              # the analytic baseline, stiffness command 0
    vswrist view --task Polish --agent analytic:1           # the baseline, stiff
    vswrist view --task Polish --agent runs/polish_ppo_0    # a trained run (vswrist train or an RL Zoo folder)
    vswrist view --task Polish --agent pretrained:Polish    # the policy shipped for Polish

The episode runs in real time (``--speed`` scales it); when it ends the next one starts (seed + 1). Keys:
space pauses and resumes, the right arrow advances one control step while paused, backspace restarts the
episode from its seed. MuJoCo's own mouse controls work as usual (ctrl + right-drag pushes a body). A trained
run drives the environment built with its own settings (action mode) and normalisation, as in
``vswrist evaluate``. Without a display (``$DISPLAY`` / ``$WAYLAND_DISPLAY`` unset) or where OpenGL cannot
open a window, the command stops with one line saying so.
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import sys
import time

from vswrist_gym import TASKS, resolve_id
from vswrist_gym.agents.evaluate import CHECKPOINT_CHOICES, CHECKPOINT_HELP

logger = logging.getLogger(__name__)

KEY_SPACE, KEY_RIGHT, KEY_BACKSPACE = 32, 262, 259  # GLFW key codes, as the viewer's key_callback reports them


class ViewerError(RuntimeError):
    """The viewer cannot open here (no display, no OpenGL window)."""


def check_display() -> None:
    """Raise ViewerError, in one line, where no window can open: no display on Linux, or GLFW failing to make an
    OpenGL window (probed with a hidden 16 x 16 window before the viewer starts, since a failure inside the
    viewer ends the process)."""
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise ViewerError("no display: $DISPLAY and $WAYLAND_DISPLAY are unset (run it on a desktop, over ssh -X, "
                          "or under xvfb-run; for frames without a display use vswrist video)")
    try:
        import glfw
    except ImportError as exc:
        raise ViewerError(f"the viewer needs the glfw package ({exc})") from None
    errors: list[str] = []
    previous = glfw.ERROR_REPORTING
    glfw.ERROR_REPORTING = "ignore"
    glfw.set_error_callback(lambda code, text: errors.append(text.decode() if isinstance(text, bytes) else text))
    try:
        if not glfw.init():
            raise ViewerError(f"cannot open a window on display {os.environ.get('DISPLAY')!r}: GLFW failed to "
                              f"initialise ({'; '.join(errors) or 'no reason given'})")
        glfw.window_hint(glfw.VISIBLE, glfw.FALSE)
        window = glfw.create_window(16, 16, "vswrist probe", None, None)
        if not window:
            raise ViewerError(f"cannot open an OpenGL window on display {os.environ.get('DISPLAY')!r} "
                              f"({'; '.join(errors) or 'no reason given'})")
        glfw.destroy_window(window)
        glfw.default_window_hints()
    finally:
        glfw.set_error_callback(None)
        glfw.ERROR_REPORTING = previous


class ViewerSession:
    """An episode loop driven by an agent, shown in a viewer; keys arrive from the viewer's thread and only set
    flags, which the loop reads between control steps."""

    def __init__(self, env, agent, seed: int = 0, speed: float = 1.0, log=print):
        self.env, self.agent, self.seed, self.speed, self.log = env, agent, seed, speed, log
        self.paused = False
        self._restart = False
        self._single_steps = 0
        self.steps = 0
        self.episodes = 0
        self.syncs = 0
        self.sim_time = 0.0
        self._ret = 0.0
        self.obs = None
        self.handle = None

    # called from the viewer's thread
    def key(self, keycode: int) -> None:
        if keycode == KEY_SPACE:
            self.paused = not self.paused
        elif keycode == KEY_RIGHT and self.paused:
            self._single_steps += 1
        elif keycode == KEY_BACKSPACE:
            self._restart = True

    def reset(self) -> None:
        self.obs, _ = self.env.reset(seed=self.seed)
        self._ret = 0.0
        self.episode_start = True

    def step(self) -> None:
        import numpy as np

        # the recurrent state (ppo_lstm) is carried from step to step; episode_start resets it
        action, self._state = self.agent.predict(self.obs, state=getattr(self, "_state", None),
                                                 episode_start=np.array([self.episode_start]), deterministic=True)
        self.episode_start = False
        self.obs, reward, term, trunc, info = self.env.step(action)
        self._ret += float(reward)
        self.steps += 1
        self.sim_time += self.env.unwrapped.ctrl_dt
        if term or trunc:
            self.episodes += 1
            self.log(f"episode {self.episodes} (seed {self.seed}): return {self._ret:.2f}, "
                     f"success {bool(info.get('is_success'))}, {'terminated' if term else 'truncated'}")
            self.seed += 1
            self.reset()

    def _launch(self, launch):
        u = self.env.unwrapped
        self.handle = launch(u.model, u.data, key_callback=self.key, show_left_ui=False, show_right_ui=False)
        self._model = u.model

    def run(self, launch, duration: float | None = None) -> None:
        """Step and show until the window closes or `duration` seconds (wall clock) have passed."""
        self.reset()
        self._launch(launch)
        dt = self.env.unwrapped.ctrl_dt / self.speed
        start = next_frame = time.monotonic()
        try:
            while self.handle.is_running() and (duration is None or time.monotonic() - start < duration):
                if self._restart:
                    self._restart = False
                    self.reset()
                if not self.paused or self._single_steps:
                    self._single_steps = max(self._single_steps - 1, 0)
                    self.step()
                if self.env.unwrapped.model is not self._model:  # a randomised device rebuilt the model
                    self._close()
                    self._launch(launch)
                self.env.unwrapped.sim.sync()  # body poses of the new state, for the scene
                self.handle.sync()
                self.syncs += 1
                next_frame += dt
                pause = next_frame - time.monotonic()
                if pause > 0:
                    time.sleep(pause)
                else:
                    next_frame = time.monotonic()  # behind (a slow machine): show every step, as fast as it goes
        finally:
            self._close()

    def _close(self) -> None:
        if self.handle is None:
            return
        self.handle.close()
        # the viewer's thread still swaps buffers for a moment after close(); leaving before it has stopped can end
        # the process in an X error (GLXBadDrawable) or a crash at exit
        deadline = time.monotonic() + 2.0
        while self.handle.is_running() and time.monotonic() < deadline:
            time.sleep(0.02)
        time.sleep(0.3)
        self.handle = None


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="vswrist view", description=__doc__.split("\n\n")[0])
    ap.add_argument("--task", required=True, type=resolve_id,
                    help=f"{', '.join(TASKS)} (the newest version), or a full id")
    ap.add_argument("--agent", default="analytic",
                    help="analytic | analytic:STIFFNESS | pretrained:TASK[:TRACK] | RUN_DIR | RL Zoo folder "
                         "(default: analytic)")
    ap.add_argument("--checkpoint", choices=CHECKPOINT_CHOICES, default="newest", help=CHECKPOINT_HELP)
    ap.add_argument("--seed", type=int, default=0, help="seed of the first episode (the next ones count up)")
    ap.add_argument("--speed", type=float, default=1.0, help="simulated seconds per wall-clock second (default 1)")
    ap.add_argument("--duration", type=float, default=None, help="close after this many wall-clock seconds")
    args = ap.parse_args(argv)
    if not (math.isfinite(args.speed) and args.speed > 0):
        ap.error(f"--speed must be a positive number, got {args.speed}")
    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        ap.error(f"--duration must be a positive number of seconds, got {args.duration}")
    env_id = args.task
    try:
        check_display()
        import gymnasium as gym
        import mujoco.viewer

        from vswrist_gym.agents.evaluate import AgentSpec
        from vswrist_gym.agents.hparams import ConfigError
        from vswrist_gym.agents.fileio import RunDirError

        try:
            spec = AgentSpec(args.agent, checkpoint=args.checkpoint)
            spec.check_task(env_id)
            env = gym.make(env_id, **spec.env_kwargs)
            agent = spec.make(env)
        except (ConfigError, RunDirError) as exc:
            print(f"vswrist view: error: {exc}", file=sys.stderr)
            return 2
    except ViewerError as exc:
        print(f"vswrist view: error: {exc}", file=sys.stderr)
        return 2
    session = ViewerSession(env, agent, seed=args.seed, speed=args.speed)
    logger.info(f"vswrist view: {env_id}, agent {args.agent}; space pauses, right arrow steps, backspace restarts")
    try:
        session.run(mujoco.viewer.launch_passive, duration=args.duration)
    except RuntimeError as exc:  # e.g. macOS outside mjpython
        print(f"vswrist view: error: the viewer did not start: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        pass
    finally:
        env.close()
    print(f"vswrist view: {session.steps} control steps ({session.sim_time:.2f} s simulated), "
          f"{session.syncs} frames, {session.episodes} finished episodes")
    return 0


if __name__ == "__main__":
    from vswrist_gym.cli import run_tool

    raise SystemExit(run_tool(main))
