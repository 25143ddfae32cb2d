"""Reeds-Shepp curves: shortest paths for a car that drives forwards and backwards.

Own implementation of the closed-form word families of Reeds & Shepp (1990),
"Optimal paths for a car that goes both forwards and backwards" (formulas
8.1-8.11 with the time-flip, reflection and backwards symmetries). Everything
is Numba-compiled scalar code so the Hybrid A* search can call it in its inner
loop.

A path is up to five segments; each has a type (`LEFT`, `STRAIGHT`, `RIGHT`)
and a signed length in units of the turning radius (negative = reverse; for
turns the length is the turned angle).
"""

from __future__ import annotations

import math

import numba
import numpy as np

LEFT = 1
STRAIGHT = 0
RIGHT = -1
_NONE = 9  # unused segment slot

_PI = math.pi
_TWO_PI = 2.0 * math.pi
_EPS = 1e-9


@numba.njit(cache=True, inline="always")
def _mod2pi(x: float) -> float:
    """Wraps into [-pi, pi]."""
    v = x - _TWO_PI * math.trunc(x / _TWO_PI)
    if v < -_PI:
        v += _TWO_PI
    elif v > _PI:
        v -= _TWO_PI
    return v


@numba.njit(cache=True, inline="always")
def _polar(x: float, y: float):
    return math.sqrt(x * x + y * y), math.atan2(y, x)


@numba.njit(cache=True, inline="always")
def _tau_omega(u, v, xi, eta, phi):
    delta = _mod2pi(u - v)
    a = math.sin(u) - math.sin(delta)
    b = math.cos(u) - math.cos(delta) - 1.0
    t1 = math.atan2(eta * a - xi * b, xi * a + eta * b)
    t2 = 2.0 * (math.cos(delta) - math.cos(v) - math.cos(u)) + 3.0
    tau = _mod2pi(t1 + _PI) if t2 < 0 else _mod2pi(t1)
    omega = _mod2pi(tau - u + v - phi)
    return tau, omega


# --- the base word families (all on L+ first); each returns ok, lengths ---


@numba.njit(cache=True)
def _lp_sp_lp(x, y, phi):  # 8.1: L+ S+ L+
    u, t = _polar(x - math.sin(phi), y - 1.0 + math.cos(phi))
    if t >= -_EPS:
        v = _mod2pi(phi - t)
        if v >= -_EPS:
            return True, t, u, v
    return False, 0.0, 0.0, 0.0


@numba.njit(cache=True)
def _lp_sp_rp(x, y, phi):  # 8.2: L+ S+ R+
    u1, t1 = _polar(x + math.sin(phi), y - 1.0 - math.cos(phi))
    u1 = u1 * u1
    if u1 >= 4.0:
        u = math.sqrt(u1 - 4.0)
        theta = math.atan2(2.0, u)
        t = _mod2pi(t1 + theta)
        v = _mod2pi(t - phi)
        if t >= -_EPS and v >= -_EPS:
            return True, t, u, v
    return False, 0.0, 0.0, 0.0


@numba.njit(cache=True)
def _lp_rm_l(x, y, phi):  # 8.3/8.4: L+ R- L
    xi = x - math.sin(phi)
    eta = y - 1.0 + math.cos(phi)
    u1, theta = _polar(xi, eta)
    if u1 <= 4.0:
        u = -2.0 * math.asin(0.25 * u1)
        t = _mod2pi(theta + 0.5 * u + _PI)
        v = _mod2pi(phi - t + u)
        if t >= -_EPS and u <= _EPS:
            return True, t, u, v
    return False, 0.0, 0.0, 0.0


@numba.njit(cache=True)
def _lp_rup_lum_rm(x, y, phi):  # 8.7: L+ R+(u) L-(u) R-
    xi = x + math.sin(phi)
    eta = y - 1.0 - math.cos(phi)
    rho = 0.25 * (2.0 + math.sqrt(xi * xi + eta * eta))
    if rho <= 1.0:
        u = math.acos(rho)
        t, v = _tau_omega(u, -u, xi, eta, phi)
        if t >= -_EPS and v <= _EPS:
            return True, t, u, v
    return False, 0.0, 0.0, 0.0


