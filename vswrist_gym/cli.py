"""The ``vswrist`` command: one entry point, subcommands implemented in their own modules.

Each subcommand is ``module:function``; the function takes the remaining argv and returns an exit code.
Modules are imported lazily so that ``vswrist info`` does not import torch, and so that a core install (no
[train] extra) runs every command that does not train or load a learned policy.

Output: tables and results go to stdout (print); diagnostics (what a command is doing, files written, warnings) go
through the module loggers to stderr, at level INFO, or WARNING with ``--quiet``, which also turns progress bars
off.
"""

from __future__ import annotations

import importlib
import sys

from vswrist_gym.agents.output import _split_quiet, configure_output, run_tool  # noqa: F401  (tools call cli.run_tool)
from vswrist_gym.model.plugin_lib import NativeBuildError

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
    "track": ("vswrist_gym.tools.track:main", "a track's runs (with --run) and its results table"),
    "gate": ("vswrist_gym.tools.gate:main", "validity gate per task: headroom and necessity of the stiffness"),
    "benchmark": ("vswrist_gym.tools.benchmark:main", "the leaderboard: gated tasks x tracks x algorithms, held out"),
}

# The commands that cannot start without the [train] extra: they check it before they write anything.
NEEDS_TRAIN = ("train", "compare", "benchmark")
# The top-level modules of each extra: a command that meets one missing names the extra to install.
EXTRA_MODULES = {
    "train": ("torch", "stable_baselines3", "sb3_contrib", "tensorboard", "matplotlib", "tqdm", "rich"),
    "stats": ("rliable", "pandas"),
    "sweep": ("ray", "optuna"),
}
TRAIN_CHECK = ("torch", "stable_baselines3", "sb3_contrib")


def missing_extra_message(command: str, module: str) -> str | None:
    """The one-line message for a command that needs module `module` (top level of a dotted name), or None when
    no extra provides it."""
    root = module.split(".")[0]
    for extra, modules in EXTRA_MODULES.items():
        if root in modules:
            return (f"vswrist {command}: error: this needs the [{extra}] extra ({root} is not installed): "
                    f"pip install 'vswrist-gym[{extra}]' (in a clone: pip install -e '.[{extra}]')")
    return None


def _missing(modules) -> str | None:
    """The first of `modules` that cannot be imported, without importing any of them."""
    import importlib.util

    for name in modules:
        try:
            if importlib.util.find_spec(name) is None:
                return name
        except (ImportError, ValueError):
            return name
    return None


def _usage() -> str:
    lines = ["usage: vswrist [--version] [-q | --quiet] COMMAND [options]", "", "commands:"]
    lines += [f"  {name:<10} {help_}" for name, (_, help_) in COMMANDS.items()]
    lines += ["", "-q, --quiet: warnings and errors only on stderr, no progress bars (results still go to stdout)",
              "`vswrist COMMAND --help` for the options of one command."]
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
    quiet = False
    while argv and argv[0] in ("-q", "--quiet"):
        quiet, argv = True, argv[1:]
    if not argv:
        print(_usage())
        return 0
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        print(f"vswrist: unknown command '{name}'; choose one of: {', '.join(COMMANDS)}", file=sys.stderr)
        return 2
    # `vswrist evaluate ... -q` means the same as `vswrist -q evaluate ...`; a command that runs others in this
    # process (`vswrist track --run`) passes its quietness on to them
    quiet_here, rest = _split_quiet(rest)
    quiet = quiet or quiet_here or (bool(_running) and _running[-1])
    configure_output(quiet)
    _running.append(quiet)
    try:
        return _dispatch(name, rest)
    finally:
        _running.pop()
        if _running:  # back to the calling command's setting
            configure_output(_running[-1])


_running: list[bool] = []  # quietness of the `vswrist` commands running in this process, outermost first


def _dispatch(name: str, rest: list[str]) -> int:
    if name in NEEDS_TRAIN and not {"-h", "--help"} & set(rest):
        absent = _missing(TRAIN_CHECK)
        if absent is not None:
            print(missing_extra_message(name, absent), file=sys.stderr)
            return 2
    module, func = COMMANDS[name][0].split(":")
    try:
        target = getattr(importlib.import_module(module), func)
    except (ImportError, AttributeError) as exc:
        message = missing_extra_message(name, getattr(exc, "name", None) or "")
        print(message or f"vswrist: command '{name}' is not available in this installation ({exc})", file=sys.stderr)
        return 2
    try:
        return int(target(rest) or 0)
    except NativeBuildError as exc:  # no compiler for the physics: what to install, not a traceback
        print(f"vswrist {name}: {exc}", file=sys.stderr)
        return 2
    except ModuleNotFoundError as exc:  # e.g. evaluating a learned policy on a core install
        message = missing_extra_message(name, exc.name or "")
        if message is None:
            raise
        print(message, file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
