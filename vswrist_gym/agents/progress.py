"""Progress bars on stderr for the commands that run longer than a few seconds (evaluate, aggregate, compare,
soak; training has stable-baselines3's own bar).

A bar is drawn only where tqdm is installed (the [train] extra: a core install runs without bars), stderr is a
terminal (a log file or a pipe gets no carriage-return clutter) and the command is not `vswrist --quiet`. Where
no bar is drawn, ``bar`` returns an object with the same few methods that does nothing, so callers never branch.
"""

from __future__ import annotations

import sys

_enabled = True  # `vswrist --quiet` turns bars off for the whole process (cli.configure_output)


def set_enabled(on: bool) -> None:
    global _enabled
    _enabled = bool(on)


def shown() -> bool:
    """Whether a bar would be drawn now (sys.stderr is looked up each time: tests and tools replace it)."""
    if not _enabled:
        return False
    try:
        return sys.stderr.isatty()
    except (AttributeError, ValueError):  # replaced by an object without isatty, or closed
        return False


class NoBar:
    """What ``bar`` returns where no bar is drawn: the tqdm methods the commands call, doing nothing."""

    def update(self, n: float = 1) -> None:
        pass

    def set_postfix_str(self, s: str = "", refresh: bool = True) -> None:
        pass

    def set_description_str(self, s: str = "", refresh: bool = True) -> None:
        pass

    def close(self) -> None:
        pass

    def __enter__(self) -> NoBar:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def bar(total: float | None = None, desc: str | None = None, unit: str = "it", disable: bool = False, **kwargs):
    """A tqdm bar on stderr, or a ``NoBar`` (see the module docstring); ``disable`` is a command's --no-progress."""
    if disable or not shown():
        return NoBar()
    try:
        from tqdm import tqdm
    except ImportError:  # a core install: tqdm comes with the [train] extra
        return NoBar()
    return tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, leave=False, **kwargs)
