#!/usr/bin/env python3
"""Compare millgate-sim's RK4 chain with scipy.integrate.solve_ivp on the same model.

Usage (from the repository root; needs `pip install numpy scipy`):

    python3 sim/benches/compare_solve_ivp.py [MODEL.toml]

Both solvers run the same model (same equations and conventions as sim/src/chain.rs:
rest start with centred gaps, PI on mass 0 with integral = -theta0, dead-zone
couplings, load ramp on the last mass) on the same output grid. Accuracy is the maximum
deviation from a reference (the Rust simulator with 64x its automatic number of steps,
which must itself agree with a tight solve_ivp run). Speed is the median wall time of
one whole simulation. solve_ivp is tried at several tolerances; the ratio is printed for
the loosest tolerance at which it is at least as accurate as the Rust default.
"""

import json
import os
import subprocess
import sys
import tempfile
import time
import tomllib

import numpy as np
from scipy.integrate import solve_ivp

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DEFAULT_MODEL = os.path.join(ROOT, "sim", "models", "table2-adjusted-backlash.toml")


def rust_run(model, substeps=None):
    """Runs the Rust bench binary; returns (timing dict, torque array)."""
    with tempfile.NamedTemporaryFile(suffix=".csv", delete=False) as tmp:
        csv_path = tmp.name
    cmd = ["cargo", "bench", "-q", "-p", "millgate-sim", "--bench", "realtime", "--",
           "--model", model, "--csv", csv_path, "--json"]
    if substeps is not None:
        cmd += ["--substeps", str(substeps)]
    out = subprocess.run(cmd, cwd=ROOT, check=True, capture_output=True, text=True).stdout
    timing = json.loads(out.strip().splitlines()[-1])
    data = np.loadtxt(csv_path, delimiter=",", skiprows=1)
    os.unlink(csv_path)
    return timing, data[:, 1]


def make_rhs(m):
    inertia = np.array([x["inertia"] for x in m["mass"]])
    stiffness = np.array([c["stiffness"] for c in m["coupling"]])
    damping = np.array([c["damping"] for c in m["coupling"]])
    half_gap = np.array([c.get("backlash", 0.0) / 2.0 for c in m["coupling"]])
    kp, ki = m["motor"]["speed_kp"], m["motor"]["speed_ki"]
    load = m["load"]
    static_nm, rate, onset = load["static_torque"] * 1e3, load["rise_rate"], load["onset"]
    n = len(inertia)

    def coupling_torque(y):
        theta, omega = y[:n], y[n:]
        x = theta[:-1] - theta[1:]
        elastic = np.where(x > half_gap, stiffness * (x - half_gap),
                           np.where(x < -half_gap, stiffness * (x + half_gap), 0.0))
        return elastic + damping * (omega[:-1] - omega[1:])

    def rhs(t, y):
        theta, omega = y[:n], y[n:]
        torque = coupling_torque(y)
        load_nm = static_nm * (1.0 - np.exp(-rate * (t - onset))) if t > onset else 0.0
        into = np.concatenate(([-kp * omega[0] - ki * theta[0]], torque))
        out = np.concatenate((torque, [load_nm]))
        return np.concatenate((omega, (into - out) / inertia))

    return n, rhs, coupling_torque


def scipy_run(m, t_eval, method, rtol):
    n, rhs, coupling_torque = make_rhs(m)
    measured = m["measurement"]["coupling"]
    sol = solve_ivp(rhs, (0.0, t_eval[-1]), np.zeros(2 * n), method=method, t_eval=t_eval,
                    rtol=rtol, atol=rtol * 1e-3, max_step=1.0 / m["measurement"]["sample_rate"])
    if not sol.success:
        raise RuntimeError(sol.message)
    return np.array([coupling_torque(sol.y[:, k])[measured] for k in range(len(t_eval))]) * 1e-3


def timed(fn, repeats):
    times = []
    result = None
    for _ in range(repeats):
        start = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - start)
    return float(np.median(times)), result


def main():
    model_path = sys.argv[1] if len(sys.argv) > 1 else DEFAULT_MODEL
    with open(model_path, "rb") as f:
        m = tomllib.load(f)
    fs = m["measurement"]["sample_rate"]
    samples = int(round(m["measurement"]["duration"] * fs))
    t_eval = np.arange(samples) / fs

    rust_timing, rust_torque = rust_run(model_path)
    ref_timing, reference = rust_run(model_path, substeps=64 * rust_timing["substeps"])
    scale = np.max(np.abs(reference))
    rust_error = np.max(np.abs(rust_torque - reference))
    tight = scipy_run(m, t_eval, "DOP853", 1e-12)
    cross_check = np.max(np.abs(tight - reference))
    print(f"model: {model_path}")
    print(f"reference: Rust with {ref_timing['substeps']} steps/sample; "
          f"tight DOP853 (rtol 1e-12) agrees to {cross_check:.2e} kN*m "
          f"({cross_check / scale:.1e} of peak {scale:.1f} kN*m)")
    print(f"rust RK4 ({rust_timing['substeps']} step/sample, {rust_timing['gap_crossings']} gap "
          f"crossings): max error {rust_error:.2e} kN*m, {rust_timing['wall_s_per_run'] * 1e6:.1f} us/run, "
          f"{rust_timing['realtime_factor']:.0f}x real time")

    chosen = None
    for method in ("RK45", "DOP853"):
        for rtol in (1e-6, 1e-8, 1e-10):
            wall, torque = timed(lambda: scipy_run(m, t_eval, method, rtol), 3)
            error = np.max(np.abs(torque - reference))
            print(f"solve_ivp {method:6s} rtol {rtol:.0e}: max error {error:.2e} kN*m, "
                  f"{wall * 1e3:.1f} ms/run, {m['measurement']['duration'] / wall:.1f}x real time")
            if error <= rust_error and (chosen is None or wall < chosen[2]):
                chosen = (method, rtol, wall, error)
    if chosen is None:
        print("no solve_ivp setting tried reached the Rust accuracy")
    else:
        method, rtol, wall, error = chosen
        print(f"ratio at equal or better accuracy (solve_ivp {method} rtol {rtol:.0e}): "
              f"Rust is {wall / rust_timing['wall_s_per_run']:.0f}x faster")


if __name__ == "__main__":
    main()
