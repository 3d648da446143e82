"""The elements basis against the paper's global basis (issue 14): a warm forward solve, a
warm log sample (the compiled tracker), the live ``update()`` latency and a cold start-up,
both bases measured in the same run.

    python benchmarks/elements.py [--samples 2000]

The robot is the paper's prototype; the elements robot splits it at its 8 disk-to-disk
elements (bending degree 2, elongation 1: 72 coordinates, 4 Magnus steps per element).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
ROBOT = ROOT / "examples" / "paper_prototype.toml"
ELEMENTS = {"strain": (("torsion", 0), ("bending_y", 2), ("bending_z", 2), ("elongation", 1)),
            "elements": tuple(np.linspace(0.0, 0.25, 9)[1:-1])}


def timed(f, n):
    f()
    out = []
    for _ in range(n):
        t0 = time.perf_counter()
        f()
        out.append(time.perf_counter() - t0)
    return np.array(out)


def cold_start(robot_text: str) -> float:
    """Seconds for ``tendonsense solve`` in a new process with an empty program cache."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "robot.toml"
        path.write_text(robot_text)
        env = dict(os.environ, TENDONSENSE_CACHE_DIR=str(Path(tmp) / "cache"))
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "tendonsense.cli", "solve", str(path),
                        "--tension", "t1=1.5", "--point-force", "0.15,0,0.2,-0.6"],
                       check=True, env=env, capture_output=True)
        return time.perf_counter() - t0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=2000)
    args = ap.parse_args(argv)
    from tendonsense import load_robot, tracking
    from tendonsense.estimation import PointForceUnknown, problem
    from tendonsense.forward import solve
    from tendonsense.online import OnlineEstimator
    from tendonsense.model import Model
    from tendonsense.robot import robot_to_toml

    base = load_robot(ROBOT)
    robots = {"global": base, "elements": base.replace(**ELEMENTS)}
    T = {"t1": 1.5, "t2": 1.0, "t3": 0.8}
    loads = [(0.15, (0.0, 0.2, -0.6))]
    n = args.samples
    t = np.linspace(0.0, 1.0, n)
    tensions = np.zeros((n, 3))
    tensions[:, 0] = 2.0 + 1.2 * np.sin(2 * np.pi * 2 * t + 0.3)
    force = 0.2 + 0.1 * np.sin(2 * np.pi * 3 * t)
    rows = {}
    for name, robot in robots.items():
        nq = Model.build(robot).nq
        solve_ms = 1e3 * np.median(timed(lambda: solve(robot, T, loads), 30))
        batch = tracking.solve_batch(robot, tensions, [(0.25, np.stack(
            [0 * force, 0 * force, -force], axis=1))])
        assert batch.converged.all()
        y = batch.displacements["t1"]
        prob = problem(robot, ["t1"], [PointForceUnknown(0.25, (0, 0, -1))])
        disp = [{"t1": v} for v in y]
        ten = [{"t1": v} for v in tensions[:, 0]]
        tracking.estimate_series(prob, disp[:50], ten[:50])
        per_sample = []
        for _ in range(3):
            t0 = time.perf_counter()
            est = tracking.estimate_series(prob, disp, ten)
            per_sample.append((time.perf_counter() - t0) / n)
        err = max(abs(e.magnitudes[0] - f) / f for e, f in zip(est, force))
        online = OnlineEstimator(prob)
        online.update(disp[0], ten[0])
        lat = np.zeros(n)
        for k in range(n):
            t0 = time.perf_counter()
            online.update(disp[k], ten[k])
            lat[k] = time.perf_counter() - t0
        cold = np.median([cold_start(robot_to_toml(robot)) for _ in range(3)])
        rows[name] = (nq, solve_ms, 1e3 * np.median(per_sample), 1e3 * np.median(lat),
                      1e3 * np.percentile(lat, 99), cold, err)
        print(f"{name:9s} nq={nq:3d}: warm solve {solve_ms:.2f} ms; log {rows[name][2]:.3f} "
              f"ms/sample (max magnitude error {err:.1e}); update() p50 {rows[name][3]:.3f} "
              f"ms, p99 {rows[name][4]:.3f} ms; cold start-up {cold:.2f} s", flush=True)
    g, e = rows["global"], rows["elements"]
    print(f"elements / global: solve {e[1] / g[1]:.2f}x, log sample {e[2] / g[2]:.2f}x, "
          f"update p99 {e[4] / g[4]:.2f}x, cold start-up {e[5] - g[5]:+.2f} s")


if __name__ == "__main__":
    main()
