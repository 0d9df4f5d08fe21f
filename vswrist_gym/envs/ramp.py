"""Motor-speed-limited FE ramps: the swing references of Hammer and Throw, integrated at reset.

A ramp runs from one FE to another at the FE rate at which the fastest-turning PM motor runs at a fraction of its
speed limit (``fe_rates``); the rate varies with the posture, so the ramp is integrated (midpoint rule, 1 ms).
``ramp_reference`` and ``ramp_through`` integrate one world's ramp with floats; ``ramp_references`` and
``ramp_through_worlds`` the ramps of many worlds at once, with the same operations element by element (each world's
ramp is the one-world ramp to the bit when the rates compute alike, ``tests/test_hammer.py``). ``swing_ramps`` picks
between them: the array form costs two array calls of the kinematics per millisecond of ramp whatever the count of
worlds (about 0.15 ms), the one-world form about 12 us per world, so a batch's resets take the array form from
``RAMP_ARRAY_MIN_WORLDS`` worlds resetting together and the single env keeps the one-world form.
"""

from __future__ import annotations

import math

import numpy as np

# from this many worlds resetting together their ramps are integrated over arrays (see the module docstring)
RAMP_ARRAY_MIN_WORLDS = 8


def ramp_reference(fe0: float, fe1: float, rate_of, t_start: float, duration: float, dt: float = 1e-3):
    """Times (s) and FE (rad) of a ramp from ``fe0`` to ``fe1`` starting at ``t_start`` whose FE rate at each
    FE is ``rate_of(fe)`` (rad/s, > 0), held at ``fe1`` after; integrated with ``dt``. NumPy arrays, so that a
    batched core can build one per episode."""
    ts, fes = [0.0, t_start], [fe0, fe0]
    t, fe, sign = t_start, fe0, math.copysign(1.0, fe1 - fe0)
    while (fe1 - fe) * sign > 0.0 and t < duration:
        # midpoint rule: rate at half a step ahead
        r = rate_of(fe + 0.5 * dt * sign * rate_of(fe))
        fe = fe + sign * r * dt
        if (fe1 - fe) * sign < 0.0:
            fe = fe1
        t += dt
        ts.append(t)
        fes.append(fe)
    ts.append(max(duration, t) + dt)
    fes.append(fes[-1])
    return np.asarray(ts), np.asarray(fes)


def ramp_references(fe0: float, fe1: float, rates_of, n: int, t_start, duration, dt: float = 1e-3) -> list:
    """``ramp_reference`` of ``n`` ramps at once whose FE rate is ``rates_of(fe, rows)`` ((k,) FE of the ramps
    ``rows`` -> (k,) rad/s), each with its own start ``t_start`` and ``duration`` (s; numbers or (n,) arrays):
    the same operations element by element, each ramp stopping where it would alone, so each (times, FE) pair is
    ``ramp_reference``'s to the bit when ``rates_of`` computes as ``rate_of``."""
    sign = math.copysign(1.0, fe1 - fe0)
    fe = np.full(n, float(fe0))
    t = np.array(np.broadcast_to(np.asarray(t_start, dtype=float), (n,)))
    end = np.broadcast_to(np.asarray(duration, dtype=float), (n,))
    times, rows_fe = [np.zeros(n), t.copy()], [fe.copy(), fe.copy()]
    done_at = np.full(n, 1)  # index of each ramp's last point
    active = np.flatnonzero(((fe1 - fe) * sign > 0.0) & (t < end))
    while active.size:
        f = fe[active]
        r = rates_of(f + 0.5 * dt * sign * rates_of(f, active), active)
        f = f + sign * r * dt
        f = np.where((fe1 - f) * sign < 0.0, fe1, f)
        fe[active] = f
        ta = t[active] + dt
        t[active] = ta
        times.append(t.copy())
        rows_fe.append(fe.copy())
        done_at[active] = len(times) - 1
        active = active[((fe1 - f) * sign > 0.0) & (ta < end[active])]
    T, F = np.asarray(times), np.asarray(rows_fe)
    out = []
    for k in range(n):
        m = done_at[k]
        out.append((np.append(T[:m + 1, k], max(end[k], T[m, k]) + dt), np.append(F[:m + 1, k], F[m, k])))
    return out


def _join(first: tuple, second: tuple) -> tuple[np.ndarray, np.ndarray]:
    """The ramp through a turn from its two legs (``ramp_through``): the first's hold point (one dt past its end)
    and the second's start (0, the turn's FE) dropped, and the turn's point once when the hold is 0."""
    (t1, f1), (t2, f2) = first, second
    ts = np.concatenate([t1[:-1], t2[1:]])
    fes = np.concatenate([f1[:-1], f2[1:]])
    keep = np.concatenate([[True], np.diff(ts) > 0.0])
    return ts[keep], fes[keep]


