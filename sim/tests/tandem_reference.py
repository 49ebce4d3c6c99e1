#!/usr/bin/env python3
"""Independent reference for sim::tandem (numpy): roll gap, partials, linearised
mill and the rightmost characteristic root with the transport delays.

Written apart from the Rust code: the matrices are assembled term by term (not from a
derivative function applied to unit vectors), the roll gap iterates Hitchcock in its
own loop, and the roots come from numpy's eigendecomposition of A (partial fractions
of the loop matrix) with Newton from a grid along the axis. The Rust test
`sim/tests/tandem.rs` checks its numbers against what this prints:

    pip install numpy
    python3 sim/tests/tandem_reference.py [sim/schedules/lu2019-5stand.toml]
"""
import json
import sys
import tomllib
from pathlib import Path

import numpy as np

PATH = Path(sys.argv[1] if len(sys.argv) > 1 else Path(__file__).parent.parent / "schedules/lu2019-5stand.toml")
S = tomllib.loads(PATH.read_text())
STANDS = S["stand"]
N = len(STANDS)
R0 = S["rolls"]["work_roll_radius"]
W = S["strip"]["width"]
E_ROLL, NU = S["rolls"]["youngs_modulus"], S["rolls"]["poisson_ratio"]
E_STRIP, L = S["strip"]["youngs_modulus"], S["interstand_distance"]
ST = S["stack"]


def roll_gap(H, h, sb, sf, k, mu):
    dh, r = H - h, (H - h) / H
    keff = k - (2 * sb + sf) / 3
    Rp = R0
    for _ in range(1000):
        q = 1.08 + 1.79 * r * mu * np.sqrt(1 - r) * np.sqrt(Rp / h) - 1.02 * r
        F = W * keff * np.sqrt(Rp * dh) * q
        Rn = R0 * (1 + 16 * (1 - NU**2) * F / (np.pi * E_ROLL * W * dh))
        if abs(Rn - Rp) < 1e-15 * R0:
            Rp = Rn
            break
        Rp = Rn
    q = 1.08 + 1.79 * r * mu * np.sqrt(1 - r) * np.sqrt(Rp / h) - 1.02 * r
    F = W * keff * np.sqrt(Rp * dh) * q
    a = np.sqrt(Rp / h)
    Hn = a * np.arctan(a * np.sqrt(dh / Rp)) + np.log((h / H) * (1 - sb / k) / (1 - sf / k)) / (2 * mu)
    phin = np.tan(Hn / (2 * a)) / a
    return dict(F=F, f=Rp * phin**2 / h, Rp=Rp, l=np.sqrt(Rp * dh), xn=Rp * phin)


def stand_pass(i):
    s = STANDS[i]
    return [s["entry_mm"] * 1e-3, s["exit_mm"] * 1e-3, s["back_tension_mpa"] * 1e6,
            s["front_tension_mpa"] * 1e6, s["flow_stress_mpa"] * 1e6, s["friction"]]


def partials(i):
    x = stand_pass(i)
    base = roll_gap(*x)
    steps = [1e-4 * (x[0] - x[1])] * 2 + [1e-4 * x[4]] * 2
    dF, df = [], []
    for j in range(4):
        up, down = list(x), list(x)
        up[j] += steps[j]
        down[j] -= steps[j]
        p, m = roll_gap(*up), roll_gap(*down)
        dF.append((p["F"] - m["F"]) / (2 * steps[j]))
        df.append((p["f"] - m["f"]) / (2 * steps[j]))
    return base, np.array(dF), np.array(df)


P = [partials(i) for i in range(N)]


