"""`vswrist view`: the key handling of the episode loop (a scripted stand-in for the viewer window), the real
MuJoCo viewer for a few seconds under Xvfb, and the one-line error without a display."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys

import numpy as np
import pytest

from vswrist_gym.tools import view


class ScriptedViewer:
    """Stands in for mujoco.viewer.launch_passive's handle: presses keys on given frames, closes on the last."""

    def __init__(self, session, script: dict, close_at: int):
        self.session, self.script, self.close_at = session, script, close_at
        self.running, self.frames, self.closed = True, 0, False

    def is_running(self):
        return self.running

    def sync(self):
        self.frames += 1
        if self.frames in self.script:
            self.session.key(self.script[self.frames])
        if self.frames >= self.close_at:
            self.running = False

    def close(self):
        self.running, self.closed = False, True


def test_pause_single_step_and_restart():
    import gymnasium as gym

    from vswrist_gym.agents.analytic import AnalyticAgent

    env = gym.make("VSWrist/Polish-v1")
    session = view.ViewerSession(env, AnalyticAgent(env), seed=3, speed=1000.0, log=lambda *a: None)
    fresh = gym.make("VSWrist/Polish-v1")
    first_obs, _ = fresh.reset(seed=3)
    t0 = fresh.unwrapped.data.time  # the reset settles the wrist first: an episode starts at t0, not at 0
    fresh.close()
    script = {5: view.KEY_SPACE, 10: view.KEY_RIGHT, 15: view.KEY_BACKSPACE, 20: view.KEY_SPACE}
    handles = []

    def launch(model, data, key_callback, **kwargs):
        assert model is env.unwrapped.model and data is env.unwrapped.data
        assert key_callback == session.key
        handles.append(ScriptedViewer(session, script, close_at=25))
        return handles[0]

    session.run(launch)
    # 5 steps, paused (frames 6-10), one single step (frame 11), restart at frame 16 while paused, resumed after
    # frame 20: steps at frames 21-25
    assert session.steps == 5 + 1 + 5 and session.syncs == 25 and handles[0].closed
    ctrl_dt = env.unwrapped.ctrl_dt
    assert env.unwrapped.data.time == pytest.approx(t0 + 5 * ctrl_dt, abs=1e-9)  # 5 steps since the restart
    # the restart replays the episode from its seed: the same first observation
    session.reset()
    np.testing.assert_array_equal(session.obs, first_obs)
    env.close()


def _xvfb():
    if shutil.which("xvfb-run") is None or shutil.which("Xvfb") is None:
        pytest.skip("Xvfb is not installed (apt-get install xvfb)")


def test_viewer_runs_under_xvfb_and_exits():
    _xvfb()
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "PYOPENGL_PLATFORM")}
    res = subprocess.run(["xvfb-run", "-a", "-s", "-screen 0 1280x1024x24", sys.executable, "-m", "vswrist_gym.cli",
                          "view", "--task", "VSWrist/Polish-v1", "--duration", "4", "--speed", "2"],
                         capture_output=True, text=True, timeout=180, env=env)
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]
    m = re.search(r"(\d+) control steps \(([\d.]+) s simulated\), (\d+) frames, (\d+) finished episodes", res.stdout)
    assert m, res.stdout
    steps, simulated, frames, episodes = int(m[1]), float(m[2]), int(m[3]), int(m[4])
    # frames advance with the episode: one per control step; at least a second's worth in 4 s even on a slow
    # machine (at speed 2 in real time it is 8 s, 400 steps), and at most the real-time pace
    assert frames == steps and 50 <= steps <= 4 * 2 * 50 + 5
    assert simulated == pytest.approx(steps * 0.02, abs=0.011)
    assert episodes == steps // 150 and f"episode 1 (seed 0)" in res.stdout if steps >= 150 else True


def test_no_display_is_one_line():
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    res = subprocess.run([sys.executable, "-m", "vswrist_gym.cli", "view", "--task", "Polish"], capture_output=True,
                         text=True, timeout=120, env=env)
    assert res.returncode == 2 and "Traceback" not in res.stderr
    assert res.stderr.strip().count("\n") == 0 and "no display" in res.stderr


def test_unreachable_display_is_one_line():
    if not sys.platform.startswith("linux"):
        pytest.skip("X11 displays are a Linux matter here")
    env = {**os.environ, "DISPLAY": ":987"}
    env.pop("WAYLAND_DISPLAY", None)
    res = subprocess.run([sys.executable, "-m", "vswrist_gym.cli", "view", "--task", "Polish"], capture_output=True,
                         text=True, timeout=120, env=env)
    assert res.returncode == 2 and "Traceback" not in res.stderr
    assert res.stderr.strip().count("\n") == 0 and ":987" in res.stderr
