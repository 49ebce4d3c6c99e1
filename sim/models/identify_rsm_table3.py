#!/usr/bin/env python3
"""Identify the RSM block drive from the paper's Table 3 and write its model files.

The paper (Krot and Korennoy 2016, Table 3) gives the eight natural frequencies of the
reducing-sizing mill's geared drive and their mode shapes over nine masses, but no
inertias or stiffnesses. The table determines them up to one common scale
(domain notes, section 3):

1. The printed Q2 entry of the 20.1 Hz mode is read as -0.130 (with +0.130 the modes
   are not orthogonal); entries printed as 0.001 are zeros. Every column has unit
   Euclidean norm (0.9994..1.0006 as printed): that is the table's normalisation.
2. Inertias from mass-orthogonality: for every pair of the nine modes, the rigid mode
   (all ones) included, sum_k m_k phi_ki phi_kj = 0. That is 36 linear equations in
   the 9 inertias; their null vector (smallest singular value 4e-4 against 0.76 for the
   next) gives the inertias up to scale, m_0 = 1.
3. K = M Phi Lambda Phi^-1 (Lambda = diag(0, w_1^2 .. w_8^2)). Its off-diagonal
   entries are below 0.1% of the largest entry except for eight (4.5% and more): the tree drive - A - B, stages C and D
   on B, stands 1 and 2 on C, stands 3 and 4 on D. Those eight are the couplings.
4. The three-digit table leaves the 62.8 Hz mode 0.062 Hz off; a least-squares polish
   of the 8 inertia ratios and 8 stiffnesses (residuals: frequency / 0.05 Hz and shape
   entry / 0.01) brings every frequency within 0.021 Hz and every shape entry within
   0.0025.
5. Scale: the drive (motor) inertia is set to 1000 kg*m^2 referred to the motor shaft;
   every other value scales with it. Frequencies and shapes do not depend on it.

Writes, beside this script:
- rsm-table3.toml: the identified drive referred to the motor shaft (no gear ratios):
  Table 3 as printed (sim/tests/rsm_table3.rs checks it).
- rsm-drive.toml: the same drive with its gear stages and two servo-coupling paths:
  masses and stiffnesses on their own shafts (referred value / n^2), gear ratios
  chosen for a 4-stand block finishing at up to ~110 m/s; configuration "table3"
  (servos M3, M5) refers back to rsm-table3.toml exactly, "fast" (M4, M6) engages the
  higher B-C and B-D gear pairs.

Run: pip install numpy scipy; python3 sim/models/identify_rsm_table3.py
"""
import os

import numpy as np
import scipy.linalg as sl
from scipy.optimize import least_squares

HERE = os.path.dirname(os.path.abspath(__file__))
DRIVE_INERTIA = 1000.0  # kg*m^2, the one free scale

FREQUENCIES_HZ = np.array([20.1, 22.7, 25.2, 31.8, 45.6, 62.8, 102.0, 156.0])
NAMES = ["drive", "stage A", "stage B", "stage C", "stage D", "stand 1", "stand 2", "stand 3", "stand 4"]
# Table 3 with the Q2 sign corrected (row Q2, column 20.1 Hz: -0.130).
SHAPES = np.array([
    [-0.324, 0.073, 0.001, 0.001, -0.09, -0.001, -0.059, 0.015],
    [-0.130, 0.017, 0.001, 0.001, 0.187, 0.003, 0.854, -0.530],
    [0.073, -0.040, 0.001, 0.001, 0.406, 0.005, 0.452, 0.835],
    [0.167, -0.232, 0.001, 0.001, 0.346, -0.653, -0.147, -0.089],
    [0.205, 0.090, 0.001, 0.001, 0.575, 0.662, -0.204, -0.120],
    [0.278, -0.473, 0.001, -0.707, -0.328, 0.226, 0.016, 0.004],
    [0.278, -0.473, 0.001, 0.707, -0.328, 0.226, 0.016, 0.004],
    [0.569, 0.491, -0.707, 0.001, -0.252, -0.127, 0.013, 0.003],
    [0.569, 0.491, 0.707, 0.001, -0.252, -0.127, 0.013, 0.003],
])


