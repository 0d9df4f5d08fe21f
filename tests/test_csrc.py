"""The C and C++ sources (``vswrist_gym/model/csrc``) and their compiled libraries' cache: the constants they
share with Python come as -D flags and a missing one stops the compiler with the source's own ``#error``; a
library built against one MuJoCo installation is never the one another installation loads; the key does not
depend on the process that computes it."""

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from vswrist_gym.model import advance_lib, plugin_lib

SOURCES = [(plugin_lib.PLUGIN_SOURCE, plugin_lib.plugin_defines), (advance_lib.SOURCE, advance_lib.advance_defines)]


def _c_compiler():
    try:
        return plugin_lib._find_compiler(("CC", "gcc", "cc"))
    except RuntimeError:
        pytest.skip("no C compiler")


@pytest.mark.parametrize("source, defines", SOURCES, ids=["plugin", "advance"])
def test_every_shared_constant_is_a_guarded_flag(source, defines):
    """Every VSWRIST_ macro the source uses but does not define itself is one Python passes, and each of those
    has an #ifndef ... #error guard (so the file cannot be compiled with a constant silently missing)."""
    text = source.read_text()
    own = set(re.findall(r"#define\s+(VSWRIST_\w+)", text))
    used = set(re.findall(r"\bVSWRIST_[A-Z0-9_]+\b", text)) - own
    assert used == set(defines())
    for name in defines():
        assert re.search(rf"#ifndef {name}\n#error \"{name} ", text), name


def test_a_missing_flag_stops_the_compiler_with_the_sources_error(tmp_path, monkeypatch):
    _c_compiler()
    monkeypatch.setenv("VSWRIST_CACHE", str(tmp_path))
    defines = plugin_lib.plugin_defines()
    missing = "VSWRIST_CONTACT_NSTATE"
    del defines[missing]
    with pytest.raises(RuntimeError, match=rf"compiling vswrist_plugin failed(.|\n)*#error \"{missing} "):
        plugin_lib.build_library(plugin_lib.PLUGIN_SOURCE, "vswrist_plugin", ("CC", "gcc", "cc"), ["-fexceptions"],
                                 defines)
    assert not list(tmp_path.rglob("*.so"))


def test_two_mujoco_installations_get_two_libraries(tmp_path, monkeypatch):
    """The same MuJoCo files reached through another directory (as a second virtual environment would hold
    them) give another cache entry, and that library's RUNPATH names the other directory."""
    _c_compiler()
    monkeypatch.setenv("VSWRIST_CACHE", str(tmp_path / "cache"))
    real = plugin_lib._mujoco_dir()
    other = tmp_path / "venv2" / "mujoco"
    other.parent.mkdir()
    other.symlink_to(real, target_is_directory=True)
    first = plugin_lib.compile_library()
    monkeypatch.setattr(plugin_lib, "_mujoco_dir", lambda: other)
    second = plugin_lib.compile_library()
    assert first != second and first.is_file() and second.is_file()
    readelf = subprocess.run(["readelf", "-d", str(second)], capture_output=True, text=True)
    if readelf.returncode == 0:
        assert str(other) in readelf.stdout and str(real) not in readelf.stdout


@pytest.mark.parametrize("source, defines", SOURCES, ids=["plugin", "advance"])
def test_the_key_is_the_same_in_another_process(source, defines):
    _c_compiler()
    args = (source, "lib", ("CC", "gcc", "cc"), ["-O1"], defines())
    here = plugin_lib.library_target(*args)[2]
    code = ("from pathlib import Path; from vswrist_gym.model import plugin_lib, advance_lib as a;"
            f"print(plugin_lib.library_target(Path({str(source)!r}), 'lib', ('CC', 'gcc', 'cc'), ['-O1'],"
            f" {'plugin_lib.plugin_defines()' if source == plugin_lib.PLUGIN_SOURCE else 'a.advance_defines()'})[2])")
    env = dict(os.environ, PYTHONHASHSEED="12345")  # another string-hash seed: a key built on hash() would differ
    there = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                           cwd=Path(__file__).resolve().parents[1], check=True).stdout.strip()
    assert Path(there) == here


def test_the_sources_ship_in_the_package():
    """pyproject's package data names the sources (a wheel built from it carries them)."""
    root = Path(__file__).resolve().parents[1]
    text = (root / "pyproject.toml").read_text()
    assert '"model/csrc/*"' in text
    for source, _ in SOURCES:
        assert source.parent == root / "vswrist_gym" / "model" / "csrc" and source.is_file()
