"""tendonsense speed benchmark (issue 5): every figure beside a plain SciPy reference path on
the same model (``scipy.optimize.least_squares`` with its default finite-difference
Jacobian), measured in the same run.

    python benchmarks/bench.py            # full run (about 5 minutes on 2 cores)
    python benchmarks/bench.py --quick    # smaller logs, for a smoke test

The problem is the paper's prototype (15 coordinates, 3 tendons, 9 disks) estimating one
tip-force magnitude from tendon t1.
"""

from __future__ import annotations

import argparse
import csv
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
ROBOT = ROOT / "examples" / "paper_prototype.toml"


def make_log(robot, n, seed=0):
    """A smooth 2-D trajectory of (tension, tip force) and the matching tendon lengths."""
    from tendonsense.forward import solve
    t = np.linspace(0.0, 1.0, n)
    F = 0.2 + 0.1 * np.sin(2 * np.pi * 3 * t)
    T = 2.0 + 1.2 * np.sin(2 * np.pi * 2 * t + 0.3)
    y, q = [], None
    for k in range(n):
        r = solve(robot, {"t1": T[k]}, [(0.25, (0.0, 0.0, -F[k]))], q0=q)
        q = r.q
        y.append(r.displacements["t1"])
    return F, T, np.array(y)


def scipy_reference(prob, Y, T, n):
    """Warm-started scipy.optimize.least_squares (finite-difference Jacobian) on our
    residual: seconds per sample and the magnitudes."""
    import jax
    import jax.numpy as jnp
    from scipy.optimize import least_squares
    from tendonsense.statics import residual, scaling
    s, v = prob.model.structure, prob.model.values
    sc = scaling(v, prob.measured)
    fun = jax.jit(lambda x, d: residual(s, v, prob.measured, x, d, prob.unknowns, 1.0, sc)[0])
    x = np.zeros(prob.model.nq + 1)
    d = prob.drive(np.array([T[0], 0, 0]), np.array([Y[0]]))
    fun(jnp.asarray(x), d).block_until_ready()
    out = []
    t0 = time.perf_counter()
    for k in range(n):
        d = prob.drive(np.array([T[k], 0, 0]), np.array([Y[k]]))
        sol = least_squares(lambda x: np.asarray(fun(jnp.asarray(x), d)), x, xtol=1e-14,
                            ftol=1e-14, gtol=1e-14)
        x = sol.x
        out.append(x[-1])
    return (time.perf_counter() - t0) / n, np.array(out)


def cli_log(n_rows, F, T, Y, env):
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "in.csv"
        with open(path, "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["time", "tension_t1", "tension_t2", "tension_t3", "displacement_t1"])
            for k in range(n_rows):
                w.writerow([k * 0.01, T[k], 0, 0, Y[k]])
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "tendonsense.cli", "estimate", str(ROBOT),
                        "--readings", str(path), "--unknown", "0.25,0,0,-1", "-o",
                        str(Path(tmp) / "out.csv"), "--quiet"], check=True, env=env,
                       capture_output=True)
        return time.perf_counter() - t0


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    n_log, n_batch, n_ref, reps = (200, 1000, 20, 2) if args.quick else (2000, 10000, 100, 3)

    import tendonsense  # noqa: F401
    from tendonsense import tracking
    from tendonsense.estimation import PointForceUnknown, estimate_problem, problem
    from tendonsense.robot import load_robot

    robot = load_robot(ROBOT)
    prob = problem(robot, ["t1"], [PointForceUnknown(0.25, (0.0, 0.0, -1.0))])
    print(f"generating a log of {n_log} samples ...", flush=True)
    F, T, Y = make_log(robot, n_log)
    disp = [{"t1": y} for y in Y]
    ten = [{"t1": t} for t in T]

    # 1. warm-started estimation over the log, Python API
    tracking.estimate_series(prob, disp[:100], ten[:100])  # compile
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        est = tracking.estimate_series(prob, disp, ten)
        times.append((time.perf_counter() - t0) / n_log)
    api = statistics.median(times)
    z = np.array([e.magnitudes[0] for e in est])
    assert all(e.converged for e in est)
    ref_time, ref_z = scipy_reference(prob, Y, T, n_ref)
    plain = [estimate_problem(prob, disp[k], ten[k]) for k in range(0, n_log, n_log // 20)]
    same = max(abs(p.magnitudes[0] - z[k]) / abs(p.magnitudes[0])
               for p, k in zip(plain, range(0, n_log, n_log // 20)))
    sig = max(abs(p.sigma[0] - est[k].sigma[0]) / p.sigma[0]
              for p, k in zip(plain, range(0, n_log, n_log // 20)))
    print(f"log estimation, API:   {api * 1e3:.3f} ms/sample (median of {reps}, {n_log} "
          f"samples); SciPy least_squares: {ref_time * 1e3:.2f} ms/sample; ratio "
          f"{ref_time / api:.0f}x; vs the paper's 167 ms: {0.167 / api:.0f}x")
    print(f"  {np.mean([e.iterations for e in est]):.2f} residual evaluations per sample")
    print(f"  agreement with the plain path: magnitudes {same:.1e} relative, sigma {sig:.1e}; "
          f"with SciPy: {np.max(np.abs(ref_z - z[:n_ref]) / np.abs(z[:n_ref])):.1e}; "
          f"with the truth: {np.max(np.abs(z - F) / F):.1e}")

    # 2. the same through the command line (per sample once past start-up)
    env = dict(os.environ)
    cli_log(10, F, T, Y, env)  # fills the on-disk compilation cache
    small = cli_log(10, F, T, Y, env)
    full = statistics.median(cli_log(n_log, F, T, Y, env) for _ in range(reps))
    print(f"log estimation, CLI:   {(full - small) / (n_log - 10) * 1e3:.3f} ms/sample "
          f"(whole command {full:.2f} s for {n_log} rows, {small:.2f} s for 10)")

    # 3. cold solve from the shell
    cold = []
    for cache in ("", None):
        e = dict(env)
        if cache is not None:
            e["TENDONSENSE_CACHE_DIR"] = cache
        for _ in range(2):
            t0 = time.perf_counter()
            subprocess.run([sys.executable, "-m", "tendonsense.cli", "solve", str(ROBOT),
                            "--tension", "t1=2.0", "--json"], check=True, env=e,
                           capture_output=True)
            cold.append(time.perf_counter() - t0)
    print(f"cold `tendonsense solve`: {cold[3]:.2f} s with the on-disk compilation cache, "
          f"{cold[1]:.2f} s without it")

    # 4. batch of independent readings
    rng = np.random.default_rng(1)
    pick = rng.integers(0, n_log, n_batch)
    bd = [{"t1": Y[k] + rng.normal(scale=1e-5)} for k in pick]
    bt = [{"t1": T[k] * (1 + rng.normal(scale=1e-3))} for k in pick]
    tracking.estimate_batch(prob, bd[:200], bt[:200])
    t0 = time.perf_counter()
    out = tracking.estimate_batch(prob, bd, bt)
    rate = n_batch / (time.perf_counter() - t0)
    print(f"batch of {n_batch} independent readings: {rate:.0f} samples/s on 2 threads "
          f"({sum(o.converged for o in out)} converged); SciPy reference: "
          f"{1 / ref_time:.0f} samples/s (warm-started, one core)")


if __name__ == "__main__":
    main()
