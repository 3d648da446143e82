"""Spacer-disk robots (issue 16): the peer's published tip, the disk model's convergence to
continuous routing, the independent BVP, and the cost against the paper's prototype.

    python benchmarks/spacer_disks.py [--repeats N]

The robot is examples/spacer_disk_robot.toml (Till & Rucker's tendon robot: steel backbone,
four tendons 15.06 mm off the centre line, routed continuously), 15 N on t1. Warm solves are
timed interleaved with the prototype's (2 N on t1), medians; cold start-up is a new process
running ``tendonsense solve`` with an empty compilation cache. The example's tendons have no
friction, as the peer's; the same robot with friction is timed too (its turning angle and
the friction's derivatives are computed only then).
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
sys.path.insert(0, str(ROOT / "tests"))

PEER_TIP = np.array([182.212, 0.0, 453.229])  # mm, the peer's shooting solution


def cold(robot_file: Path, tension: str) -> float:
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "TENDONSENSE_CACHE_DIR": cache}
        t = time.perf_counter()
        subprocess.run([sys.executable, "-m", "tendonsense.cli", "solve", str(robot_file),
                        "--tension", tension, "--json"], check=True, capture_output=True,
                       env=env)
        return time.perf_counter() - t


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=200)
    args = ap.parse_args()
    from cosserat_bvp import CosseratBVP
    from test_spacer_disks import with_tendons
    from tendonsense import load_robot
    from tendonsense.forward import solve

    peer = load_robot(ROOT / "examples" / "spacer_disk_robot.toml")
    proto = load_robot(ROOT / "examples" / "paper_prototype.toml")
    tip = solve(peer, {"t1": 15.0}).backbone[-1] * 1e3
    print(f"continuous routing: tip {np.round(tip, 4)} mm, "
          f"{np.linalg.norm(tip - PEER_TIP) * 1e3:.2f} µm from the peer's")
    for n in (11, 21, 41, 81, 161):
        t = solve(with_tendons(peer, n), {"t1": 15.0}).backbone[-1] * 1e3
        print(f"  {n:4d} disks: {np.linalg.norm(t - PEER_TIP):.4f} mm from the peer, "
              f"{np.linalg.norm(t - tip):.4f} mm from continuous")
    for mu in (0.0, 0.25):
        robot = with_tendons(peer, friction=mu)
        T = (15.0, 5.0, 0.0, 0.0)
        ref = CosseratBVP(robot, T, shear=False).solve()
        gvs = solve(robot, dict(zip(robot.tendon_names, T)))
        dy = max(abs(gvs.displacements[k] - v) for k, v in ref.tendon_length_changes().items())
        print(f"BVP, 15 N on t1 and 5 N on t2, μ = {mu}: tip "
              f"{np.linalg.norm(gvs.markers['tip'] - ref.markers()['tip']) * 1e6:.3f} µm, "
              f"lengths {dy * 1e9:.1f} nm")
    grav = CosseratBVP(peer, (0.0,) * 4, shear=False).solve().markers()["tip"]
    print(f"gravity alone: tip {np.linalg.norm(solve(peer, {}).markers['tip'] - grav) * 1e6:.4f}"
          f" µm from the BVP")

    cases = (("spacer-disk robot, 15 N", peer, {"t1": 15.0}),
             ("paper prototype, 2 N", proto, {"t1": 2.0}),
             ("spacer-disk robot with friction μ = 0.25, 15 N", with_tendons(peer, friction=0.25),
              {"t1": 15.0}))
    for _, r, T in cases:
        solve(r, T)
    times = {name: [] for name, _, _ in cases}
    for _ in range(args.repeats):
        for name, r, T in cases:
            t = time.perf_counter()
            res = solve(r, T)
            times[name].append(time.perf_counter() - t)
            assert res.converged
    for name, r, T in cases:
        print(f"warm solve, {name}: median {np.median(times[name]) * 1e3:.2f} ms "
              f"({solve(r, T).iterations} iterations)")
    for name, f, t in (("spacer-disk robot", ROOT / "examples" / "spacer_disk_robot.toml",
                        "t1=15"),
                       ("paper prototype", ROOT / "examples" / "paper_prototype.toml", "t1=2")):
        print(f"cold start-up (new process, empty cache), {name}: {cold(f, t):.2f} s")


if __name__ == "__main__":
    main()
