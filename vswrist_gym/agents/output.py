"""Where a command's output goes: diagnostics through the package's loggers to stderr, results on stdout.

It lives in the agents layer (not in cli) so that modules run as `python -m` tools below the CLI can set the
output up as `vswrist` does without importing a higher layer."""

import logging
import sys

from . import progress


class _StderrHandler(logging.StreamHandler):
    """A handler that writes to whatever sys.stderr is at the time (pytest and tools replace it)."""

    def __init__(self):
        super().__init__(sys.stderr)

    @property
    def stream(self):
        return sys.stderr

    @stream.setter
    def stream(self, value):
        pass


class _Formatter(logging.Formatter):
    """INFO lines as they are; warnings and errors say so."""

    def format(self, record: logging.LogRecord) -> str:
        text = record.getMessage()
        if record.levelno >= logging.WARNING:
            text = f"{record.levelname.lower()}: {text}"
        if record.exc_info:
            text += "\n" + self.formatException(record.exc_info)
        return text


def configure_output(quiet: bool = False) -> None:
    """The package's loggers to stderr at INFO (WARNING when quiet), progress bars off when quiet. Called once per
    command; calling it again replaces its handler rather than adding a second."""
    logger = logging.getLogger("vswrist_gym")
    for h in list(logger.handlers):
        if isinstance(h, _StderrHandler):
            logger.removeHandler(h)
    handler = _StderrHandler()
    handler.setFormatter(_Formatter())
    logger.addHandler(handler)
    logger.setLevel(logging.WARNING if quiet else logging.INFO)
    progress.set_enabled(not quiet)


def _split_quiet(argv: list[str]) -> tuple[bool, list[str]]:
    """(quiet, argv without -q/--quiet): no command has a -q option of its own, so the flag may stand anywhere."""
    rest = [a for a in argv if a not in ("-q", "--quiet")]
    return len(rest) != len(argv), rest


def run_tool(main) -> int:
    """`python -m vswrist_gym.tools.<tool> [-q] ...`: a tool's ``main(argv)`` with the output set up as `vswrist`
    sets it up (diagnostics on stderr at INFO, -q/--quiet for warnings only and no progress bars)."""
    quiet, argv = _split_quiet(sys.argv[1:])
    configure_output(quiet)
    return int(main(argv) or 0)
