"""Calibration without a camera (issue 11): E, ρ and μ from tendon length readings alone.

    python benchmarks/calibration.py [--seeds N]

The tutorial's 13 camera-free poses (tip weights, each tendon pulled, pairs) of the paper's
prototype with E = 1 MPa, ρ = 1340 kg/m³, μ = 0.4, read by all three tendons; the fit starts
from E = 1.5 MPa, ρ = 1100 kg/m³, μ = 0.2. Reports the cold and warm time of the 13-snapshot,
3-parameter fit (median of 5 warm runs), the error without noise, the spread of the errors
with 0.1 mm length noise over ``--seeds`` draws, and the cost of a leave-one-out
cross-validation. Then the same from snapshots of the independent BVP (shear rigid) with
E, ρ, μ unlike the robot file's, with the global and the elements basis.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

POSES = [({}, 0.0), ({}, 5.0), ({}, 10.0), ({}, 20.0), ({"t1": 1.0}, 0.0), ({"t1": 2.0}, 0.0),
         ({"t1": 3.0}, 0.0), ({"t2": 2.0}, 0.0), ({"t3": 2.0}, 0.0), ({"t1": 2.0}, 10.0),
         ({"t1": 3.5}, 0.0), ({"t2": 3.0}, 0.0), ({"t3": 3.0}, 0.0)]
GF = 9.80665e-3
ALL = ("young_modulus", "density", "friction")


def snapshots(robot, noise, rng, solve_fn):
    from tendonsense.identification import Snapshot
    out = []
    for T, grams in POSES:
        load = (0.25, (0.0, 0.0, -grams * GF)) if grams else None
        y = solve_fn(robot, T, load)
        out.append(Snapshot({n: T.get(n, 0.0) for n in robot.tendon_names}, {}, load,
                            {n: v + (rng.normal(0, noise) if noise else 0.0)
                             for n, v in y.items()}))
    return out


def errors(fit, true):
    return {k: fit.parameters[k] / v - 1 for k, v in true.items()}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=20)
    args = ap.parse_args()
    from cosserat_bvp import CosseratBVP
    from tendonsense import load_robot
    from tendonsense.forward import solve
    from tendonsense.identification import identify

    truth = load_robot(ROOT / "examples" / "paper_prototype.toml")
    true = {"young_modulus": 1e6, "density": 1340.0, "friction": 0.4}
    guess = truth.with_parameters(young_modulus=1.5e6, density=1100.0, friction=0.2)

    def model(robot, T, load):
        return solve(robot, T, [load] if load else []).displacements

    clean = snapshots(truth, 0.0, None, model)
    t = time.perf_counter()
    fit = identify(guess, clean, ALL)
    cold = time.perf_counter() - t
    warm = []
    for _ in range(5):
        t = time.perf_counter()
        fit = identify(guess, clean, ALL)
        warm.append(time.perf_counter() - t)
    print(f"13 snapshots, 3 parameters, tendon readings only: cold {cold:.2f} s, warm median "
          f"{np.median(warm):.3f} s ({fit.iterations} iterations); errors without noise "
          + ", ".join(f"{k} {v:.1e}" for k, v in errors(fit, true).items()))
    rng = np.random.default_rng(0)
    spread = []
    for _ in range(args.seeds):
        f = identify(guess, snapshots(truth, 1e-4, rng, model), ALL)
        spread.append([abs(v) for v in errors(f, true).values()] + [f.converged])
    spread = np.array(spread)
    print(f"0.1 mm length noise, {args.seeds} draws: |error| median / max "
          + ", ".join(f"{k} {np.median(spread[:, i]) * 100:.2f} / {spread[:, i].max() * 100:.2f} %"
                      for i, k in enumerate(true))
          + f"; converged {int(spread[:, 3].sum())}/{args.seeds}")
    t = time.perf_counter()
    cv = identify(guess, snapshots(truth, 1e-4, np.random.default_rng(1), model), ALL,
                  crossval=True)
    print(f"cross-validation (13 refits): {time.perf_counter() - t:.2f} s; left-out / fitted "
          f"RMS length error median {np.median([c.displacement_error for c in cv.crossval]) * 1e6:.0f}"
          f" / {np.median([c.fitted_displacement_error for c in cv.crossval]) * 1e6:.0f} µm")

    bvp_true = {"young_modulus": 0.8e6, "density": 1500.0, "friction": 0.25}
    bvp_robot = truth.with_parameters(**bvp_true)

    def bvp(robot, T, load):
        Tv = tuple(T.get(n, 0.0) for n in robot.tendon_names)
        return CosseratBVP(robot, Tv, [load] if load else [], shear=False).solve(
        ).tendon_length_changes()

    t = time.perf_counter()
    ref = snapshots(bvp_robot, 0.0, None, bvp)
    print(f"BVP snapshots (E 0.8 MPa, ρ 1500, μ 0.25): {time.perf_counter() - t:.0f} s")
    elements = truth.replace(
        strain=(("torsion", 0), ("bending_y", 2), ("bending_z", 2), ("elongation", 1)),
        elements=tuple(np.linspace(0.0, 0.25, 9)[1:-1]))
    for name, robot in (("global", truth), ("elements", elements)):
        t = time.perf_counter()
        f = identify(robot, ref, ALL)
        print(f"  {name} basis: " + ", ".join(f"{k} {v * 100:+.2f} %"
                                               for k, v in errors(f, bvp_true).items())
              + f", length RMSE {f.displacement_rmse * 1e6:.1f} µm, converged {f.converged}, "
              f"{time.perf_counter() - t:.1f} s (cold)")


if __name__ == "__main__":
    main()
