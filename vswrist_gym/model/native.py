"""Per-substep sinh springs and motor low-pass as MuJoCo callbacks, compiled C with a Python fallback.

MuJoCo callbacks (``mjcb_passive``, ``mjcb_act_dyn``) are process-global. These callbacks read every parameter
from the model they are called with (custom numeric ``vswrist_spring``, actuator ``dynprm``), so wrists with
different springs share them safely; for any model without the ``vswrist_spring`` / ``vswrist_motor`` fields
they call whatever callback was installed before (or do nothing), e.g. Gymnasium's Ant in the same process.

The C source below is compiled once per MuJoCo version with the system C compiler against the headers and
library shipped in the ``mujoco`` wheel, into a user cache directory (nothing is downloaded). Without a
compiler the same callbacks run in Python (correct, several times slower): ``backend()`` says which is active.
"""

from __future__ import annotations

import contextlib
import ctypes
import hashlib
import math
import os
import shutil
import subprocess
import sys
import tempfile
import warnings
from pathlib import Path

import mujoco
import numpy as np

from .builder import CLOSURE_FIELDS, CLOSURE_TAG, MOTOR_TAG, SPRING_FIELDS, SPRING_TAG

C_SOURCE = r"""
#include <math.h>
#include <string.h>
#include <mujoco/mujoco.h>

#define SPRING_FIELDS %(fields)d
#define CLOSURE_FIELDS %(closure_fields)d

static mjfGeneric prev_passive = 0;
static mjfAct prev_act_dyn = 0;

static const mjtNum* find_numeric(const mjModel* m, const char* name, int size) {
  for (int i = 0; i < m->nnumeric; i++) {
    if (m->numeric_size[i] == size && strcmp(m->names + m->name_numericadr[i], name) == 0) {
      return m->numeric_data + m->numeric_adr[i];
    }
  }
  return 0;
}

/* Loop-closure monitor: the largest weld violation (m or rad, as WristSim.loop_closure_error: the distance
   between the coupler's and a leg end's origins, or the angle between their frames) seen at any evaluation is
   kept in userdata[slot]. Body poses are current here (mj_fwdPosition runs before mj_passive), so a step of n
   substeps checks the state at the start of each of them, for a few dozen flops each. */
static void vswrist_closure(const mjModel* m, mjData* d) {
  const mjtNum* c = find_numeric(m, "%(closure)s", CLOSURE_FIELDS);
  if (!c) return;
  const int slot = (int)c[0], cb = (int)c[1];
  if (slot < 0 || slot >= m->nuserdata || cb < 0) return;
  const mjtNum* pc = d->xpos + 3 * cb;
  const mjtNum* qc = d->xquat + 4 * cb;
  mjtNum worst = d->userdata[slot];
  for (int k = 2; k < CLOSURE_FIELDS; k++) {
    const int e = (int)c[k];
    const mjtNum* pe = d->xpos + 3 * e;
    const mjtNum* qe = d->xquat + 4 * e;
    const mjtNum dx = pe[0] - pc[0], dy = pe[1] - pc[1], dz = pe[2] - pc[2];
    const mjtNum dist = sqrt(dx * dx + dy * dy + dz * dz);
    mjtNum dot = fabs(qc[0] * qe[0] + qc[1] * qe[1] + qc[2] * qe[2] + qc[3] * qe[3]);
    if (dot > 1.0) dot = 1.0;
    const mjtNum angle = 2.0 * acos(dot);
    if (dist > worst) worst = dist;
    if (angle > worst) worst = angle;
  }
  d->userdata[slot] = worst;
}

/* tau = -2 K sinh((q1 - theta) / delta0): +tau on the leg's first joint, -tau on the motor rotor. */
static void vswrist_passive(const mjModel* m, mjData* d) {
  const mjtNum* p = find_numeric(m, "%(spring)s", SPRING_FIELDS);
  if (!p) {
    if (prev_passive) prev_passive(m, d);
    return;
  }
  const mjtNum twoK = 2.0 * p[0], inv_d0 = 1.0 / p[1];
  for (int k = 0; k < 3; k++) {
    const mjtNum delta = d->qpos[(int)p[8 + k]] - d->qpos[(int)p[11 + k]];
    const mjtNum tau = -twoK * sinh(delta * inv_d0);
    d->qfrc_passive[(int)p[2 + k]] += tau;
    d->qfrc_passive[(int)p[5 + k]] -= tau;
  }
  vswrist_closure(m, d);
}

/* Servo setpoint: a rate-limited first-order low-pass of the reference (ctrl),
   d act/dt = clip((ctrl - act) / T, -vmax, vmax), kept within +-lead of the motor angle q (following-error
   limit, lead = kd vmax / kp): the PD loop kp (act - q) - kd qdot then never asks for more than vmax and does
   not wind up when the torque saturates. dynprm = (T, vmax, lead). */
static mjtNum vswrist_act_dyn(const mjModel* m, const mjData* d, int id) {
  if (!find_numeric(m, "%(motor)s", 1)) {
    return prev_act_dyn ? prev_act_dyn(m, d, id) : 0.0;
  }
  const mjtNum* prm = m->actuator_dynprm + id * mjNDYN;
  const mjtNum act = d->act[m->actuator_actadr[id]];
  const int jnt = m->actuator_trnid[2 * id];
  const mjtNum q = d->qpos[m->jnt_qposadr[jnt]], qdot = d->qvel[m->jnt_dofadr[jnt]];
  const mjtNum tb = 2.0 * m->opt.timestep;
  mjtNum rate = (d->ctrl[id] - act) / prm[0];
  if (rate > prm[1]) rate = prm[1];
  if (rate < -prm[1]) rate = -prm[1];
  const mjtNum hi = qdot + (q + prm[2] - act) / tb, lo = qdot + (q - prm[2] - act) / tb;
  if (rate > hi) rate = hi;
  if (rate < lo) rate = lo;
  return rate;
}

int vswrist_install(void) {
  if (mjcb_passive != vswrist_passive) { prev_passive = mjcb_passive; mjcb_passive = vswrist_passive; }
  if (mjcb_act_dyn != vswrist_act_dyn) { prev_act_dyn = mjcb_act_dyn; mjcb_act_dyn = vswrist_act_dyn; }
  return 1;
}

int vswrist_installed(void) {
  return mjcb_passive == vswrist_passive && mjcb_act_dyn == vswrist_act_dyn;
}

void vswrist_uninstall(void) {
  if (mjcb_passive == vswrist_passive) mjcb_passive = prev_passive;
  if (mjcb_act_dyn == vswrist_act_dyn) mjcb_act_dyn = prev_act_dyn;
  prev_passive = 0;
  prev_act_dyn = 0;
}
""" % {"fields": SPRING_FIELDS, "spring": SPRING_TAG, "motor": MOTOR_TAG, "closure": CLOSURE_TAG,
       "closure_fields": CLOSURE_FIELDS}

