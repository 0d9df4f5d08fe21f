"""Actions: the four action modes, the command maps they use, and the action checks.

Action mode ``posture_stiffness`` (the default): four numbers in [-1, 1].

* a[0:3] -> posture reference (RUD, FE, PS), each mapped **linearly** onto the device's range of motion
  (``range_of_motion`` in the parameter preset): ref = lo + (a + 1) / 2 (hi - lo).
* a[3] -> internal torque lam in [0, lam_max], monotone in stiffness. With the ``asinh`` map (default)
  lam = 2K sinh(f asinh(lam_max / 2K)), f = (a + 1) / 2: since the per-leg spring stiffness is
  (2K/delta0) sqrt(1 + (tau/2K)^2), equal steps of the command give roughly equal *ratios* of stiffness
  (log-like), which resolves the soft end as well as the stiff end. ``linear`` maps f onto lam linearly.
  Only lam >= 0 is used: the stiffness grows with |lam| for either sign (the load term makes negative lam a
  little softer than positive), so a signed map would not be monotone. lam_max is the smallest upper
  bound of the reachable range over the range of motion, so every command is reachable at every posture.

Mode ``posture_compliance`` (6 numbers): posture as above, then two diagonal compliances log-mapped onto
``compliance.min..max`` and an off-diagonal correlation in (-0.9, 0.9). Mode ``residual`` (4): a posture offset
of at most ``residual.posture_scale`` rad around the task's reference and a stiffness command
``stiffness_nominal + stiffness_scale a``. Mode ``motor`` (4): motor references directly, linear over the legs'
reachable angles +- the deflection limit (and the PS range).
"""

from __future__ import annotations

import math

import numpy as np


class StiffnessMap:
    """Stiffness command s in [-1, 1] <-> internal torque lam in [0, lam_max] (N m)."""

    def __init__(self, lam_max: float, K: float, kind: str = "asinh"):
        if not lam_max > 0.0:
            raise ValueError(f"lam_max must be positive, got {lam_max}")
        self.lam_max, self.two_k, self.kind = float(lam_max), 2.0 * float(K), kind
        self._a = float(np.arcsinh(self.lam_max / self.two_k))

    def to_lam(self, s):
        """lam (N m) of stiffness commands ``s``: one world's number or a batch's array (clipped to [-1, 1])."""
        f = 0.5 * (np.minimum(np.maximum(np.asarray(s, dtype=float), -1.0), 1.0) + 1.0)
        if self.kind == "linear":
            return f * self.lam_max
        return self.two_k * np.sinh(f * self._a)

    def to_command(self, lam: float) -> float:
        lam = min(max(float(lam), 0.0), self.lam_max)
        f = lam / self.lam_max if self.kind == "linear" else float(np.arcsinh(lam / self.two_k)) / self._a
        return 2.0 * f - 1.0


class PostureMap:
    """Posture command in [-1, 1]^3 <-> posture reference (RUD, FE, PS), rad, linear over the range of motion."""

    def __init__(self, lo: np.ndarray, hi: np.ndarray):
        self.lo = np.asarray(lo, dtype=float)
        self.hi = np.asarray(hi, dtype=float)
        self.half = 0.5 * (self.hi - self.lo)
        self.mid = 0.5 * (self.hi + self.lo)

    def to_posture(self, a: np.ndarray) -> np.ndarray:
        # np.clip(a, -1, 1) through the ufuncs directly (np.clip's dispatch costs more than the arithmetic)
        return self.mid + self.half * np.minimum(np.maximum(a, -1.0), 1.0)

    def to_command(self, posture: np.ndarray) -> np.ndarray:
        return np.clip((np.asarray(posture, dtype=float) - self.mid) / self.half, -1.0, 1.0)

    def clip(self, posture: np.ndarray) -> np.ndarray:
        return np.minimum(np.maximum(posture, self.lo), self.hi)


def check_action(action, shape: tuple[int, ...]) -> np.ndarray:
    """The action as float64, or a one-line ValueError naming what is wrong.

    Accepted: an array (NumPy or anything ``np.asarray`` reads, e.g. a torch tensor) of exactly ``shape``
    holding real numbers (any float or integer dtype), or a list/tuple of that many real numbers. Refused,
    because each hides a bug in the caller rather than an action: other shapes, even of the right size
    ((1, 4) from a batched policy, (2, 2)), since flattening them guesses the layout; complex values (the cast
    would drop the imaginary part); booleans (a mask passed by mistake); strings, None and other objects;
    NaN and inf."""
    try:
        a = np.asarray(action)
    except (ValueError, TypeError) as exc:  # ragged nesting, or an object NumPy cannot read
        raise ValueError(f"action must be a 1-D array of shape {shape} (or a list of {shape[0]} numbers), "
                         f"got {type(action).__name__} that is not a regular array: {exc}") from None
    if a.dtype.kind not in "fiu":
        raise ValueError(f"action must hold real numbers (a float or integer dtype) in [-1, 1], got dtype "
                         f"{a.dtype} ({type(action).__name__})")
    if a.shape != shape:
        raise ValueError(f"action must be a 1-D array of shape {shape} (or a list of {shape[0]} numbers), "
                         f"got shape {a.shape}; reshape or index a batch yourself")
    a = a.astype(np.float64)  # a copy: the caller's array is never modified
    if not np.isfinite(a).all():
        bad = [i for i in range(a.size) if not np.isfinite(a[i])]
        kinds = sorted({"NaN" if np.isnan(a[i]) else "inf" for i in bad})
        raise ValueError(f"action holds {' and '.join(kinds)} at index {bad}: {a.tolist()}; "
                         f"actions must be finite numbers in [-1, 1]")
    return a