@numba.njit(cache=True)
def _lp_rum_lum_rp(x, y, phi):  # 8.8: L+ R-(u) L-(u) R+
    xi = x + math.sin(phi)
    eta = y - 1.0 - math.cos(phi)
    rho = (20.0 - xi * xi - eta * eta) / 16.0
    if 0.0 <= rho <= 1.0:
        u = -math.acos(rho)
        if u >= -0.5 * _PI:
            t, v = _tau_omega(u, u, xi, eta, phi)
            if t >= -_EPS and v >= -_EPS:
                return True, t, u, v
    return False, 0.0, 0.0, 0.0


@numba.njit(cache=True)
def _lp_rm_sm_lm(x, y, phi):  # 8.9: L+ R-(pi/2) S- L-
    xi = x - math.sin(phi)
    eta = y - 1.0 + math.cos(phi)
    rho, theta = _polar(xi, eta)
    if rho >= 2.0:
        r = math.sqrt(rho * rho - 4.0)
        u = 2.0 - r
        t = _mod2pi(theta + math.atan2(r, -2.0))
        v = _mod2pi(phi - 0.5 * _PI - t)
        if t >= -_EPS and u <= _EPS and v <= _EPS:
            return True, t, u, v
    return False, 0.0, 0.0, 0.0


@numba.njit(cache=True)
def _lp_rm_sm_rm(x, y, phi):  # 8.10: L+ R-(pi/2) S- R-
    xi = x + math.sin(phi)
    eta = y - 1.0 - math.cos(phi)
    rho, theta = _polar(-eta, xi)
    if rho >= 2.0:
        t = theta
        u = 2.0 - rho
        v = _mod2pi(t + 0.5 * _PI - phi)
        if t >= -_EPS and u <= _EPS and v <= _EPS:
            return True, t, u, v
    return False, 0.0, 0.0, 0.0


@numba.njit(cache=True)
def _lp_rm_s_lm_rp(x, y, phi):  # 8.11: L+ R-(pi/2) S- L-(pi/2) R+
    xi = x + math.sin(phi)
    eta = y - 1.0 - math.cos(phi)
    rho, theta = _polar(xi, eta)
    if rho >= 2.0:
        u = 4.0 - math.sqrt(rho * rho - 4.0)
        if u <= _EPS:
            t = _mod2pi(math.atan2((4.0 - u) * xi - 2.0 * eta, -2.0 * xi + (u - 4.0) * eta))
            v = _mod2pi(t - phi)
            if t >= -_EPS and v >= -_EPS:
                return True, t, u, v
    return False, 0.0, 0.0, 0.0


# Word ids: which base family, and the segment pattern it produces.
_W_LSL, _W_LSR, _W_LRL, _W_LRL_B, _W_LRLR_P, _W_LRLR_M = 0, 1, 2, 3, 4, 5
_W_LRSL, _W_LRSR, _W_LRSL_B, _W_LRSR_B, _W_LRSLR = 6, 7, 8, 9, 10
_NUM_WORDS = 11


