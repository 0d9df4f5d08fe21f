"""Action mappings and the named observation table.

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
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np


@dataclass(frozen=True)
class ObsTerm:
    """One named observation term: its size, unit, meaning, a function returning a fresh array, and its bounds
    (the declared space; values are clipped to them, which the bounds are chosen never to need in operation)."""

    name: str
    size: int
    unit: str
    doc: str
    fn: Callable[[], np.ndarray]
    low: float | np.ndarray = -np.inf
    high: float | np.ndarray = np.inf


class StiffnessMap:
    """Stiffness command s in [-1, 1] <-> internal torque lam in [0, lam_max] (N m)."""

    def __init__(self, lam_max: float, K: float, kind: str = "asinh"):
        if not lam_max > 0.0:
            raise ValueError(f"lam_max must be positive, got {lam_max}")
        self.lam_max, self.two_k, self.kind = float(lam_max), 2.0 * float(K), kind
        self._a = float(np.arcsinh(self.lam_max / self.two_k))

    def to_lam(self, s: float) -> float:
        f = 0.5 * (min(max(float(s), -1.0), 1.0) + 1.0)
        if self.kind == "linear":
            return f * self.lam_max
        return self.two_k * float(np.sinh(f * self._a))

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


def wrap_angle(x):
    """Angle difference wrapped to [-pi, pi)."""
    return (np.asarray(x) + np.pi) % (2.0 * np.pi) - np.pi