def check_actions(actions, n: int, shape: tuple[int, ...]) -> np.ndarray:
    """A batch's actions (``n`` rows of ``shape``) as float64, or a ``ValueError`` naming the env index of the
    first bad row: checked before any world is stepped, so a bad batch changes nothing."""
    try:
        arr = np.asarray(actions)
    except (ValueError, TypeError) as exc:
        raise ValueError(f"actions must be an array of shape ({n}, {', '.join(map(str, shape))}), got "
                         f"{type(actions).__name__} that is not a regular array: {exc}") from None
    if arr.shape != (n,) + shape:
        raise ValueError(f"actions must have shape {(n,) + shape} (one row per env), got {arr.shape}")
    if arr.dtype.kind not in "fiu":
        raise ValueError(f"actions must hold real numbers (a float or integer dtype), got dtype {arr.dtype}")
    arr = arr.astype(np.float64)
    if not np.isfinite(arr).all():
        for i in range(n):
            try:
                check_action(arr[i], shape)
            except ValueError as exc:
                raise ValueError(f"env {i}: {exc}") from None
    return arr


def clip_action(a):
    """Checked actions (finite: ``check_action``/``check_actions``), one world's or a batch's, clipped to [-1, 1]
    (= ``np.clip``), as a new array."""
    return np.minimum(np.maximum(a, -1.0), 1.0)


class ActionsMixin:
    """The action side of ``VSWristEnv``: command maps built at construction, action -> motor references."""

    def _lam_max(self) -> float:
        """Smallest reachable upper bound of lam over a grid of the range of motion (N m)."""
        rom = self.nominal_params.range_of_motion
        his = [self.ctrl.lambda_range(np.array([a, b]))[1]
               for a in np.linspace(rom.rud_min, rom.rud_max, 5) for b in np.linspace(rom.fe_min, rom.fe_max, 5)]
        self._lam_hi_max = float(max(his))
        return float(min(his))

    def _motor_range(self) -> tuple[np.ndarray, np.ndarray]:
        """Motor reference range for mode ``motor``: leg angles over the range of motion +- the deflection limit."""
        from ..kinematics import WristKinematics
        rom = self.nominal_params.range_of_motion
        kin = WristKinematics(self.nominal_params)
        q1 = np.array([kin.joint_angles(np.array([a, b]))[0::4]
                       for a in np.linspace(rom.rud_min, rom.rud_max, 7)
                       for b in np.linspace(rom.fe_min, rom.fe_max, 7)])
        dl = self.nominal_params.spring.deflection_limit
        lo = np.append(q1.min(axis=0) - dl, rom.ps_min)
        hi = np.append(q1.max(axis=0) + dl, rom.ps_max)
        return lo, hi

    def reference_to_action(self, posture_ref, stiffness: float) -> np.ndarray:
        """The ``posture_stiffness`` action (4,) that commands ``posture_ref`` (RUD, FE, PS; rad) with
        stiffness command ``stiffness`` in [-1, 1]: the inverse of that mode's mapping."""
        s = float(stiffness)
        if not (math.isfinite(s) and -1.0 <= s <= 1.0):
            raise ValueError(f"stiffness command must be in [-1, 1], got {stiffness!r}")
        ref = np.asarray(posture_ref, dtype=float)
        if ref.shape != (3,) or not np.isfinite(ref).all():
            raise ValueError(f"posture_ref must be 3 finite angles (RUD, FE, PS) in rad, got {posture_ref!r}")
        return np.append(self.posture_map.to_command(ref), s).astype(np.float32)

    def lam_to_stiffness_command(self, lam: float) -> float:
        """The stiffness command in [-1, 1] that maps to internal torque ``lam`` (N m), clipped to [0, lam_max]."""
        return self.stiffness_map.to_command(lam)

    def _posture_command(self, a: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Modes ``posture_stiffness`` and ``residual``: the posture reference (..., 3) (rad) and internal torque
        lam (...) (N m) that clipped actions ``a`` (..., 4) command, ``target`` (..., 3) being the task's reference
        now (``residual`` offsets it): one world's action or a batch's rows (``batch_step``)."""
        if self.cfg["action_mode"] == "posture_stiffness":
            return self.posture_map.to_posture(a[..., :3]), self.stiffness_map.to_lam(a[..., 3])
        r = self.cfg["residual"]
        ref = self.posture_map.clip(target + r["posture_scale"] * a[..., :3])
        return ref, self.stiffness_map.to_lam(r["stiffness_nominal"] + r["stiffness_scale"] * a[..., 3])

    def _motor_refs(self, a: np.ndarray) -> np.ndarray:
        mode = self.cfg["action_mode"]
        if mode == "motor":
            return self._motor_lo + 0.5 * (a + 1.0) * (self._motor_hi - self._motor_lo)
        if mode != "posture_compliance":
            ref, lam = self._posture_command(a, self._target)
            return self.ctrl.step(ref, lam=lam)
        # posture_compliance: diagonal compliances log-mapped, off-diagonal as a correlation in (-0.9, 0.9)
        c = self.cfg["compliance"]
        ref = self.posture_map.to_posture(a[:3])
        lc = np.log(c["min"]) + 0.5 * (a[3:5] + 1.0) * (np.log(c["max"]) - np.log(c["min"]))
        d = np.exp(lc)
        off = 0.9 * a[5] * math.sqrt(d[0] * d[1])
        C = np.array([[d[0], off], [off, d[1]]])
        return self.ctrl.step(ref, compliance_ref=C)
