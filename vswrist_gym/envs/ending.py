"""How a step ends, over arrays of worlds: its physics failing, what the environment does then, and the episode's
end. The single env (``base.VSWristEnv._finish_step``) calls these with its one world, the batch (``batch_step``)
with its live worlds.

A world's physics failed when its simulator reported a divergence (MuJoCo found the state unstable and reset it:
``WristSim.step`` raised ``SimulationError``) or its measured posture or spring deflections are not finite. Its
episode then ends (terminated, with the termination penalty) from a clean, finite state, so that the last
observation is valid; the period's loop-closure opening is unknown (inf).
"""

from __future__ import annotations

import math

import numpy as np


def step_failures(reported: dict, posture: np.ndarray, deflections: np.ndarray, t: list) -> dict[int, str]:
    """{world: why its physics failed this step} of N worlds: ``reported`` {world: the simulator's message} of the
    worlds whose simulator reported a divergence (in world order), else ``posture`` (N, 3) or ``deflections``
    (N, 3) not finite (``t`` (N,): the worlds' times, s, for the message). The simulators' reports come first."""
    failures = dict(reported)
    # the usual step, where every number is finite, costs two whole-array tests; the worlds are told apart only
    # when one of them fails
    if not (np.isfinite(posture).all() and np.isfinite(deflections).all()):
        bad = ~(np.isfinite(posture).all(axis=1) & np.isfinite(deflections).all(axis=1))
        for k in np.flatnonzero(bad).tolist():
            if k not in failures:
                failures[k] = f"non-finite state at t = {t[k]:.3f} s"
    return failures


def restart_failed(worlds: list, failures: dict, closure: list) -> None:
    """The worlds ``failures`` names (indices into ``worlds``) restart from the simulator's initial state, with
    no wrench, and are measured again (``_measure``); their loop-closure opening (``closure[k]``) becomes inf:
    MuJoCo already reset the diverged state, so the opening it reached is unknown."""
    for k in failures:
        closure[k] = math.inf
        e = worlds[k]
        e.sim.reset()
        e.sim.apply_wrench(np.zeros(3), np.zeros(3))
        e._measure()


def episode_end(terminated, step, episode_steps: int, closure, closure_warn: float, closure_truncate: bool):
    """How a step ends the episode, over arrays of worlds or one world's numbers: (time_up, cut, truncated). The
    last step (``episode_steps``) of an episode not ended by a divergence (``terminated``); ``closure_truncate``:
    the welds opened past ``closure_warn``, so the physics from here on is not trustworthy; either truncates."""
    going = np.logical_not(terminated)
    time_up = going & (step >= episode_steps)
    cut = going & (closure > closure_warn) & closure_truncate
    return time_up, cut, time_up | cut
