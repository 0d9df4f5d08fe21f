"""The VS-Wrist's MuJoCo engine plugins (``vswrist.drive``, ``vswrist.closure``, ``vswrist.contact``): their C
source (``csrc/vswrist_plugin.c``), compiled at first use into a user cache directory, and loaded into the
process.

This module imports nothing else from the package: it is also the ``mujoco.plugins`` entry point, which
``import mujoco`` runs, possibly while a module of this package is halfway through its own ``import mujoco``.
``vswrist_gym.model.native`` is the interface the rest of the package uses.
"""

from __future__ import annotations

import contextlib
import ctypes
import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import mujoco

DRIVE_PLUGIN = "vswrist.drive"  # MuJoCo plugin names, registered by the library compiled here
CLOSURE_PLUGIN = "vswrist.closure"
CONTACT_PLUGIN = "vswrist.contact"
# the plugin state of a vswrist.contact instance, in this order (CONTACT_STATE_SIZE numbers)
CONTACT_STATE = ("force_sum", "substeps", "touched", "touch_time", "touch_pos_x", "touch_pos_y", "touch_pos_z",
                 "touch_vel_x", "touch_vel_y", "touch_vel_z")
CONTACT_STATE_SIZE = len(CONTACT_STATE)

CSRC = Path(__file__).resolve().parent / "csrc"  # the C and C++ sources, shipped as package data
PLUGIN_SOURCE = CSRC / "vswrist_plugin.c"


def plugin_defines() -> dict[str, str]:
    """The -D flags of the plugin source: the names and sizes it shares with Python, defined here only."""
    return {"VSWRIST_DRIVE_NAME": f'"{DRIVE_PLUGIN}"', "VSWRIST_CLOSURE_NAME": f'"{CLOSURE_PLUGIN}"',
            "VSWRIST_CONTACT_NAME": f'"{CONTACT_PLUGIN}"', "VSWRIST_CONTACT_NSTATE": str(CONTACT_STATE_SIZE)}


_plugin_path: Path | None = None  # the plugin library loaded into this process, if any


class NativeBuildError(RuntimeError):
    """The compiled physics (the C plugin or the C++ batched advance) could not be built or loaded. The package
    has one physics path, the compiled one; the Python callbacks are its reference, run only on request
    (``VSWRIST_NATIVE=0``), so a missing compiler is an error that says what to do rather than a silent slowdown."""


def native_build_error(what: str, exc: BaseException) -> NativeBuildError:
    """The error for a ``what`` (the plugin, the advance) that did not build, with the build's own message."""
    return NativeBuildError(
        f"vswrist-gym compiles its {what} at first use and could not: {exc}. Install a C and C++ compiler "
        f"(Debian/Ubuntu: apt install gcc g++; Fedora: dnf install gcc gcc-c++; macOS: xcode-select --install), "
        f"or set VSWRIST_NATIVE=0 to run the Python reference physics (several times slower, one thread; meant "
        f"for tests and comparisons)")


def _mujoco_dir() -> Path:
    return Path(mujoco.__file__).resolve().parent


def _cache_dir() -> Path:
    root = os.environ.get("VSWRIST_CACHE") or os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(root) / "vswrist_gym"


def library_key(source: str, flags: list[str], compiler: str, mujoco_dir: str, mujoco_version: str,
                platform: str = sys.platform) -> str:
    """The compiled library's cache key: everything its bytes and its loading depend on. The MuJoCo directory
    is in it because the library links to that directory's libmujoco by RUNPATH: a key without it let one
    virtual environment load a library built against another's MuJoCo."""
    text = "\0".join([source, *flags, compiler, mujoco_dir, mujoco_version, platform])
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _libmujoco() -> Path:
    mdir = _mujoco_dir()
    libs = sorted(mdir.glob("libmujoco.so*")) or sorted(mdir.glob("libmujoco*.dylib"))
    if not libs:
        raise RuntimeError(f"libmujoco not found in {mdir}")
    return libs[0]


def _find_compiler(compilers: tuple[str, ...]) -> str:
    env_var, *commands = compilers
    found = os.environ.get(env_var) or next(filter(None, map(shutil.which, commands)), None)
    if found is None:
        raise RuntimeError(f"no compiler (${env_var}, {'/'.join(commands)}) found")
    return str(Path(shutil.which(found) or found).resolve())


