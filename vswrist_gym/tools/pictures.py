"""One picture per task for the README: the analytic baseline mid-episode, from the task's own camera.

    python -m vswrist_gym.tools.pictures --out docs/figures/tasks/

Each picture is the frame `render_mode="rgb_array"` gives (the task's `render` settings: 640 x 480, camera
`task_view`, floor and lights), at the step named below for the task, of episode seed 0 under the analytic
baseline at its default stiffness. The PNGs are reduced to a 256-colour palette to keep the repository small.
Rendering is offscreen: EGL on Linux without a display (the package's rule), or whatever `MUJOCO_GL` says.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

import numpy as np

from vswrist_gym import LATEST, TASKS, newest_task_name

logger = logging.getLogger(__name__)

# The control step at which each task's object is in view and in use: the tool on the surface (Polish), against
# the obstacle (Impact), in the hole (Insertion), the drill engaged (Drill), the load hanging (LoadHold) (50 Hz);
# the head mid-swing (Hammer, 100 Hz); the ball about to leave the hand (Throw, 100 Hz).
PICTURE_STEP = {"LoadHold": 100, "Polish": 75, "Impact": 90, "Insertion": 120, "Drill": 75, "Hammer": 16,
                "Throw": 26}


def frame(task: str, step: int | None = None, seed: int = 0, width: int | None = None,
          height: int | None = None) -> np.ndarray:
    """The rgb frame of `task` after `step` control steps of the analytic baseline (episode seed `seed`)."""
    import gymnasium as gym

    from vswrist_gym.agents.analytic import AnalyticAgent

    render = {k: v for k, v in (("width", width), ("height", height)) if v is not None}
    env = gym.make(LATEST[task], render_mode="rgb_array", config={"render": render} if render else None)
    try:
        agent = AnalyticAgent(env)
        obs, _ = env.reset(seed=seed)
        for _ in range(PICTURE_STEP[task] if step is None else step):
            obs, _, term, trunc, _ = env.step(agent.predict(obs, deterministic=True)[0])
            if term or trunc:
                break
        return np.asarray(env.render())
    finally:
        env.close()


def save_png(path: Path, rgb: np.ndarray, colours: int = 256) -> None:
    """A palette PNG (median-cut quantised): a quarter to a third the size of the full-colour one."""
    from PIL import Image

    Image.fromarray(rgb).quantize(colors=colours, method=Image.Quantize.MEDIANCUT).save(path, optimize=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m vswrist_gym.tools.pictures", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="docs/figures/tasks", help="output folder (default docs/figures/tasks)")
    ap.add_argument("--tasks", nargs="+", type=newest_task_name, default=list(TASKS),
                    help=f"short names or full ids (default all: {' '.join(TASKS)})")
    ap.add_argument("--seed", type=int, default=0, help="episode seed (default 0)")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for task in args.tasks:
        path = out / f"{task}.png"
        save_png(path, frame(task, seed=args.seed))
        logger.info(f"wrote {path}: {task}, step {PICTURE_STEP[task]}, seed {args.seed}, "
                    f"{path.stat().st_size // 1024} KiB")
    return 0


if __name__ == "__main__":
    from vswrist_gym.cli import run_tool

    raise SystemExit(run_tool(main))