_lib: ctypes.CDLL | None = None
_backend: str | None = None
_py_prev: dict[str, object] = {}


def _mujoco_dir() -> Path:
    return Path(mujoco.__file__).resolve().parent


def _cache_dir() -> Path:
    root = os.environ.get("VSWRIST_CACHE") or os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(root) / "vswrist_gym"


def _library_path() -> Path:
    key = hashlib.sha256((C_SOURCE + mujoco.__version__ + sys.platform).encode()).hexdigest()[:16]
    return _cache_dir() / f"vswrist_callbacks_{key}.so"


def compile_library(force: bool = False) -> Path:
    """Compile the callbacks (once; atomically, safe with parallel processes) and return the library path."""
    target = _library_path()
    if target.is_file() and not force:
        return target
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        probe = tempfile.NamedTemporaryFile(dir=target.parent)
        probe.close()
    except OSError:  # read-only home: build in the temporary directory instead
        target = Path(tempfile.gettempdir()) / f"vswrist_gym_{os.getuid() if hasattr(os, 'getuid') else 0}" / target.name
        if target.is_file() and not force:
            return target
    compiler = os.environ.get("CC") or shutil.which("gcc") or shutil.which("cc")
    if compiler is None:
        raise RuntimeError("no C compiler (gcc/cc) found")
    mdir = _mujoco_dir()
    libs = sorted(mdir.glob("libmujoco.so*")) or sorted(mdir.glob("libmujoco*.dylib"))
    if not libs:
        raise RuntimeError(f"libmujoco not found in {mdir}")
    target.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=target.parent) as tmp:
        src = Path(tmp) / "vswrist_callbacks.c"
        src.write_text(C_SOURCE)
        out = Path(tmp) / target.name
        cmd = [compiler, "-O2", "-shared", "-fPIC", f"-I{mdir / 'include'}", str(src), "-o", str(out),
               str(libs[0]), f"-Wl,-rpath,{mdir}", "-lm"]
        res = subprocess.run(cmd, capture_output=True, text=True)
        if res.returncode != 0:
            raise RuntimeError(f"compiling the VS-Wrist callbacks failed: {' '.join(cmd)}\n{res.stderr}")
        os.replace(out, target)
    return target


# ----------------------------------------------------------------------------------- Python fallback
def _spring_field(m) -> np.ndarray | None:
    try:
        f = m.numeric(SPRING_TAG)
    except KeyError:
        return None
    return f.data if f.data.shape[0] == SPRING_FIELDS else None


def _py_passive(m, d) -> None:
    p = _spring_field(m)
    if p is None:
        prev = _py_prev.get("passive")
        if prev is not None:
            prev(m, d)
        return
    idx = p[2:].astype(int)
    delta = d.qpos[idx[6:9]] - d.qpos[idx[9:12]]
    tau = -2.0 * p[0] * np.sinh(delta / p[1])
    d.qfrc_passive[idx[0:3]] += tau
    d.qfrc_passive[idx[3:6]] -= tau
    _py_closure(m, d)