@numba.njit(cache=True)
def _word(w, x, y, phi, types, lengths):
    """Evaluates base word w at (x, y, phi); fills types/lengths (L+ first).

    Returns False when the word has no solution.
    """
    for i in range(5):
        types[i] = _NONE
        lengths[i] = 0.0
    hp = 0.5 * _PI
    if w == _W_LSL:
        ok, t, u, v = _lp_sp_lp(x, y, phi)
        if ok:
            types[0], types[1], types[2] = LEFT, STRAIGHT, LEFT
            lengths[0], lengths[1], lengths[2] = t, u, v
        return ok
    if w == _W_LSR:
        ok, t, u, v = _lp_sp_rp(x, y, phi)
        if ok:
            types[0], types[1], types[2] = LEFT, STRAIGHT, RIGHT
            lengths[0], lengths[1], lengths[2] = t, u, v
        return ok
    if w == _W_LRL:
        ok, t, u, v = _lp_rm_l(x, y, phi)
        if ok:
            types[0], types[1], types[2] = LEFT, RIGHT, LEFT
            lengths[0], lengths[1], lengths[2] = t, u, v
        return ok
    if w == _W_LRL_B:  # backwards: solve for the reversed path, reverse order
        xb = x * math.cos(phi) + y * math.sin(phi)
        yb = x * math.sin(phi) - y * math.cos(phi)
        ok, t, u, v = _lp_rm_l(xb, yb, phi)
        if ok:
            types[0], types[1], types[2] = LEFT, RIGHT, LEFT
            lengths[0], lengths[1], lengths[2] = v, u, t
        return ok
    if w == _W_LRLR_P:
        ok, t, u, v = _lp_rup_lum_rm(x, y, phi)
        if ok:
            types[0], types[1], types[2], types[3] = LEFT, RIGHT, LEFT, RIGHT
            lengths[0], lengths[1], lengths[2], lengths[3] = t, u, -u, v
        return ok
    if w == _W_LRLR_M:
        ok, t, u, v = _lp_rum_lum_rp(x, y, phi)
        if ok:
            types[0], types[1], types[2], types[3] = LEFT, RIGHT, LEFT, RIGHT
            lengths[0], lengths[1], lengths[2], lengths[3] = t, u, u, v
        return ok
    if w == _W_LRSL:
        ok, t, u, v = _lp_rm_sm_lm(x, y, phi)
        if ok:
            types[0], types[1], types[2], types[3] = LEFT, RIGHT, STRAIGHT, LEFT
            lengths[0], lengths[1], lengths[2], lengths[3] = t, -hp, u, v
        return ok
    if w == _W_LRSR:
        ok, t, u, v = _lp_rm_sm_rm(x, y, phi)
        if ok:
            types[0], types[1], types[2], types[3] = LEFT, RIGHT, STRAIGHT, RIGHT
            lengths[0], lengths[1], lengths[2], lengths[3] = t, -hp, u, v
        return ok
    if w == _W_LRSL_B or w == _W_LRSR_B:
        xb = x * math.cos(phi) + y * math.sin(phi)
        yb = x * math.sin(phi) - y * math.cos(phi)
        if w == _W_LRSL_B:
            ok, t, u, v = _lp_rm_sm_lm(xb, yb, phi)
            last = LEFT
        else:
            ok, t, u, v = _lp_rm_sm_rm(xb, yb, phi)
            last = RIGHT
        if ok:
            types[0], types[1], types[2], types[3] = last, STRAIGHT, RIGHT, LEFT
            lengths[0], lengths[1], lengths[2], lengths[3] = v, u, -hp, t
        return ok
    # _W_LRSLR
    ok, t, u, v = _lp_rm_s_lm_rp(x, y, phi)
    if ok:
        types[0], types[1], types[2], types[3], types[4] = LEFT, RIGHT, STRAIGHT, LEFT, RIGHT
        lengths[0], lengths[1], lengths[2], lengths[3], lengths[4] = t, -hp, u, -hp, v
    return ok


@numba.njit(cache=True)
def shortest_path_normalized(x: float, y: float, phi: float, reverse_weight: float = 1.0):
    """The shortest Reeds-Shepp path from the origin to (x, y, phi), unit radius.

    With `reverse_weight` > 1 the path of least weighted length (backward
    segments count `reverse_weight` times) is chosen instead: a robot whose
    camera looks forward should not back into space it has not seen.

    Returns:
        (types (5,) int64, lengths (5,) float64, total length). Unused slots
        have type 9 and length 0.
    """
    best_types = np.full(5, _NONE, dtype=np.int64)
    best_lengths = np.zeros(5)
    best = np.inf
    best_cost = np.inf
    types = np.empty(5, dtype=np.int64)
    lengths = np.empty(5)
    for w in range(_NUM_WORDS):
        for sym in range(4):
            # sym: 0 identity, 1 time-flip, 2 reflect, 3 both.
            sx = -x if (sym == 1 or sym == 3) else x
            sy = -y if (sym == 2 or sym == 3) else y
            sphi = -phi if (sym == 1 or sym == 2) else phi
            if not _word(w, sx, sy, sphi, types, lengths):
                continue
            total = 0.0
            cost = 0.0
            for i in range(5):
                total += abs(lengths[i])
                backward = (lengths[i] < 0.0) != (sym == 1 or sym == 3)
                cost += abs(lengths[i]) * (reverse_weight if backward else 1.0)
            if cost < best_cost - 1e-12:
                best_cost = cost
                best = total
                for i in range(5):
                    tp = types[i]
                    ln = lengths[i]
                    if sym == 1 or sym == 3:
                        ln = -ln
                    if (sym == 2 or sym == 3) and tp != _NONE:
                        tp = -tp
                    best_types[i] = tp
                    best_lengths[i] = ln
    return best_types, best_lengths, best


