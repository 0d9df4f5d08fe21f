import os
import subprocess
import sys

import vswrist_gym  # noqa: F401  (sets MUJOCO_GL by the package's rule; must precede the first `import mujoco`)

import numpy as np
import pytest

from vswrist_gym.kinematics import WristKinematics


@pytest.fixture(scope="session", params=["paper", "paper_knm"])
def preset(request):
    return request.param


@pytest.fixture(scope="session")
def kin():
    return WristKinematics()


# One offscreen render of a one-sphere model with MuJoCo alone (none of this package's code), in a fresh
# interpreter that picks its OpenGL back end as the package does: a missing back end can abort the process.
_GL_PROBE = """
import vswrist_gym, mujoco
m = mujoco.MjModel.from_xml_string('<mujoco><worldbody><light pos="0 0 1"/><geom size="0.1"/></worldbody></mujoco>')
d = mujoco.MjData(m)
mujoco.mj_forward(m, d)
r = mujoco.Renderer(m, 16, 16)
r.update_scene(d)
assert r.render().shape == (16, 16, 3)
r.close()
"""


@pytest.fixture(scope="session")
def headless_gl():
    """Skip, with MuJoCo's reason, where this machine cannot render offscreen; decided once up front, so that
    the rendering tests themselves catch nothing and fail on any error of the code under test."""
    res = subprocess.run([sys.executable, "-c", _GL_PROBE], capture_output=True, text=True, timeout=120)
    if res.returncode != 0:
        reason = (res.stderr.strip().splitlines() or [f"exit status {res.returncode}"])[-1]
        pytest.skip(f"no offscreen OpenGL (MUJOCO_GL={os.environ.get('MUJOCO_GL')}): {reason}")


def final_info(env, policy, seed):
    """The last step's info of one episode of ``policy`` (obs -> action) from reset seed ``seed``."""
    obs, info = env.reset(seed=seed)
    done = False
    while not done:
        obs, _, term, trunc, info = env.step(policy(obs))
        done = term or trunc
    return info


def random_postures(kin, n, seed=0, margin=0.0):
    """n postures uniformly over the range of motion (optionally shrunk by ``margin`` rad)."""
    rng = np.random.default_rng(seed)
    return rng.uniform(kin.u_min + margin, kin.u_max - margin, size=(n, 2))