def build(s):
    """A, the delayed columns B_k (rank one on y_w of stand k) and the delays."""
    n = 5 * N - 1
    A = np.zeros((n, n))
    B = np.zeros((n, N - 1))
    tau = np.zeros(N - 1)
    g = E_STRIP / L
    mw, mb = ST["work_roll_mass"], ST["backup_roll_mass"]
    kwb, cwb = ST["work_backup_stiffness"], ST["work_backup_damping"]
    kbh, cbh = ST["backup_housing_stiffness"], ST["backup_housing_damping"]
    sig = lambda j: 4 * N + j
    for i in range(N):
        b, dF, df = P[i]
        o = 4 * i
        H, h = STANDS[i]["entry_mm"] * 1e-3, STANDS[i]["exit_mm"] * 1e-3
        vR = STANDS[i]["roll_speed"] * s
        vout = vR * (1 + b["f"])
        A[o, o + 2] = A[o + 1, o + 3] = 1
        A[o + 2, o] += (2 * dF[1] - kwb) / mw
        A[o + 2, o + 1] += kwb / mw
        A[o + 2, o + 2] -= cwb / mw
        A[o + 2, o + 3] += cwb / mw
        A[o + 3, o] += kwb / mb
        A[o + 3, o + 1] -= (kwb + kbh) / mb
        A[o + 3, o + 2] += cwb / mb
        A[o + 3, o + 3] -= (cwb + cbh) / mb
        if i >= 1:
            A[o + 2, sig(i - 1)] += dF[2] / mw
            B[o + 2, i - 1] += dF[0] / mw  # unit dH of this stand
        if i + 1 < N:
            A[o + 2, sig(i)] += dF[3] / mw
        if i + 1 < N:  # v_out of stand i into tension i (minus)
            r = sig(i)
            A[r, o] -= g * vR * df[1] * 2
            A[r, o + 2] += g * 2 * b["xn"] / h
            A[r, sig(i)] -= g * vR * df[3]
            if i >= 1:
                A[r, sig(i - 1)] -= g * vR * df[2]
                B[r, i - 1] -= g * vR * df[0]
            tau[i] = L / vout
        if i >= 1:  # v_in of stand i into tension i - 1 (plus)
            r = sig(i - 1)
            A[r, o] += g * (vR * h * df[1] * 2 + vout * 2) / H
            A[r, o + 2] += g * 2 * (b["l"] - b["xn"]) / H
            A[r, sig(i - 1)] += g * vR * h * df[2] / H
            if i + 1 < N:
                A[r, sig(i)] += g * vR * h * df[3] / H
            B[r, i - 1] += g * (vR * h * df[0] / H - vout * h / H / H)
    return A, B, tau


def rightmost(s, fmax=400.0):
    A, B, tau = build(s)
    mu, V = np.linalg.eig(A)
    Wv = np.linalg.inv(V)
    C = np.zeros((N - 1, A.shape[0]))
    for k in range(N - 1):
        C[k, 4 * k] = 2.0
    R = np.einsum("kj,jl->jkl", C @ V, Wv @ B)

    def dlog(lam):
        d = 1 / (lam - mu)
        G = np.einsum("j,jkl->kl", d, R)
        Gp = -np.einsum("j,jkl->kl", d * d, R)
        z = np.exp(-lam * tau)
        K = np.eye(N - 1) - z[:, None] * G
        Kp = (tau * z)[:, None] * G - z[:, None] * Gp
        return d.sum() + np.trace(np.linalg.solve(K, Kp))

    best = None
    for f in np.arange(1.0, fmax, 1 / (2 * tau.max())):
        lam = 2j * np.pi * f
        for _ in range(40):
            step = 1 / dlog(lam)
            if abs(step) > 2 * np.pi / tau.max():
                step *= 2 * np.pi / tau.max() / abs(step)
            lam -= step
            if abs(step) < 1e-10 * abs(lam):
                if best is None or lam.real > best.real:
                    best = lam
                break
    return best


if __name__ == "__main__":
    out = {"stands": []}
    for b, dF, df in P:
        out["stands"].append({"force_n": b["F"], "forward_slip": b["f"], "flattened_radius_m": b["Rp"],
                              "neutral_point_m": b["xn"], "force_partials": list(dF), "slip_partials": list(df)})
    for s in (0.9, 1.2):
        r = rightmost(s)
        out[f"rightmost_{s}"] = {"real_per_s": r.real, "frequency_hz": abs(r.imag) / (2 * np.pi)}
    print(json.dumps(out, indent=1))
