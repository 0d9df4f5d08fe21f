import os

os.environ.setdefault("MUJOCO_GL", "egl")  # headless rendering; must precede the first `import mujoco`

import numpy as np
import pytest

from vswrist_gym.kinematics import WristKinematics


@pytest.fixture(scope="session", params=["paper", "paper_knm"])
def preset(request):
    return request.param


@pytest.fixture(scope="session")
def kin():
    return WristKinematics()


def random_postures(kin, n, seed=0, margin=0.0):
    """n postures uniformly over the range of motion (optionally shrunk by ``margin`` rad)."""
    rng = np.random.default_rng(seed)
    return rng.uniform(kin.u_min + margin, kin.u_max - margin, size=(n, 2))
