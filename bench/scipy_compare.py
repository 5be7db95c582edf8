#!/usr/bin/env python3
"""The same calibration as `taut_calib::calibrate`, with scipy.optimize.least_squares.

Same recording, same model, same weights, same loss, same initial guess:

    r_ij = (l_ij - |P_i - A_j| - L0_j) / sigma_ij          (point-mass platform)
    sigma_ij^2 = sigma_enc^2 + sigma_tracker^2 + (T_ij rho_ij / EA)^2   (rho at the initial guess)
    readings with T_ij < min_tension_n excluded; Huber loss, threshold 2 sigma

solved per cable (the problem separates; giving scipy the joint 16-parameter problem would only
make it slower) with method='trf' (MINPACK's 'lm' has no robust loss) and the analytic Jacobian.
The variances are evaluated once, at the initial guess; taut_calib evaluates them at its
least-squares stage's solution instead (a few sigma from the optimum). The weights differ by
under 1%, the results by about a micrometre (printed), far below the parameters' sigmas.

    scipy_compare.py REC.csv [--runs N] [--ours calib_once.txt]

REC.csv.init holds the initial guess (A_x A_y A_z L0 per line), written by the bench_data example.
With --ours (the output of the calib_once example) it prints both medians, the ratio and the
largest parameter difference side by side.
"""
import argparse
import io
import sys
import time

import numpy as np
from scipy.optimize import least_squares

# The project defaults ([calibration] table of taut-config).
MIN_TENSION_N = 3.0
TRACKER_SIGMA_M = 1.5e-3
ENCODER_SIGMA_M = 0.05e-3
CABLE_EA_N = 2.0e5
HUBER_K = 2.0


def load(path):
    """cdpr-recording v1 -> (P (m,3), L (m,n), F (m,n) or None)."""
    with open(path) as f:
        lines = [l for l in f if l.strip() and not l.startswith("#")]
    header = lines[0].strip().split(",")
    body = "".join(lines[1:])
    try:
        data = np.loadtxt(io.StringIO(body), delimiter=",", ndmin=2)
    except ValueError:  # empty fields (missing values)
        data = np.genfromtxt(io.StringIO(body), delimiter=",", missing_values="", filling_values=np.nan, ndmin=2)
    col = {name: k for k, name in enumerate(header)}
    p = data[:, [col["px"], col["py"], col["pz"]]]
    n = sum(1 for h in header if h[0] == "l" and h[1:].isdigit())
    l = data[:, [col[f"l{j}"] for j in range(n)]]
    f = data[:, [col[f"f{j}"] for j in range(n)]] if "f0" in col else None
    return p, l, f


def cable_problem(p, l, f, x0, j):
    """Used readings and their sigmas for cable j."""
    ok = np.isfinite(p).all(axis=1) & np.isfinite(l[:, j])
    if f is not None:
        ok &= np.isfinite(f[:, j]) & (f[:, j] >= MIN_TENSION_N)
    X, lj = p[ok], l[ok, j]
    t = f[ok, j] if f is not None else np.zeros(len(lj))
    rho0 = np.linalg.norm(X - x0[:3], axis=1)
    sigma = np.sqrt(ENCODER_SIGMA_M**2 + TRACKER_SIGMA_M**2 + (t * rho0 / CABLE_EA_N) ** 2)
    return X, lj, 1.0 / sigma


def solve_cable(X, lj, w, x0):
    def fun(x):
        return (lj - np.linalg.norm(X - x[:3], axis=1) - x[3]) * w

    def jac(x):
        d = X - x[:3]
        rho = np.linalg.norm(d, axis=1)
        J = np.empty((len(lj), 4))
        J[:, :3] = d / rho[:, None] * w[:, None]  # d r / d A = +u
        J[:, 3] = -w
        return J

    # Tolerances tighter than scipy's defaults: with the defaults trf stops early on the
    # ill-conditioned (anchor along the cable, L0) direction, centimetres from the optimum.
    return least_squares(
        fun, x0, jac=jac, method="trf", loss="huber", f_scale=HUBER_K, x_scale="jac", ftol=1e-12, xtol=1e-12, gtol=1e-12
    )


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("recording")
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--ours", help="output of the calib_once example, for the side-by-side table")
    a = ap.parse_args()
    p, l, f = load(a.recording)
    x0s = np.loadtxt(a.recording + ".init", ndmin=2)
    n = l.shape[1]
    problems = [cable_problem(p, l, f, x0s[j], j) for j in range(n)]
    times, results = [], None
    for _ in range(a.runs):
        t0 = time.perf_counter()
        results = [solve_cable(X, lj, w, x0s[j]) for j, (X, lj, w) in enumerate(problems)]
        times.append((time.perf_counter() - t0) * 1e3)
    scipy_ms = float(np.median(times))
    print(f"samples={len(p)} cables={n} runs={a.runs}")
    print(f"scipy_median_ms={scipy_ms:.1f}")
    print(f"scipy_nfev={[r.nfev for r in results]} status={[r.status for r in results]}")
    for j, r in enumerate(results):
        print("scipy_param %d %.9f %.9f %.9f %.9f" % (j, *r.x))
    if not a.ours:
        return
    ours = {}
    params = {}
    with open(a.ours) as fh:
        for line in fh:
            if line.startswith("param "):
                v = line.split()
                params[int(v[1])] = np.array([float(x) for x in v[2:6]])
            elif "=" in line and " " not in line.strip():
                k, v = line.strip().split("=", 1)
                ours[k] = v
    our_ms = float(ours["calibrate_median_ms"])
    our_solve_ms = float(ours.get("calibrate_no_heldout_median_ms", our_ms))
    diff = max(float(np.max(np.abs(results[j].x - params[j]))) for j in range(n)) if params else float("nan")
    print()
    print(f"{'':44} {'median, ms':>12} {'scipy / this':>14}")
    print(f"{'scipy least_squares (trf, huber), per cable':44} {scipy_ms:12.1f} {'':>14}")
    print(f"{'taut_calib::calibrate (with held-out solve)':44} {our_ms:12.2f} {scipy_ms / our_ms:13.0f}x")
    print(f"{'taut_calib::calibrate (no held-out solve)':44} {our_solve_ms:12.2f} {scipy_ms / our_solve_ms:13.0f}x")
    if "calibrate_median_cpu_ms" in ours:
        print(f"{'  (CPU time of the calibrating thread)':44} {float(ours['calibrate_median_cpu_ms']):12.2f}")
    print(f"largest parameter difference taut_calib vs scipy: {diff * 1e6:.2f} um")


if __name__ == "__main__":
    sys.exit(main())
