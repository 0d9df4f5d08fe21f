"""One control period of many worlds in one C call: ``advance(...)`` steps each world's ``mj_step`` substeps
and brings what the environment reads up to date, for a chunk of a batch's worlds, without the GIL.

Why: a batch (``envs.batch.VSWristVectorEnv``) steps its worlds on threads. Through the bindings every world
costs several GIL hand-overs (``mj_step``, then ``mj_kinematics``/``mj_comPos``/``mj_comVel`` or
``mj_forward``, each releasing and re-taking the lock) and a few microseconds of Python between them; threads
then queue for the lock, and a thread that runs Python (the batch's rewards and observations) holds it for
milliseconds. Here a thread makes one ``ctypes`` call for its whole chunk (``ctypes`` releases the GIL for the
call), so the physics of one chunk overlaps the Python of another.

Per world the call does what ``VSWristEnv._advance`` does through ``WristSim`` (and the contact meter of
``shared.PeriodMeanForce``), in the same order, so the numbers are the same to the bit: zero the loop-closure
peak and the contact meter's window; with actuation latency, that many substeps on the previous motor
references (and the divergence check); write the motor references into ``ctrl``, the period's other calls of
``mj_step`` (a Throw world with a release watch, ``H_WATCH``: its search for the release to the substep, as
``ThrowEnv._advance_physics``), the divergence check on MuJoCo's NaN warnings (a diverged world is left as MuJoCo reset it,
unsynced, as ``WristSim.step`` raises before its sync), then the sync: ``mj_kinematics`` + ``mj_comPos`` +
``mj_comVel`` (``sync_kinematics``) or ``mj_forward`` with the sensors enabled (``WristSim._forward``).
Then, with a gather plan, it copies what the environment reads after the step (joint positions, the coupler's
pose and velocity, the loop-closure bodies, sensors: ``batch_sim.gather_plan``) into the world's row of
one array, on the world's thread, so that the batch reads every world's simulator in one NumPy array.

An error MuJoCo raises inside a world (``mju_error``) is intercepted as the Python bindings intercept it (a
thread-local log handler that jumps back to the world's ``setjmp``): that world's status says so and the
batch raises ``mujoco.FatalError`` naming it, as the bindings' ``mj_step`` would raise it; the process
lives on. The library is C++ (its thread pool, ``csrc/vswrist_advance.cc``); the system C++ compiler builds it
once per ``plugin_lib.library_key`` into the cache directory of the plugin library; where there is none,
``load()`` raises ``plugin_lib.NativeBuildError``. Only the reference physics (``VSWRIST_NATIVE=0``, the Python
callbacks, which hold the GIL inside ``mj_step``) steps world by world through ``WristSim``.
"""

from __future__ import annotations

import ctypes
import os
from pathlib import Path

import numpy as np

from .plugin_lib import CSRC, build_library, native_build_error

# columns of the handle table (one row per world, uint64): what the call needs of each world's MjModel/MjData, and
# the world's actuation latency this period (substeps run on the previous motor references before the new ones)
H_MODEL, H_DATA, H_PEAK, H_METER, H_METER_SIZE, H_LATENCY, H_WATCH = range(7)
HANDLE_COLUMNS = 7

# a world's release watch (``H_WATCH``: the address of its row of WATCH_SIZE float64, or 0: none), Throw's search
# for the release to the substep (``envs.throw.ThrowEnv._watch_worlds``): the release plane's point c and unit
# normal dir (m, base frame); the flags armed, passed, released, due (the ball's mass goes at the next substep
# boundary) as 0/1; the peak's data.time (s), speed (m/s) and linear velocity (3, m/s); active (0: the whole
# period is plain, before the forward swing); the ball's body id, its mass (kg) and principal inertia (kg m^2)
# once it has gone, and the reach (m) behind the plane beyond which a part is plain
(W_C, W_DIR, W_ARMED, W_PASSED, W_RELEASED, W_DUE, W_PEAK_TIME, W_PEAK_SPEED, W_PEAK_VEL, W_ACTIVE, W_BODY,
 W_MASS_GONE, W_INERTIA_GONE, W_REACH) = (0, 3, 6, 7, 8, 9, 10, 11, 12, 15, 16, 17, 18, 19)
WATCH_SIZE = 20

# ``status`` of a world after a call
OK, DIVERGED, MUJOCO_ERROR = 0, 1, 2

SYNC_NONE, SYNC_KINEMATICS, SYNC_FORWARD = 0, 1, 2