def weld_violation(xpos, xquat, coupler: int, ends) -> float:
    """Largest violation of the welds between body ``coupler`` and bodies ``ends``: the distance between their
    origins (m) or the angle between their frames (rad), whichever is larger (the C monitor's formula)."""
    pc, qc = xpos[coupler].tolist(), xquat[coupler].tolist()
    worst = 0.0
    for e in ends:
        pe, qe = xpos[e].tolist(), xquat[e].tolist()
        dx, dy, dz = pe[0] - pc[0], pe[1] - pc[1], pe[2] - pc[2]
        dot = abs(qc[0] * qe[0] + qc[1] * qe[1] + qc[2] * qe[2] + qc[3] * qe[3])
        worst = max(worst, math.sqrt(dx * dx + dy * dy + dz * dz), 2.0 * math.acos(min(1.0, dot)))
    return worst


def _py_closure(m, d) -> None:
    """The C monitor's twin: keep the largest weld violation seen in ``userdata[slot]``."""
    try:
        c = m.numeric(CLOSURE_TAG).data
    except KeyError:
        return
    if c.shape[0] != CLOSURE_FIELDS or not 0 <= int(c[0]) < m.nuserdata or c[1] < 0:
        return
    slot = int(c[0])
    d.userdata[slot] = max(float(d.userdata[slot]),
                           weld_violation(d.xpos, d.xquat, int(c[1]), [int(e) for e in c[2:]]))


def _py_act_dyn(m, d, i) -> float:
    try:
        m.numeric(MOTOR_TAG)
    except KeyError:
        prev = _py_prev.get("act_dyn")
        return prev(m, d, i) if prev is not None else 0.0
    tc, vmax, lead = m.actuator_dynprm[i, :3]
    act = d.act[m.actuator_actadr[i]]
    j = m.actuator_trnid[i, 0]
    q, qdot = d.qpos[m.jnt_qposadr[j]], d.qvel[m.jnt_dofadr[j]]
    tb = 2.0 * m.opt.timestep
    rate = min(max((d.ctrl[i] - act) / tc, -vmax), vmax)
    rate = min(rate, qdot + (q + lead - act) / tb)
    rate = max(rate, qdot + (q - lead - act) / tb)
    return float(rate)


# ------------------------------------------------------------------------------------------ install
def install(prefer: str = "auto") -> str:
    """Install the callbacks process-wide (idempotent); returns the backend, "c" or "python".

    ``prefer="python"`` forces the Python callbacks (for comparison); ``VSWRIST_NATIVE=0`` does the same.
    """
    global _lib, _backend
    if os.environ.get("VSWRIST_NATIVE", "1") == "0":
        prefer = "python"
    if prefer != "python":
        try:
            if _lib is None:
                _lib = ctypes.CDLL(str(compile_library()))
            if _backend == "python":
                _uninstall_python()
            _lib.vswrist_install()
            _backend = "c"
            return _backend
        except (OSError, RuntimeError) as exc:
            if prefer == "c":
                raise
            warnings.warn(f"VS-Wrist native callbacks unavailable ({exc}); using the slower Python callbacks",
                          RuntimeWarning, stacklevel=2)
    if _backend == "c" and _lib is not None:
        _lib.vswrist_uninstall()
    if mujoco.get_mjcb_passive() is not _py_passive:
        _py_prev["passive"] = mujoco.get_mjcb_passive()
        mujoco.set_mjcb_passive(_py_passive)
    if mujoco.get_mjcb_act_dyn() is not _py_act_dyn:
        _py_prev["act_dyn"] = mujoco.get_mjcb_act_dyn()
        mujoco.set_mjcb_act_dyn(_py_act_dyn)
    _backend = "python"
    return _backend


@contextlib.contextmanager
def compiling():
    """Hold the Python callbacks off while MuJoCo compiles a model: the compiler may run the physics on a model
    the Python bindings cannot wrap yet, and the callback then fails inside the compiler. A model being
    compiled needs no springs; the C callbacks read raw models and stay."""
    if _backend != "python":
        yield
        return
    saved = dict(_py_prev)
    _uninstall_python()
    try:
        yield
    finally:
        _py_prev.update(saved)
        mujoco.set_mjcb_passive(_py_passive)
        mujoco.set_mjcb_act_dyn(_py_act_dyn)


def _uninstall_python() -> None:
    if mujoco.get_mjcb_passive() is _py_passive:
        mujoco.set_mjcb_passive(_py_prev.get("passive"))
    if mujoco.get_mjcb_act_dyn() is _py_act_dyn:
        mujoco.set_mjcb_act_dyn(_py_prev.get("act_dyn"))
    _py_prev.clear()


def uninstall() -> None:
    """Remove the callbacks (restoring the previous ones): a bare MuJoCo for benchmarks."""
    global _backend
    if _backend == "c" and _lib is not None:
        _lib.vswrist_uninstall()
    elif _backend == "python":
        _uninstall_python()
    _backend = None


def installed() -> bool:
    """Whether the callbacks are currently in place (another library could have replaced them)."""
    if _backend == "c" and _lib is not None:
        return bool(_lib.vswrist_installed())
    if _backend == "python":
        return mujoco.get_mjcb_passive() is _py_passive and mujoco.get_mjcb_act_dyn() is _py_act_dyn
    return False


def backend() -> str | None:
    """"c", "python", or None when not installed."""
    return _backend
