"""Where does the force act (issue 10): accuracy against the independent Cosserat BVP of the
test suite, with the global and the elements basis, and the cost of a located estimate.

    python benchmarks/location.py

The prototype, three tendons read (1.5, 1.0, 0.8 N), one force of known direction and
unknown magnitude and X between the disks; the readings come from the BVP (shear rigid).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

CASES = ((0.07, (0.0, 0.2, -0.6)), (0.1, (0.0, 0.0, -0.5)), (0.15, (0.0, 0.2, -0.6)),
         (0.175, (0.0, 0.3, -0.3)), (0.2, (0.0, 0.2, -0.6)), (0.22, (0.0, -0.3, -0.4)))


def main():
    from cosserat_bvp import CosseratBVP
    from tendonsense import load_robot
    from tendonsense.estimation import PointForceUnknown, estimate, problem
    from tendonsense.forward import solve
    from tendonsense.tracking import estimate_series

    base = load_robot(ROOT / "examples" / "paper_prototype.toml")
    el = base.replace(strain=(("torsion", 0), ("bending_y", 2), ("bending_z", 2),
                              ("elongation", 1)), elements=tuple(np.linspace(0, 0.25, 9)[1:-1]))
    T = dict(zip(base.tendon_names, (1.5, 1.0, 0.8)))
    errors = {"global": [], "elements": []}
    for X, f in CASES:
        ref = CosseratBVP(base, tuple(T.values()), [(X, f)], shear=False).solve()
        y = ref.tendon_length_changes()
        f = np.array(f)
        for name, robot in (("global", base), ("elements", el)):
            est = estimate(robot, y, T, [PointForceUnknown(None, tuple(f))])
            dx = est.extra["locations"][0] - X
            dm = est.magnitudes[0] / np.linalg.norm(f) - 1
            errors[name].append((abs(dx), abs(dm)))
            print(f"X = {X:.3f} m, {name:8s}: X error {dx * 1e3:+7.2f} mm, magnitude "
                  f"{dm * 100:+6.2f} %, σ_X {est.extra['location_sigma'][0] * 1e3:.1f} mm, "
                  f"converged {est.converged}", flush=True)
    for name, e in errors.items():
        e = np.array(e)
        print(f"{name}: X error median {np.median(e[:, 0]) * 1e3:.2f} mm (max "
              f"{e[:, 0].max() * 1e3:.2f}), magnitude median {np.median(e[:, 1]) * 100:.2f} % "
              f"(max {e[:, 1].max() * 100:.2f} %)")
    for name, robot in (("global", base), ("elements", el)):
        y = solve(robot, T, [(0.15, (0.0, 0.2, -0.6))]).displacements
        unknown = [PointForceUnknown(None, tuple(np.array([0, 0.2, -0.6]) / np.hypot(0.2, 0.6)))]
        estimate(robot, y, T, unknown)
        times = []
        for _ in range(5):
            t0 = time.perf_counter()
            estimate(robot, y, T, unknown)
            times.append(time.perf_counter() - t0)
        prob = problem(robot, list(T), unknown)
        n = 200
        F = 0.5 + 0.2 * np.sin(np.linspace(0, 2 * np.pi, n))
        d = np.array([0, 0.2, -0.6]) / np.hypot(0.2, 0.6)
        disp = [solve(robot, T, [(0.15, tuple(F[k] * d))]).displacements for k in range(n)]
        estimate_series(prob, disp[:5], [T] * 5)
        t0 = time.perf_counter()
        out = estimate_series(prob, disp, [T] * n)
        per = (time.perf_counter() - t0) / n
        print(f"{name}: a located estimate {np.median(times):.3f} s warm (median of 5); a log "
              f"{per * 1e3:.2f} ms/sample ({sum(e.converged for e in out)}/{n} converged, "
              f"the first with the search)")


if __name__ == "__main__":
    main()