def identify():
    shapes = np.where(SHAPES == 0.001, 0.0, SHAPES)
    n = len(NAMES)
    phi = np.column_stack([np.ones(n), shapes])
    rows = [phi[:, i] * phi[:, j] for i in range(n) for j in range(i + 1, n)]
    _, singular, vt = np.linalg.svd(np.array(rows))
    inertia = vt[-1] / vt[-1][0]
    print(f"orthogonality: singular values {singular[-1]:.1e} (null) and {singular[-2]:.2f}")
    lam = np.concatenate([[0.0], (2 * np.pi * FREQUENCIES_HZ) ** 2])
    stiffness = np.diag(inertia) @ phi @ np.diag(lam) @ np.linalg.inv(phi)
    largest = np.abs(stiffness).max()
    edges = [(i, j) for i in range(n) for j in range(i + 1, n)
             if abs(stiffness[i, j] + stiffness[j, i]) / 2 > 0.01 * largest]
    rest = max(abs(stiffness[i, j]) for i in range(n) for j in range(n)
               if i != j and (min(i, j), max(i, j)) not in edges)
    print("tree edges:", ", ".join(f"{NAMES[i]} - {NAMES[j]}" for i, j in edges),
          f"(other off-diagonal entries <= {rest / largest:.1e} of the largest)")
    assert len(edges) == n - 1
    k0 = [-(stiffness[i, j] + stiffness[j, i]) / 2 for i, j in edges]

    def model(p):
        m = np.concatenate([[1.0], np.exp(p[: n - 1])])
        k = np.exp(p[n - 1:])
        kk = np.zeros((n, n))
        for (i, j), c in zip(edges, k):
            kk[i, i] += c
            kk[j, j] += c
            kk[i, j] -= c
            kk[j, i] -= c
        w, v = sl.eigh(kk, np.diag(m))
        return m, k, np.sqrt(np.maximum(w, 0.0)) / (2 * np.pi), v / np.linalg.norm(v, axis=0)

    def residuals(p):
        _, _, f, v = model(p)
        r = list((f[1:] - FREQUENCIES_HZ) / 0.05)
        for c in range(1, n):
            shape = v[:, c] if v[:, c] @ shapes[:, c - 1] >= 0 else -v[:, c]
            r += list((shape - shapes[:, c - 1]) / 0.01)
        return np.array(r)

    start = np.concatenate([np.log(inertia[1:]), np.log(k0)])
    fit = least_squares(residuals, start, xtol=1e-14, ftol=1e-14)
    m, k, f, v = model(fit.x)
    worst_shape = 0.0
    for c in range(1, n):
        shape = v[:, c] if v[:, c] @ shapes[:, c - 1] >= 0 else -v[:, c]
        worst_shape = max(worst_shape, np.abs(shape - shapes[:, c - 1]).max())
    print(f"polished: frequencies within {np.abs(f[1:] - FREQUENCIES_HZ).max():.3f} Hz, "
          f"shapes within {worst_shape:.4f}")
    return edges, m * DRIVE_INERTIA, k * DRIVE_INERTIA


HEADER_TABLE3 = """# RSM block drive identified from the paper's Table 3 (Krot and Korennoy 2016), written
# by identify_rsm_table3.py (see its docstring): inertias from the orthogonality of the
# modes (rigid mode included), stiffnesses from K = M Phi Lambda Phi^-1, one free scale
# (drive inertia 1000 kg*m^2). Everything is referred to the motor shaft (no gear
# ratios): the modes are Table 3's with the Q2 sign corrected.
# Coupling damping is not identified (0); [motor], [load] and [measurement] are
# required by the model schema; the time simulation is of chains and refuses a tree.
"""

HEADER_DRIVE = """# RSM block drive with its gear stages and servo couplings, written by
# identify_rsm_table3.py. Inertias and stiffnesses are on their own shafts (the Table 3
# values referred to the motor shaft divided by n^2, n = shaft speed / motor speed).
# Gear ratios are chosen, not the paper's (it gives none), for a 4-stand block
# finishing at up to ~110 m/s with 228 mm rolls and a 600-1800 rpm motor.
# Configuration "table3" (servos M3, M5) refers back to rsm-table3.toml exactly;
# "fast" (M4, M6) engages the higher B-C and B-D gear pairs.
"""

TAIL = """
[motor]
speed_kp = 0.0
speed_ki = 0.0

[load]
static_torque = 0.0
rise_rate = 50.0
onset = 0.0

[measurement]
coupling = 0
sample_rate = 2000.0
duration = 0.5
"""