# what a gather plan (``plan``: rows of (field, start, count)) copies from each synced world into its row of ``out``:
# MjData arrays (flattened: xpos[b] starts at 3 b), the loop-closure peak (start and count 0, 1) and the coupler's
# measured RUD and FE (``sim.coupler_angles`` of the rotation matrix at xmat[start:start + 9]; count 2): computed on
# the physics threads with the C library's asin and atan2, which Python's ``math`` calls too
F_QPOS, F_QVEL, F_XPOS, F_XQUAT, F_XMAT, F_CVEL, F_SENSOR, F_SITE_XMAT, F_PEAK, F_ANGLES = range(10)

SOURCE = CSRC / "vswrist_advance.cc"


def advance_defines() -> dict[str, str]:
    """The -D flags of the C++ source: the layouts and codes it shares with this module, defined here only."""
    names = {"HANDLE_COLUMNS": HANDLE_COLUMNS, "H_MODEL": H_MODEL, "H_DATA": H_DATA, "H_PEAK": H_PEAK,
             "H_METER": H_METER, "H_METER_SIZE": H_METER_SIZE, "H_LATENCY": H_LATENCY, "H_WATCH": H_WATCH,
             "WATCH_SIZE": WATCH_SIZE, "W_C": W_C, "W_DIR": W_DIR, "W_ARMED": W_ARMED, "W_PASSED": W_PASSED,
             "W_RELEASED": W_RELEASED, "W_DUE": W_DUE, "W_PEAK_TIME": W_PEAK_TIME, "W_PEAK_SPEED": W_PEAK_SPEED,
             "W_PEAK_VEL": W_PEAK_VEL, "W_ACTIVE": W_ACTIVE, "W_BODY": W_BODY, "W_MASS_GONE": W_MASS_GONE,
             "W_INERTIA_GONE": W_INERTIA_GONE, "W_REACH": W_REACH, "OK": OK, "DIVERGED": DIVERGED,
             "MUJOCO_ERROR": MUJOCO_ERROR, "SYNC_KINEMATICS": SYNC_KINEMATICS, "SYNC_FORWARD": SYNC_FORWARD,
             "F_QPOS": F_QPOS, "F_QVEL": F_QVEL, "F_XPOS": F_XPOS, "F_XQUAT": F_XQUAT, "F_XMAT": F_XMAT,
             "F_CVEL": F_CVEL, "F_SENSOR": F_SENSOR, "F_SITE_XMAT": F_SITE_XMAT, "F_ANGLES": F_ANGLES}
    return {f"VSWRIST_{k}": str(v) for k, v in names.items()}


_lib = None  # the loaded library (ctypes), once loaded


def compile_library() -> Path:
    """Compile the library (once; atomically, safe with parallel processes) and return its path."""
    return build_library(SOURCE, "vswrist_advance", ("CXX", "g++", "c++", "clang++"), ["-pthread"],
                         advance_defines())


def load():
    """The compiled library (ctypes), built at first use; None under ``VSWRIST_NATIVE=0`` (the reference physics:
    callers then step world by world). ``NativeBuildError`` where it cannot be built (no C++ compiler)."""
    global _lib
    if _lib is None:
        if os.environ.get("VSWRIST_NATIVE", "1") != "0":
            try:
                lib = ctypes.CDLL(str(compile_library()))
            except (OSError, RuntimeError) as exc:
                raise native_build_error("batched advance (model/csrc/vswrist_advance.cc)", exc) from exc
            else:
                p, i = ctypes.c_void_p, ctypes.c_int
                lib.vswrist_advance.argtypes = [p, p, i, p, p, i, i, p, p, p, i, p, i]
                lib.vswrist_advance.restype = i
                lib.vswrist_pool_new.argtypes = [i]
                lib.vswrist_pool_new.restype = p
                lib.vswrist_pool_free.argtypes = [p]
                lib.vswrist_pool_free.restype = None
                lib.vswrist_pool_submit.argtypes = [p, p, p, p, p, i, i, p, p, p, i, i, p, i, p, i]
                lib.vswrist_pool_submit.restype = None
                lib.vswrist_pool_release.argtypes = [p, i]
                lib.vswrist_pool_release.restype = None
                lib.vswrist_pool_wait.argtypes = [p, i]
                lib.vswrist_pool_wait.restype = None
                lib.vswrist_pool_run_one.argtypes = [p, i]
                lib.vswrist_pool_run_one.restype = i
                lib.vswrist_pool_ready.argtypes = [p, p]
                lib.vswrist_pool_ready.restype = i
                _lib = lib
    return _lib or None