def library_target(source: Path, stem: str, compilers: tuple[str, ...], flags: list[str],
                   defines: dict[str, str]) -> tuple[str, list[str], Path]:
    """The compiler, its arguments and the cache path of the library ``build_library`` makes of these."""
    compiler = _find_compiler(compilers)
    args = ["-O2", "-shared", "-fPIC", *flags, *(f"-D{k}={v}" for k, v in defines.items())]
    key = library_key(Path(source).read_text(), args, compiler, str(_mujoco_dir()), mujoco.__version__)
    return compiler, args, _cache_dir() / f"{stem}_{key}.so"


def build_library(source: Path, stem: str, compilers: tuple[str, ...], flags: list[str],
                  defines: dict[str, str], force: bool = False) -> Path:
    """Compile the source file ``source`` with ``-D`` flags ``defines`` against the MuJoCo wheel's headers and
    library, once per ``library_key``, into the cache directory (or the temporary one where home is
    read-only); atomically, safe with parallel processes. ``compilers``: an environment variable naming the
    compiler, then the commands to try. Returns the library's path; RuntimeError without a compiler or when
    the compiler fails (its message included)."""
    compiler, args, target = library_target(source, stem, compilers, flags, defines)
    mdir = _mujoco_dir()
    if target.is_file() and not force:
        return target
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        probe = tempfile.NamedTemporaryFile(dir=target.parent)
        probe.close()
    except OSError:  # read-only home: build in the temporary directory instead
        uid = os.getuid() if hasattr(os, "getuid") else 0
        target = Path(tempfile.gettempdir()) / f"vswrist_gym_{uid}" / target.name
        if target.is_file() and not force:
            return target
    target.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=target.parent) as tmp:
        out = Path(tmp) / target.name
        cmd = [compiler, *args, f"-I{mdir / 'include'}", str(source), "-o", str(out), str(_libmujoco()),
               f"-Wl,-rpath,{mdir}", "-lm"]
        res = subprocess.run(cmd, capture_output=True, text=True)
        if res.returncode != 0:
            raise RuntimeError(f"compiling {stem} failed: {' '.join(cmd)}\n{res.stderr}")
        os.replace(out, target)
    return target


def compile_library(force: bool = False) -> Path:
    """Compile the plugin library (once; atomically, safe with parallel processes) and return its path."""
    # -fexceptions: the plugin calls mju_error, which the Python bindings turn into a C++ exception that must
    # unwind through these frames
    return build_library(PLUGIN_SOURCE, "vswrist_plugin", ("CC", "gcc", "cc"), ["-fexceptions"],
                         plugin_defines(), force)


def load_plugin() -> Path:
    """Compile (first use) and load the plugin library into this process; returns its path. Idempotent.

    Raises RuntimeError where there is no C compiler or the plugins did not register."""
    global _plugin_path
    if _plugin_path is not None:
        return _plugin_path
    path = compile_library()
    mujoco.mj_loadPluginLibrary(str(path))
    core = ctypes.CDLL(str(_libmujoco()))  # the library the bindings use: dlopen returns the loaded one
    core.mjp_getPlugin.restype = ctypes.c_void_p
    core.mjp_getPlugin.argtypes = [ctypes.c_char_p, ctypes.c_void_p]
    for name in (DRIVE_PLUGIN, CLOSURE_PLUGIN, CONTACT_PLUGIN):
        if not core.mjp_getPlugin(name.encode(), None):
            raise RuntimeError(f"loading {path} did not register the MuJoCo plugin {name}")
    _plugin_path = path
    return path


def plugin_library() -> Path | None:
    """The path of the plugin library loaded into this process (None before ``load_plugin``)."""
    return _plugin_path


def mujoco_entry_point() -> None:
    """``mujoco.plugins`` entry point: ``import mujoco`` calls it (for example in ``python -m mujoco.viewer``)
    when vswrist-gym is installed, so exported wrists open there. Quiet where no compiler is available:
    loading such a model then fails with MuJoCo's 'plugin not found' error; ``VSWRIST_NATIVE=0`` skips it."""
    if os.environ.get("VSWRIST_NATIVE", "1") == "0":
        return
    with contextlib.suppress(OSError, RuntimeError):
        load_plugin()
