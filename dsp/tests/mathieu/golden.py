#!/usr/bin/env python3
"""Golden values for dsp/tests/mathieu.rs, computed independently of the Rust code.

Writes, beside this script:
- characteristic.csv: kind (a|b), order n, q, value. mpmath at 40 digits: eigenvalues of
  the DLMF 28.4 recurrence matrices truncated at 80 terms per class (twice the Rust
  size), each cross-checked against scipy.special.mathieu_a/mathieu_b (a different
  algorithm) and against Abramowitz and Stegun Table 20.1.
- floquet.csv: a, q, c, exponent. The damped equation x'' + 2c x' + (a - 2q cos 2t) x = 0
  itself (no substitution, no half-period symmetry) integrated over one full period pi
  by scipy's DOP853 at rtol 1e-13; exponent = ln(largest |multiplier|) / pi, per unit t.
  A subset is re-integrated by mpmath.odefun (Taylor series, 30 digits) as a check.
- damped_edges.csv: order n, q, c, lower, upper: edges (in a) of the damped instability
  tongue n, roots of the DOP853 exponent in a (scipy brentq), bracketed by the
  characteristic values.

Run: pip install numpy scipy mpmath; python3 dsp/tests/mathieu/golden.py [characteristic]
[floquet] [damped_edges] (all three by default; about 5 minutes)
"""
import csv
import math
import os

import mpmath as mp
import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import brentq, minimize_scalar
from scipy.special import mathieu_a, mathieu_b

HERE = os.path.dirname(os.path.abspath(__file__))
mp.mp.dps = 40
TERMS = 80

Q_VALUES = [-100, -50, -10, -2, -0.5, -0.03, 1e-3, 0.01, 0.03, 0.1, 0.5, 1, 2, 5, 10, 25, 50, 75, 100]


def class_eigenvalues(kind, parity, q, count):
    """Smallest `count` eigenvalues of one recurrence class (mpmath, symmetric form)."""
    q = mp.mpf(q)
    if kind == "a" and parity == 0:  # a_{2m}: A0, A2, ...; row 0 scaled by sqrt(2)
        diag = [mp.mpf((2 * m) ** 2) for m in range(TERMS)]
        off = [mp.sqrt(2) * q] + [q] * (TERMS - 2)
    elif kind == "a":  # a_{2m+1}: A1, A3, ...
        diag = [mp.mpf((2 * m + 1) ** 2) for m in range(TERMS)]
        diag[0] += q
        off = [q] * (TERMS - 1)
    elif parity == 1:  # b_{2m+1}: B1, B3, ...
        diag = [mp.mpf((2 * m + 1) ** 2) for m in range(TERMS)]
        diag[0] -= q
        off = [q] * (TERMS - 1)
    else:  # b_{2m+2}: B2, B4, ...
        diag = [mp.mpf((2 * m + 2) ** 2) for m in range(TERMS)]
        off = [q] * (TERMS - 1)
    matrix = mp.zeros(TERMS, TERMS)
    for i in range(TERMS):
        matrix[i, i] = diag[i]
    for i in range(TERMS - 1):
        matrix[i, i + 1] = off[i]
        matrix[i + 1, i] = off[i]
    values = mp.eigsy(matrix, eigvals_only=True)
    return sorted(values)[:count]


def characteristic(kind, n, q):
    parity = n % 2
    index = n // 2 if kind == "a" else (n - 1) // 2
    return class_eigenvalues(kind, parity, q, index + 1)[index]


def write_characteristic():
    rows = []
    worst_scipy = 0.0
    for q in Q_VALUES:
        cache = {}
        for kind, parity in (("a", 0), ("a", 1), ("b", 1), ("b", 0)):
            cache[(kind, parity)] = class_eigenvalues(kind, parity, q, 6)
        for kind, orders in (("a", range(0, 11)), ("b", range(1, 11))):
            for n in orders:
                index = n // 2 if kind == "a" else (n - 1) // 2
                value = cache[(kind, n % 2)][index]
                scipy_value = (mathieu_a if kind == "a" else mathieu_b)(n, q)
                scale = max(1.0, abs(float(value)))
                deviation = abs(float(value) - scipy_value) / scale
                worst_scipy = max(worst_scipy, deviation)
                assert deviation < 1e-6, (kind, n, q, value, scipy_value)
                rows.append((kind, n, repr(float(q)), mp.nstr(value, 25)))
    # Abramowitz and Stegun Table 20.1 (8 decimals).
    table = {
        1: {"a0": -0.45513860, "b1": -0.11024882, "a1": 1.85910807, "b2": 3.91702477, "a2": 4.37130098},
        5: {"a0": -5.80004602, "b1": -5.79008060, "a1": 1.85818754, "b2": 2.09946045, "a2": 7.44910974},
    }
    for q, values in table.items():
        for name, expected in values.items():
            got = characteristic(name[0], int(name[1:]), q)
            assert abs(float(got) - expected) <= 6e-9, (name, q, got)
    with open(os.path.join(HERE, "characteristic.csv"), "w", newline="") as handle:
        handle.write("# kind,n,q,value: Mathieu characteristic values a_n(q), b_n(q); see golden.py\n")
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerows(rows)
    print(f"characteristic.csv: {len(rows)} values; scipy agrees to {worst_scipy:.1e} relative")