def _ptr(a: np.ndarray | None) -> int:
    return 0 if a is None else a.ctypes.data


def advance(lib, handles: np.ndarray, worlds: np.ndarray, theta: np.ndarray, ctrl_idx: np.ndarray, nstep: int,
            sync: int, status: np.ndarray, step_seconds: np.ndarray | None = None, plan: np.ndarray | None = None,
            out: np.ndarray | None = None) -> int:
    """One call over ``worlds`` (int32, indices into ``handles``) on the calling thread; ``theta``
    (len(worlds), 4) float64 C-contiguous, ``status`` int32 of len(worlds), written; ``step_seconds``: None or
    float64 accumulators per world; ``plan`` (int32 (k, 3)) and ``out`` (float64 C-contiguous (len(worlds),
    columns)): the gather. Returns the number of worlds not OK."""
    return lib.vswrist_advance(handles.ctypes.data, worlds.ctypes.data, len(worlds), theta.ctypes.data,
                               ctrl_idx.ctypes.data, nstep, sync, status.ctypes.data, _ptr(step_seconds),
                               *_gather_args(plan, out))


def _gather_args(plan: np.ndarray | None, out: np.ndarray | None) -> tuple:
    if out is None:
        return 0, 0, 0, 0
    assert plan.dtype == np.int32 and plan.flags.c_contiguous and out.dtype == np.float64 \
        and out.flags.c_contiguous and out.shape[1] == int(plan[:, 2].sum())
    return plan.ctypes.data, len(plan), out.ctypes.data, out.shape[1]


class Pool:
    """``threads`` C++ threads that step a batch's chunks of worlds (see the source). ``submit`` returns at
    once; ``run_one(keep)`` steps the next unclaimed released chunk on the calling thread (its index), unless
    at most ``keep`` are left unclaimed (-1); ``ready()`` gives the chunks' done flags; ``wait(c)`` blocks until
    chunk c is done, ``wait()`` until all released ones are. The arrays given to ``submit`` are kept referenced
    until the next submit, so they outlive the threads' use of them."""

    def __init__(self, lib, threads: int):
        self._lib, self.threads, self.pid = lib, threads, os.getpid()
        self._p = lib.vswrist_pool_new(threads)
        self._keep: tuple = ()

    def submit(self, handles, worlds, theta, ctrl_idx, nstep, sync, status, step_seconds, bounds,
               released: int | None = None, plan: np.ndarray | None = None, out: np.ndarray | None = None) -> None:
        """``released``: how many of the first chunks may run now (default all); ``release`` lets the others
        run once their rows of ``theta`` are written. ``plan``/``out``: the gather, as ``advance``."""
        self._keep = (handles, worlds, theta, ctrl_idx, status, step_seconds, plan, out, bounds)
        k = len(bounds) - 1
        self._lib.vswrist_pool_submit(self._p, handles.ctypes.data, worlds.ctypes.data, theta.ctypes.data,
                                      ctrl_idx.ctypes.data, nstep, sync, status.ctypes.data, _ptr(step_seconds),
                                      bounds.ctypes.data, k, k if released is None else int(released),
                                      *_gather_args(plan, out))

    def release(self, upto: int | None = None) -> None:
        """Lets chunks below ``upto`` (default: all) be claimed."""
        self._lib.vswrist_pool_release(self._p, len(self._keep[-1]) - 1 if upto is None else int(upto))

    def wait(self, chunk: int = -1) -> None:
        self._lib.vswrist_pool_wait(self._p, chunk)

    def run_one(self, keep: int = 0) -> int:
        return self._lib.vswrist_pool_run_one(self._p, keep)

    def ready(self) -> np.ndarray:
        flags = np.zeros(len(self._keep[-1]) - 1, dtype=np.int8)
        self._lib.vswrist_pool_ready(self._p, flags.ctypes.data)
        return flags.astype(bool)

    def close(self) -> None:
        """Stops and joins the threads (after the running job, which the caller has waited for)."""
        if self._p is not None and self.pid == os.getpid():  # a forked child has no threads to join
            self._lib.vswrist_pool_free(self._p)
        self._p = None

    def __del__(self):  # a batch dropped without close(): its idle threads are joined here
        try:
            self.close()
        except Exception:  # noqa: BLE001 - interpreter shutdown: the library may be gone already
            pass