def ramp_through(points, rates_of, t_start: float, hold_s: float, duration: float, dt: float = 1e-3):
    """Times (s) and FE (rad) of a reference through FE ``points[0] -> points[1] -> points[2]``: from ``t_start``
    to ``points[1]`` at the FE rate ``rates_of[0](fe)``, ``hold_s`` there, then to ``points[2]`` at
    ``rates_of[1](fe)`` (rad/s, > 0), held after; each leg integrated with the midpoint rule and step ``dt`` as
    ``ramp_reference``."""
    first = ramp_reference(points[0], points[1], rates_of[0], t_start, duration, dt)
    t_back = float(first[0][-2])  # the first leg's end (its last point is the hold one dt later)
    return _join(first, ramp_reference(points[1], points[2], rates_of[1], t_back + hold_s,
                                       max(duration, t_back + hold_s), dt))


def ramp_through_worlds(points, rates_of, n: int, t_start: float, hold_s: float, duration: float,
                        dt: float = 1e-3) -> list:
    """``ramp_through`` of ``n`` worlds at once (``rates_of``: two functions ``(fe, rows) -> rates`` as
    ``ramp_references`` takes), each world's ramp ``ramp_through``'s to the bit when the rates compute alike."""
    firsts = ramp_references(points[0], points[1], rates_of[0], n, t_start, duration, dt)
    t_back = np.array([t1[-2] for t1, _ in firsts])
    seconds = ramp_references(points[1], points[2], rates_of[1], n, t_back + hold_s,
                              np.maximum(duration, t_back + hold_s), dt)
    return [_join(a, b) for a, b in zip(firsts, seconds)]


def leg_rate(ctrl, rud: float, fe: float) -> float:
    """max over the legs of |d q1 / d FE| at (rud, fe): motor radians per radian of FE (rigid), from the
    controller's closed-form J_a (``AnalyticController._q1_ja``; tests/test_hammer.py checks it against central
    differences of the exact inverse kinematics): the closed form costs about a thirtieth of the two IK solutions
    a difference needs."""
    _, Ja = ctrl._q1_ja(rud, fe)
    return max(abs(Ja[0][1]), abs(Ja[1][1]), abs(Ja[2][1]))


def fe_rate(ctrl, rud: float, speed: float):
    """The FE rate (rad/s) at RUD ``rud`` as a function of FE, at which the fastest-turning PM motor turns at
    ``speed`` (rad/s): ``speed / leg_rate``."""
    return lambda fe: speed / leg_rate(ctrl, rud, fe)


def fe_rates(ctrl, rud: np.ndarray, speed: float):
    """``fe_rate`` of the worlds at RUDs ``rud`` (n,), over arrays: ``(fe, rows) -> rates`` of the worlds ``rows``
    at FE ``fe``, from the controller's kinematics over arrays (which compute as its scalar path)."""
    def rates_of(fe, rows):
        _, (_, J1), _, _ = ctrl.posture_kinematics_batch(rud[rows], fe, with_q1=False)
        return speed / np.maximum(np.maximum(np.abs(J1[0]), np.abs(J1[1])), np.abs(J1[2]))
    return rates_of


def swing_ramps(ctrl, rud, points, speeds, t_start: float, hold_s: float, duration: float) -> list:
    """The swing references (times, FE) of worlds at RUDs ``rud`` (a list) that share a controller's parameters:
    through ``points`` (three FEs, ``ramp_through``) at motor speeds ``speeds`` (rad/s, one per leg of the path),
    or, with two points, one ramp from ``t_start`` (``ramp_reference``; ``hold_s`` unused). Over arrays from
    ``RAMP_ARRAY_MIN_WORLDS`` worlds, else world by world (the module docstring)."""
    n = len(rud)
    if n < RAMP_ARRAY_MIN_WORLDS:
        out = []
        for r in rud:
            rates = [fe_rate(ctrl, r, s) for s in speeds]
            if len(points) == 2:
                out.append(ramp_reference(*points, rates[0], t_start, duration))
            else:
                out.append(ramp_through(points, rates, t_start, hold_s, duration))
        return out
    rud = np.asarray(rud, dtype=float)
    rates = [fe_rates(ctrl, rud, s) for s in speeds]
    if len(points) == 2:
        return ramp_references(*points, rates[0], n, t_start, duration)
    return ramp_through_worlds(points, rates, n, t_start, hold_s, duration)