def exponent_scipy(a, q, c):
    """ln(largest |multiplier|) / pi of the damped equation, by DOP853 over [0, pi]."""

    def rhs(t, y):
        w = a - 2.0 * q * math.cos(2.0 * t)
        return [y[1], -2.0 * c * y[1] - w * y[0], y[3], -2.0 * c * y[3] - w * y[2]]

    sol = solve_ivp(rhs, (0.0, math.pi), [1.0, 0.0, 0.0, 1.0], method="DOP853",
                    rtol=1e-13, atol=1e-15)
    y = sol.y[:, -1]
    monodromy = np.array([[y[0], y[2]], [y[1], y[3]]])
    multipliers = np.linalg.eigvals(monodromy)
    return math.log(max(abs(multipliers))) / math.pi


def exponent_mpmath(a, q, c):
    mp.mp.dps = 30
    a, q, c = mp.mpf(a), mp.mpf(q), mp.mpf(c)

    def rhs(t, y):
        w = a - 2 * q * mp.cos(2 * t)
        return [y[1], -2 * c * y[1] - w * y[0]]

    first = mp.odefun(rhs, 0, [mp.mpf(1), mp.mpf(0)])(mp.pi)
    second = mp.odefun(rhs, 0, [mp.mpf(0), mp.mpf(1)])(mp.pi)
    trace = first[0] + second[1]
    det = first[0] * second[1] - first[1] * second[0]
    disc = mp.sqrt(mp.mpc(trace * trace - 4 * det))
    largest = max(abs((trace + disc) / 2), abs((trace - disc) / 2))
    mp.mp.dps = 40
    return float(mp.log(largest) / mp.pi)


def write_floquet():
    rows = []
    a_values = [-20.0, -3.0, -0.5, 0.0, 0.3, 0.9, 1.0, 1.2, 1.9, 2.5, 3.95, 4.3, 6.0, 9.2, 16.1, 24.0, 37.0, 60.0]
    q_values = [-40.0, -3.0, -0.7, 0.05, 0.4, 1.0, 2.5, 6.0, 15.0, 40.0, 100.0]
    c_values = [0.0, 0.03, 0.4]
    for a in a_values:
        for q in q_values:
            for c in c_values:
                rows.append((a, q, c, exponent_scipy(a, q, c)))
    worst = 0.0
    for a, q, c in [(1.0, 0.4, 0.0), (1.2, 1.0, 0.03), (3.95, 2.5, 0.03), (-0.5, 0.05, 0.4), (9.2, 6.0, 0.0), (24.0, 15.0, 0.03)]:
        reference = exponent_mpmath(a, q, c)
        worst = max(worst, abs(reference - exponent_scipy(a, q, c)))
    assert worst < 1e-9, worst
    with open(os.path.join(HERE, "floquet.csv"), "w", newline="") as handle:
        handle.write("# a,q,c,exponent: growth exponent per unit t of x'' + 2c x' + (a - 2q cos 2t) x = 0; see golden.py\n")
        writer = csv.writer(handle, lineterminator="\n")
        for a, q, c, value in rows:
            writer.writerow((repr(a), repr(q), repr(c), repr(value)))
    print(f"floquet.csv: {len(rows)} points; mpmath odefun agrees with DOP853 to {worst:.1e}")


def write_damped_edges():
    rows = []
    for n, q, c in [(1, 0.3, 0.05), (1, 1.0, 0.1), (1, 4.0, 0.3), (2, 1.0, 0.02), (2, 3.0, 0.1),
                    (3, 4.0, 0.05), (4, 8.0, 0.1), (1, -2.0, 0.2), (3, -6.0, 0.1)]:
        # x = exp(-c t) y: y sees a - c^2, so the damped tongue lies inside the
        # undamped one shifted up by c^2.
        lo = float(min(characteristic("a", n, q), characteristic("b", n, q))) + c * c
        hi = float(max(characteristic("a", n, q), characteristic("b", n, q))) + c * c
        inner = minimize_scalar(lambda a: -exponent_scipy(a, q, c), bounds=(lo, hi), method="bounded",
                                options={"xatol": 1e-10})
        peak = inner.x
        assert exponent_scipy(peak, q, c) > 0, (n, q, c)
        lower = brentq(lambda a: exponent_scipy(a, q, c), lo, peak, xtol=1e-13)
        upper = brentq(lambda a: exponent_scipy(a, q, c), peak, hi, xtol=1e-13)
        rows.append((n, repr(q), repr(c), repr(lower), repr(upper)))
    with open(os.path.join(HERE, "damped_edges.csv"), "w", newline="") as handle:
        handle.write("# n,q,c,lower,upper: edges in a of damped tongue n (exponent = 0); see golden.py\n")
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerows(rows)
    print(f"damped_edges.csv: {len(rows)} tongues")


if __name__ == "__main__":
    import sys

    parts = sys.argv[1:] or ["characteristic", "floquet", "damped_edges"]
    for part in parts:
        globals()["write_" + part]()