@numba.njit(cache=True)
def shortest_path(start: np.ndarray, goal: np.ndarray, radius: float, reverse_weight: float = 1.0):
    """Shortest path between poses (x, y, theta) for turning radius `radius`
    (least weighted length with `reverse_weight`, see `shortest_path_normalized`).

    Returns:
        (types (5,), lengths (5,) in radius units, total length in metres).
    """
    dx = goal[0] - start[0]
    dy = goal[1] - start[1]
    c = math.cos(start[2])
    s = math.sin(start[2])
    x = (c * dx + s * dy) / radius
    y = (-s * dx + c * dy) / radius
    phi = goal[2] - start[2]
    types, lengths, total = shortest_path_normalized(x, y, phi, reverse_weight)
    return types, lengths, total * radius


@numba.njit(cache=True)
def path_length(start: np.ndarray, goal: np.ndarray, radius: float) -> float:
    """Length [m] of the shortest Reeds-Shepp path."""
    _, _, total = shortest_path(start, goal, radius)
    return total


@numba.njit(cache=True)
def sample_path(start: np.ndarray, types: np.ndarray, lengths: np.ndarray,
                radius: float, step: float) -> np.ndarray:
    """Poses (M, 3) along a path at arc-length spacing <= step [m].

    Both ends and every segment junction (cusps included) are samples; theta
    is continuous (not wrapped) along the path.
    """
    counts = np.zeros(5, dtype=np.int64)
    n = 1
    for i in range(5):
        if types[i] != _NONE and abs(lengths[i]) > 0.0:
            counts[i] = max(int(math.ceil(abs(lengths[i]) * radius / step)), 1)
            n += counts[i]
    out = np.empty((n, 3))
    x0, y0, th0 = start[0], start[1], start[2]
    out[0, 0], out[0, 1], out[0, 2] = x0, y0, th0
    k = 1
    for i in range(5):
        if counts[i] == 0:
            continue
        for j in range(1, counts[i] + 1):
            out[k, 0], out[k, 1], out[k, 2] = _advance(x0, y0, th0, types[i], lengths[i] * j / counts[i], radius)
            k += 1
        x0, y0, th0 = out[k - 1, 0], out[k - 1, 1], out[k - 1, 2]
    return out


@numba.njit(cache=True, inline="always")
def _advance(x, y, th, tp, ln, radius):
    """Pose after driving a segment of type tp and signed length ln (radius units)."""
    if tp == STRAIGHT:
        return x + ln * radius * math.cos(th), y + ln * radius * math.sin(th), th
    if tp == LEFT:
        nth = th + ln
        return (x + radius * (math.sin(nth) - math.sin(th)),
                y + radius * (-math.cos(nth) + math.cos(th)), nth)
    nth = th - ln
    return (x + radius * (-math.sin(nth) + math.sin(th)),
            y + radius * (math.cos(nth) - math.cos(th)), nth)


def end_pose(start: np.ndarray, types: np.ndarray, lengths: np.ndarray, radius: float) -> np.ndarray:
    """The pose reached by driving the path from start (theta unwrapped)."""
    x, y, th = float(start[0]), float(start[1]), float(start[2])
    for tp, ln in zip(types, lengths):
        if tp == _NONE:
            continue
        x, y, th = _advance(x, y, th, int(tp), float(ln), radius)
    return np.array([x, y, th])
