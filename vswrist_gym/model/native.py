"""The VS-Wrist's sinh springs and motor setpoint dynamics inside MuJoCo's substeps: an engine plugin in C, with
the same physics as Python callbacks for reference (``VSWRIST_NATIVE=0``).

The compiled path registers two MuJoCo engine plugins (``mjpPlugin``), ``vswrist.drive`` (passive force and
actuator capability: one instance per motor, the series spring and the setpoint dynamics, configured per
instance) and ``vswrist.closure`` (the loop-closure monitor). A model names them in its ``<extension>``
section (``builder.model_xml(physics="plugin")``), so it carries its own springs and motors: it runs in any
MuJoCo program that has loaded the plugin library (``load_plugin()``, ``mujoco.mj_loadPluginLibrary``), and
no other model in the process is touched. All mutable state lives in each ``mjData`` (``plugin_data``,
``plugin_state``), none in the library, so separate ``mjData`` may step on separate threads.

The C source (``csrc/vswrist_plugin.c``, built by ``plugin_lib``) is compiled with the system C compiler against
the headers and library shipped in the ``mujoco`` wheel, into a user cache directory (nothing is downloaded),
once per source, flags, compiler and MuJoCo installation (``plugin_lib.library_key``).

Without a C compiler ``install`` raises ``plugin_lib.NativeBuildError``, which says how to get one: there is
one physics path. The reference (``VSWRIST_NATIVE=0`` or ``install("python")``, for tests and comparisons): the
same physics as MuJoCo's process-global callbacks ``mjcb_passive`` / ``mjcb_act_dyn`` written in Python (correct,
several times slower), reading each model's parameters from its custom numeric ``vswrist_spring`` and actuator
``dynprm`` (``physics="callbacks"``); models without those fields are passed to whatever callback was installed
before. Such a model cannot be exported: outside this package nothing applies its springs. ``backend()`` says
which path is active.
"""

from __future__ import annotations

import contextlib
import math
import os

import mujoco
import numpy as np

from .plugin_lib import (CLOSURE_PLUGIN, DRIVE_PLUGIN, PLUGIN_SOURCE, NativeBuildError,  # noqa: F401
                         compile_library, load_plugin, mujoco_entry_point, native_build_error, plugin_library)

# The reference's parameters, which ``builder`` writes into a callbacks model as custom numerics: the springs'
# (K, delta0, then the spring and motor joints' addresses), the loop-closure monitor's (userdata slot, coupler
# body, end bodies) and a tag marking the model's motors as this package's
SPRING_TAG = "vswrist_spring"
MOTOR_TAG = "vswrist_motor"
SPRING_FIELDS = 14
CLOSURE_TAG = "vswrist_closure"
CLOSURE_FIELDS = 4

_backend: str | None = None
_py_prev: dict[str, object] = {}


# ---------------------------------------------------------------------------------- Python reference
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


def weld_opening(pc, qc, pe, qe, sqrt, acos, minimum) -> tuple:
    """How far one weld is open: the distance between the coupler's and a leg end's origins ``pc``, ``pe`` (x, y,
    z; m) and the angle between their frames ``qc``, ``qe`` (quaternions w, x, y, z; rad). One world's floats with
    math's ``sqrt``, ``acos`` and ``min``, or a batch's columns of worlds with NumPy's (``batch_sim``)."""
    dx, dy, dz = pe[0] - pc[0], pe[1] - pc[1], pe[2] - pc[2]
    dot = abs(qc[0] * qe[0] + qc[1] * qe[1] + qc[2] * qe[2] + qc[3] * qe[3])
    return sqrt(dx * dx + dy * dy + dz * dz), 2.0 * acos(minimum(1.0, dot))


def weld_violation(xpos, xquat, coupler: int, ends) -> float:
    """Largest violation of the welds between body ``coupler`` and bodies ``ends``: the distance between their
    origins (m) or the angle between their frames (rad), whichever is larger (the C monitor's formula)."""
    pc, qc = xpos[coupler].tolist(), xquat[coupler].tolist()
    worst = 0.0
    for e in ends:
        worst = max(worst, *weld_opening(pc, qc, xpos[e].tolist(), xquat[e].tolist(), math.sqrt, math.acos, min))
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
    """Make the springs and motors available to models built from now on; returns the backend, "c" (the
    compiled plugin) or "python" (the reference callbacks). Idempotent.

    "c" (and "auto", its other name) loads the plugin library, compiling it at first use, and removes the
    reference callbacks if this module installed them: no global callback remains; without a compiler it raises
    ``NativeBuildError``. ``prefer="python"`` installs the reference (for tests and comparisons), as does
    ``VSWRIST_NATIVE=0``.
    """
    global _backend
    if prefer not in ("auto", "c", "python"):
        raise ValueError(f"backend must be 'auto', 'c' or 'python', got {prefer!r}")
    if os.environ.get("VSWRIST_NATIVE", "1") == "0":
        prefer = "python"
    if prefer != "python":
        try:
            load_plugin()
        except (OSError, RuntimeError) as exc:
            raise native_build_error("MuJoCo plugin (the springs and motors, model/csrc/vswrist_plugin.c)",
                                     exc) from exc
        _uninstall_python()
        _backend = "c"
        return _backend
    ensure_callbacks()
    _backend = "python"
    return _backend


def ensure_callbacks() -> None:
    """Put the reference callbacks in place (again), for models built with ``physics="callbacks"``."""
    if mujoco.get_mjcb_passive() is not _py_passive:
        _py_prev["passive"] = mujoco.get_mjcb_passive()
        mujoco.set_mjcb_passive(_py_passive)
    if mujoco.get_mjcb_act_dyn() is not _py_act_dyn:
        _py_prev["act_dyn"] = mujoco.get_mjcb_act_dyn()
        mujoco.set_mjcb_act_dyn(_py_act_dyn)


@contextlib.contextmanager
def compiling():
    """Hold the Python callbacks off while MuJoCo compiles a model: the compiler may run the physics on a model
    the Python bindings cannot wrap yet, and the callback then fails inside the compiler. A model being
    compiled needs no springs."""
    if mujoco.get_mjcb_passive() is not _py_passive and mujoco.get_mjcb_act_dyn() is not _py_act_dyn:
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
    """Remove the reference callbacks (restoring the previous ones). The plugin library stays loaded (a
    shared library cannot be unloaded safely); it acts only on models that name its plugins."""
    global _backend
    _uninstall_python()
    _backend = None


def installed() -> bool:
    """Whether the active backend is in place (another library could have replaced the callbacks)."""
    if _backend == "c":
        return plugin_library() is not None
    if _backend == "python":
        return mujoco.get_mjcb_passive() is _py_passive and mujoco.get_mjcb_act_dyn() is _py_act_dyn
    return False


def backend() -> str | None:
    """"c" (plugin), "python" (reference callbacks), or None when neither was installed."""
    return _backend


def physics(backend_: str | None = None) -> str:
    """The ``builder`` physics mode for a backend: "plugin" for "c", "callbacks" for "python"."""
    b = backend_ or _backend
    if b not in ("c", "python"):
        raise ValueError(f"backend must be 'c' or 'python', got {b!r}")
    return "plugin" if b == "c" else "callbacks"
