"""tests/bit_snapshot.py, the before/after check of a change that must leave every number as it was: the same code
gives the same bits twice, a changed number is reported with its size, and a bad command line is one usage line."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bit_snapshot  # noqa: E402


def test_same_code_same_bits_and_a_changed_number_is_reported(tmp_path):
    first = bit_snapshot.snapshot(tasks=["LoadHold"], steps=30, worlds=2)
    assert set(first) == {"LoadHold/0/single", "LoadHold/1/single", "LoadHold/batch"}
    np.savez(tmp_path / "ref.npz", **first)
    again = bit_snapshot.snapshot(tasks=["LoadHold"], steps=30, worlds=2)
    assert all(line.endswith("IDENTICAL") for line in bit_snapshot.compare(again, np.load(tmp_path / "ref.npz")))
    again["LoadHold/batch"] = again["LoadHold/batch"].copy()
    again["LoadHold/batch"][7] += 1e-9
    lines = bit_snapshot.compare(again, np.load(tmp_path / "ref.npz"))
    diffs = [line for line in lines if not line.endswith("IDENTICAL")]
    assert len(diffs) == 1 and diffs[0].startswith("LoadHold/batch DIFF max "), lines
    assert float(diffs[0].rsplit(" ", 1)[1]) == pytest.approx(1e-9, rel=1e-3)  # the size of the change made


def test_usage_is_one_line():
    res = subprocess.run([sys.executable, str(Path(__file__).resolve().parent / "bit_snapshot.py"), "check"],
                         capture_output=True, text=True, timeout=60)
    assert res.returncode == 2 and res.stderr.strip().count("\n") == 0 and "save|check" in res.stderr
