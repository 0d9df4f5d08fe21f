"""Where a command's output goes: tables and results on stdout, diagnostics on stderr through logging (quiet with
-q), progress bars only on a terminal."""

import io
import os
import subprocess
import sys
from pathlib import Path

import pytest

import vswrist_gym
from vswrist_gym.agents import progress

ROOT = Path(vswrist_gym.__file__).resolve().parents[1]


def _vswrist(*args, cwd):
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONWARNINGS": "ignore"}
    return subprocess.run([sys.executable, "-m", "vswrist_gym.cli", *map(str, args)], capture_output=True, text=True,
                          env=env, cwd=cwd, timeout=300)


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def _terminal(monkeypatch) -> _Terminal:
    """stderr as a terminal would be, and bars allowed (as `vswrist` without -q sets them). Called in the test
    itself: pytest puts its own stderr back between a fixture's setup and the test."""
    term = _Terminal()
    monkeypatch.setattr(sys, "stderr", term)
    monkeypatch.setattr(progress, "_enabled", True)
    return term


@pytest.mark.parametrize("quiet", [[], ["-q"], ["--quiet"]])
def test_results_on_stdout_diagnostics_on_stderr(tmp_path, quiet):
    out = tmp_path / "eval"
    r = _vswrist(*quiet, "evaluate", "--task", "LoadHold", "--agent", "analytic", "--episodes", 1, "--seeds", 0,
                 "--out", out, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "rms_posture_error" in r.stdout and "wrote" not in r.stdout  # the table, and only results
    if quiet:
        assert r.stderr == ""
    else:
        assert f"wrote {out / 'metrics.json'}" in r.stderr


def test_quiet_may_follow_the_command(tmp_path):
    r = _vswrist("evaluate", "--task", "LoadHold", "--agent", "analytic", "--episodes", 1, "--seeds", 0,
                 "--out", tmp_path / "eval", "-q", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert r.stderr == "" and "rms_posture_error" in r.stdout


def test_no_bar_off_a_terminal(monkeypatch):
    monkeypatch.setattr(sys, "stderr", io.StringIO())
    monkeypatch.setattr(progress, "_enabled", True)
    assert isinstance(progress.bar(total=3), progress.NoBar)


def test_no_bar_when_quiet_or_asked_or_without_tqdm(monkeypatch):
    terminal = _terminal(monkeypatch)
    assert isinstance(progress.bar(total=3, disable=True), progress.NoBar)  # a command's --no-progress
    monkeypatch.setattr(progress, "_enabled", False)  # vswrist -q
    assert isinstance(progress.bar(total=3), progress.NoBar)
    monkeypatch.setattr(progress, "_enabled", True)
    monkeypatch.setitem(sys.modules, "tqdm", None)  # a core install: importing tqdm fails
    with progress.bar(total=3) as b:
        assert isinstance(b, progress.NoBar)
        b.update()
    assert terminal.getvalue() == ""


def test_evaluation_counts_its_episodes_on_a_terminal(monkeypatch):
    pytest.importorskip("tqdm")
    terminal = _terminal(monkeypatch)
    from vswrist_gym.agents.evaluate import AgentSpec
    from vswrist_gym.agents.protocol import evaluate

    records, _ = evaluate("VSWrist/LoadHold-v0", AgentSpec("analytic").make, [0, 1], 2, desc="analytic")
    assert len(records) == 4
    text = terminal.getvalue()
    # the bar counts 2 seeds x 2 episodes and moves as they finish (tqdm draws at most every 0.1 s, and a bar
    # that is not left on screen is erased at the end instead of drawn full)
    assert "analytic: episodes:   0%" in text and "| 0/4 [" in text and "| 1/4 [" in text


def test_commands_run_by_a_quiet_command_stay_quiet(tmp_path, monkeypatch, capsys):
    """`vswrist -q track --run` runs other commands in its process: they are quiet too, and a command run after
    the quiet one in the same process is not."""
    import logging

    from vswrist_gym import cli

    seen = []

    def fake(argv):
        seen.append(logging.getLogger("vswrist_gym").getEffectiveLevel())
        if argv:
            return cli.main(argv)  # the inner command
        logging.getLogger("vswrist_gym.test").info("inner info")
        return 0

    monkeypatch.setitem(cli.COMMANDS, "fake", ("tests_fake_module:main", ""))
    fake_module = type(sys)("tests_fake_module")
    fake_module.main = fake
    monkeypatch.setitem(sys.modules, "tests_fake_module", fake_module)
    try:
        assert cli.main(["-q", "fake", "fake"]) == 0
        assert seen == [logging.WARNING, logging.WARNING]
        assert cli.main(["fake"]) == 0
        assert seen[-1] == logging.INFO and "inner info" in capsys.readouterr().err
    finally:  # the package's logger as a library user has it: no handler, no level, bars allowed
        logger = logging.getLogger("vswrist_gym")
        for h in list(logger.handlers):
            logger.removeHandler(h)
        logger.setLevel(logging.NOTSET)
        progress.set_enabled(True)