# Gear ratio (speed of the second mass over the first) per coupling of the tree, and
# the alternative gear pairs of the "fast" configuration.
RATIOS = {("drive", "stage A"): 1.0, ("stage A", "stage B"): 1.6, ("stage B", "stage C"): 1.5,
          ("stage B", "stage D"): 2.2, ("stage C", "stand 1"): 1.0, ("stage C", "stand 2"): 1.3,
          ("stage D", "stand 3"): 1.0, ("stage D", "stand 4"): 1.25}
SERVOS = {("stage B", "stage C"): ("M3", "M4", 1.8), ("stage B", "stage D"): ("M5", "M6", 2.6)}
COUPLING_NAMES = {("drive", "stage A"): "motor coupling", ("stage A", "stage B"): "gear pair A-B",
                  ("stage B", "stage C"): "gear pair B-C", ("stage B", "stage D"): "gear pair B-D",
                  ("stage C", "stand 1"): "spindle 1", ("stage C", "stand 2"): "spindle 2",
                  ("stage D", "stand 3"): "spindle 3", ("stage D", "stand 4"): "spindle 4"}


def write_table3(edges, inertia, stiffness):
    lines = [HEADER_TABLE3, 'name = "RSM block drive, paper Table 3 (referred to the motor shaft)"\n']
    for name, j in zip(NAMES, inertia):
        lines.append(f'\n[[mass]]\nname = "{name}"\ninertia = {j:.6g}\n')
    for (i, j), c in zip(edges, stiffness):
        pair = (NAMES[i], NAMES[j])
        lines.append(f'\n[[coupling]]\nname = "{COUPLING_NAMES[pair]}"\nbetween = ["{pair[0]}", "{pair[1]}"]\n'
                     f"stiffness = {c:.6g}\ndamping = 0.0\n")
    lines.append(TAIL)
    with open(os.path.join(HERE, "rsm-table3.toml"), "w") as handle:
        handle.write("".join(lines))


def write_drive(edges, inertia, stiffness):
    n = {"drive": 1.0}
    for i, j in edges:  # edges run outward from the drive in this order
        n[NAMES[j]] = n[NAMES[i]] * RATIOS[(NAMES[i], NAMES[j])]
    lines = [HEADER_DRIVE, 'name = "RSM block drive with gear stages (Table 3 in configuration table3)"\n']
    for name, j in zip(NAMES, inertia):
        lines.append(f'\n[[mass]]\nname = "{name}"\ninertia = {j / n[name] ** 2:.6g}\n')
    for (i, j), c in zip(edges, stiffness):
        pair = (NAMES[i], NAMES[j])
        own = c / n[pair[0]] ** 2
        if pair in SERVOS:
            table3_servo, fast_servo, fast_ratio = SERVOS[pair]
            for servo, ratio, label in ((table3_servo, RATIOS[pair], "low"), (fast_servo, fast_ratio, "high")):
                lines.append(f'\n[[coupling]]\nname = "{COUPLING_NAMES[pair]} ({label}, {servo})"\n'
                             f'between = ["{pair[0]}", "{pair[1]}"]\nratio = {ratio}\nservo = "{servo}"\n'
                             f"stiffness = {own:.6g}\ndamping = 0.0\n")
        else:
            ratio = RATIOS[pair]
            ratio_line = "" if ratio == 1.0 else f"ratio = {ratio}\n"
            lines.append(f'\n[[coupling]]\nname = "{COUPLING_NAMES[pair]}"\nbetween = ["{pair[0]}", "{pair[1]}"]\n'
                         f"{ratio_line}stiffness = {own:.6g}\ndamping = 0.0\n")
    lines.append(TAIL)
    lines.append('\n[[configuration]]\nname = "table3"\nengaged = ["M3", "M5"]\n')
    lines.append('\n[[configuration]]\nname = "fast"\nengaged = ["M4", "M6"]\n')
    with open(os.path.join(HERE, "rsm-drive.toml"), "w") as handle:
        handle.write("".join(lines))


if __name__ == "__main__":
    edges, inertia, stiffness = identify()
    write_table3(edges, inertia, stiffness)
    write_drive(edges, inertia, stiffness)
    print("wrote rsm-table3.toml and rsm-drive.toml")
