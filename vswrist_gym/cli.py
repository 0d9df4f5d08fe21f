"""The ``vswrist`` command: one entry point, subcommands implemented in their own modules.

Each subcommand is ``module:function``; the function takes the remaining argv and returns an exit code.
Modules are imported lazily so that ``vswrist info`` does not import torch.
"""

from __future__ import annotations

import importlib
import sys

COMMANDS = {
    "info": ("vswrist_gym.tools.info:main", "device parameters, stiffness range at home, kinematics self-check"),
    "bench-sim": ("vswrist_gym.tools.sim_bench:main", "simulator speed: substeps/s, overhead against bare mj_step"),
    "reproduce": ("vswrist_gym.tools.reproduce:main", "regenerate the paper's section 5 figures and numbers"),
    "bench-env": ("vswrist_gym.tools.bench:main", "environment speed against Gymnasium's Ant-v5"),
    "video": ("vswrist_gym.tools.video:main", "write an episode video of an agent on a task"),
    "view": ("vswrist_gym.tools.view:main", "MuJoCo's interactive viewer on a running episode"),
    "train": ("vswrist_gym.agents.train:main", "train a PPO, SAC or recurrent PPO (ppo_lstm) policy"),
    "evaluate": ("vswrist_gym.agents.evaluate:main", "evaluate a trained or analytic agent"),
    "compare": ("vswrist_gym.agents.compare:main", "train, evaluate and compare agents on a task"),
    "aggregate": ("vswrist_gym.agents.aggregate:main", "scores across tasks: IQM, probability of improvement"),
    "export": ("vswrist_gym.model.export:main", "write the wrist as a self-contained MJCF (MuJoCo plugin)"),
    "sweep": ("vswrist_gym.sweep.cli:main", "run a sweep file (grid or hyperparameter search) on Ray"),
    "track": ("vswrist_gym.agents.track:main", "a track's runs (with --run) and its results table"),
}


def _usage() -> str:
    lines = ["usage: vswrist [--version] COMMAND [options]", "", "commands:"]
    lines += [f"  {name:<10} {help_}" for name, (_, help_) in COMMANDS.items()]
    lines += ["", "`vswrist COMMAND --help` for the options of one command."]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(_usage())
        return 0
    if argv[0] in ("-V", "--version"):
        from vswrist_gym import __version__

        print(f"vswrist-gym {__version__}")
        return 0
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        print(f"vswrist: unknown command '{name}'; choose one of: {', '.join(COMMANDS)}", file=sys.stderr)
        return 2
    module, func = COMMANDS[name][0].split(":")
    try:
        target = getattr(importlib.import_module(module), func)
    except (ImportError, AttributeError) as exc:
        print(f"vswrist: command '{name}' is not available in this installation ({exc})", file=sys.stderr)
        return 2
    return int(target(rest) or 0)


if __name__ == "__main__":
    sys.exit(main())
