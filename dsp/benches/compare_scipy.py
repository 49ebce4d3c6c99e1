#!/usr/bin/env python3
"""Time scipy.optimize.curve_fit against millgate-dsp's fit_eq1 on the same records.

For each length, `cargo run --release --example fit_timing` generates the Table 1
transient over 0.5 s with seeded gaussian noise (RMS 2% of a9), writes it to CSV, fits
it (no initial guess: matrix-pencil start) and prints its median time as JSON. This
script fits the very same CSV with curve_fit given the TRUE parameters as the initial
guess (the most favourable start scipy can get), and prints both times, both
frequency errors and the speed ratio. Both fits must find the same frequencies (f1 and
f2 within a relative 1e-6 of scipy's, the resolution of the printed parameters is 1e-7):
the script exits with status 1 otherwise.

Usage (from the repository root): python3 dsp/benches/compare_scipy.py
With FIT_TIMING=/path/to/fit_timing set, that binary is run instead of `cargo run`:
so two builds (a branch and main) can be timed alternately against scipy in one
sitting, each run measuring scipy again beside it.
Needs: pip install numpy scipy
"""

import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np
from scipy.optimize import curve_fit

TABLE1 = [-147.0, 85.0, 191.0, -31.0, 11.99, 20.91, 22.17, 3.65, 112.0, 36.7]

# Largest relative difference between our fitted f1, f2 and scipy's.
SAME_FREQUENCY = 1e-6


def eq1(t, a1, a2, a3, a4, a5, a6, a7, a8, a9, a10):
    """Paper eq. (1), corrected form (domain notes 1.1)."""
    return (
        (a1 * np.cos(2 * np.pi * a5 * t) + a3 * np.sin(2 * np.pi * a5 * t)) * np.exp(-a7 * t)
        + (a2 * np.cos(2 * np.pi * a6 * t) + a4 * np.sin(2 * np.pi * a6 * t)) * np.exp(-a8 * t)
        + a9 * (1 - np.exp(-a10 * t))
    )


def rust_fit(length, csv_path):
    env = dict(os.environ)
    env.setdefault("CARGO_TARGET_DIR", "target-dsp")
    binary = env.get("FIT_TIMING")
    command = [binary] if binary else [
        "cargo", "run", "--release", "-q", "-p", "millgate-dsp", "--example", "fit_timing",
        "--"]
    out = subprocess.run(
        command + [str(length), csv_path],
        check=True, capture_output=True, text=True, env=env,
    )
    return json.loads(out.stdout)


def scipy_fit(csv_path, repeats):
    data = np.loadtxt(csv_path, delimiter=",", skiprows=1)
    t, y = data[:, 0], data[:, 1]
    params, _ = curve_fit(eq1, t, y, p0=TABLE1, maxfev=20000)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        curve_fit(eq1, t, y, p0=TABLE1, maxfev=20000)
        times.append(time.perf_counter() - start)
    times.sort()
    rms = float(np.sqrt(np.mean((y - eq1(t, *params)) ** 2)))
    return params, times[len(times) // 2], rms


def main():
    print(f"{'N':>5} | {'ours (s)':>10} {'scipy (s)':>10} {'ratio':>7} | "
          f"{'f1 err ours':>11} {'f1 err scipy':>12} | {'f2 err ours':>11} "
          f"{'f2 err scipy':>12} | {'rms ours':>8} {'rms scipy':>9}")
    failed = False
    with tempfile.TemporaryDirectory() as tmp:
        for length in (500, 2000):
            csv_path = os.path.join(tmp, f"table1_{length}.csv")
            ours = rust_fit(length, csv_path)
            params, scipy_s, scipy_rms = scipy_fit(csv_path, repeats=50)
            f1_err = abs(params[4] / TABLE1[4] - 1)
            f2_err = abs(params[5] / TABLE1[5] - 1)
            print(f"{length:>5} | {ours['median_s']:>10.2e} {scipy_s:>10.2e} "
                  f"{scipy_s / ours['median_s']:>6.1f}x | {ours['f1_rel_error']:>11.2e} "
                  f"{f1_err:>12.2e} | {ours['f2_rel_error']:>11.2e} {f2_err:>12.2e} | "
                  f"{ours['rms_residual']:>8.4f} {scipy_rms:>9.4f}")
            for name, index in (("f1", 4), ("f2", 5)):
                difference = abs(ours["params"][index] / params[index] - 1)
                if difference > SAME_FREQUENCY:
                    print(f"{length} samples: {name} {ours['params'][index]} differs from "
                          f"scipy's {params[index]} by {difference:.1e} (relative)")
                    failed = True
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
