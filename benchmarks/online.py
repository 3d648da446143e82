"""Live estimation (issue 9): latency of ``OnlineEstimator.update``, the cost of impossible
samples, an overdetermined log, the CLI stream's row round trip and start-up.

    python benchmarks/online.py [--samples 10000] [--elements]

With ``--elements`` the prototype has the elements basis of ``benchmarks/elements.py`` (8
elements between the disks, 72 coordinates) instead of the paper's global one.

Prints medians and tails; timings on the shared 2-core machine vary by about ±20 %.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
ROBOT = ROOT / "examples" / "paper_prototype.toml"


def smooth_log(robot, n, tendons=("t1",)):
    """Tension of t1 and a tip force varying smoothly; the tendon lengths that match."""
    from tendonsense.tracking import solve_batch
    t = np.linspace(0.0, 1.0, n)
    F = 0.2 + 0.1 * np.sin(2 * np.pi * 3 * t)
    T = np.zeros((n, 3))
    T[:, 0] = 2.0 + 1.2 * np.sin(2 * np.pi * 2 * t + 0.3)
    out = solve_batch(robot, T, [(0.25, np.stack([0 * F, 0 * F, -F], axis=1))])
    assert out.converged.all()
    return F, T, out.displacements


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=10000)
    ap.add_argument("--elements", action="store_true",
                    help="the elements basis between the disks (72 coordinates)")
    args = ap.parse_args(argv)
    from tendonsense import load_robot
    from tendonsense.estimation import PointForceUnknown, problem
    from tendonsense.online import OnlineEstimator
    from tendonsense.robot import robot_to_toml

    robot, robot_file = load_robot(ROBOT), ROBOT
    if args.elements:
        sys.path.insert(0, str(Path(__file__).parent))
        from elements import ELEMENTS
        robot = robot.replace(**ELEMENTS)
        robot_file = Path(tempfile.mkdtemp()) / "prototype_elements.toml"
        robot_file.write_text(robot_to_toml(robot))
    n = args.samples
    F, T, Y = smooth_log(robot, n)
    names = robot.tendon_names
    readings = [({"t1": Y["t1"][k]}, {"t1": T[k, 0]}) for k in range(n)]

    # 1. update() latency over a smooth log
    online = OnlineEstimator(problem(robot, ["t1"], [PointForceUnknown(0.25, (0, 0, -1))]))
    online.update(*readings[0])
    lat, fails, kind = np.zeros(n), 0, []
    for k, (y, t) in enumerate(readings):
        t0 = time.perf_counter()
        e = online.update(y, t)
        lat[k] = time.perf_counter() - t0
        fails += not e.converged
        kind.append(e.sliding[0] if e.sliding else "in")
    print(f"update(): p50 {1e3 * np.median(lat):.3f} ms, p99 {1e3 * np.percentile(lat, 99):.3f} "
          f"ms over {n} samples, {fails} not converged")
    kind = np.array(kind)  # t1's friction: pulled in, paid out, or stuck (its range estimated)
    for what in ("in", "out", "stuck"):
        if (kind == what).any():
            print(f"  t1 {what:5s}: {(kind == what).sum():5d} samples, p50 "
                  f"{1e3 * np.median(lat[kind == what]):.3f} ms, p99 "
                  f"{1e3 * np.percentile(lat[kind == what], 99):.3f} ms")

    # 2. impossible samples (the first refused by the rules for a reading, the others with no
    # equilibrium of the model: rescued within the time limit), and a 5,000-row log with 1 %
    impossible = [({"t1": 5.0}, {"t1": 2.0}), ({"t1": -0.1}, {"t1": 2.0}),
                  ({"t1": -0.15}, {"t1": 38.0}), ({"t1": -0.2}, {"t1": 0.0}),
                  ({"t1": -0.05}, {"t1": 0.1})]
    cost = []
    for bad in impossible * 4:
        online.update(*readings[10])
        t0 = time.perf_counter()
        e = online.update(*bad)
        cost.append(time.perf_counter() - t0)
        assert not e.converged, bad
    print(f"impossible sample: median {1e3 * np.median(cost):.1f} ms, max "
          f"{1e3 * np.max(cost):.1f} ms ({len(cost)} samples of {len(impossible)} kinds)")
    m = min(5000, n)
    rng = np.random.default_rng(0)
    bad_rows = set(rng.choice(np.arange(1, m), m // 100, replace=False).tolist())
    for tag, rows in (("clean", set()), ("1 % impossible", bad_rows)):
        online.reset()
        t0 = time.perf_counter()
        ok = 0
        for k in range(m):
            e = online.update(*(impossible[k % len(impossible)] if k in rows else readings[k]))
            ok += e.converged
        dt = time.perf_counter() - t0
        print(f"{m}-row log, {tag}: {dt:.2f} s, {ok} converged, {m - ok} marked")

    # 3. overdetermined: three tendons read, one unknown force
    T3 = np.tile([1.0, 0.5, 0.7], (200, 1)) * np.linspace(1, 2, 200)[:, None]
    from tendonsense.tracking import solve_batch
    f3 = np.linspace(0.1, 0.3, 200)
    out = solve_batch(robot, T3, [(0.25, np.stack([0 * f3, 0 * f3, -f3], axis=1))])
    over = OnlineEstimator(problem(robot, list(names), [PointForceUnknown(0.25, (0, 0, -1))]))
    over.update({t: out.displacements[t][0] for t in names}, dict(zip(names, T3[0])))
    lat3, ok3 = [], 0
    for k in range(200):
        t0 = time.perf_counter()
        e = over.update({t: out.displacements[t][k] for t in names}, dict(zip(names, T3[k])))
        lat3.append(time.perf_counter() - t0)
        ok3 += e.converged and abs(e.magnitudes[0] - f3[k]) < 1e-6 * f3[k]
    print(f"overdetermined log (3 tendons, 1 unknown): median {1e3 * np.median(lat3):.2f} ms "
          f"per sample, {ok3}/200 converged and right")

    # 4. the CLI stream: round trip of one row through a pipe
    proc = subprocess.Popen([sys.executable, "-m", "tendonsense.cli", "estimate",
                             str(robot_file), "--readings", "-", "--unknown", "0.25,0,0,-1"],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                            text=True, bufsize=1)
    proc.stdin.write("time,tension_t1,tension_t2,tension_t3,displacement_t1\n")
    proc.stdin.flush()
    proc.stdout.readline()
    trip = []
    for k in range(min(n, 2000)):
        t0 = time.perf_counter()
        proc.stdin.write(f"{k},{float(T[k, 0])!r},0,0,{float(Y['t1'][k])!r}\n")
        proc.stdin.flush()
        proc.stdout.readline()
        trip.append(time.perf_counter() - t0)
    proc.stdin.close()
    proc.wait()
    trip = np.array(trip[5:])
    print(f"CLI stream row round trip: p50 {1e3 * np.median(trip):.2f} ms, p99 "
          f"{1e3 * np.percentile(trip, 99):.2f} ms")

    # 5. start-up, warm on-disk cache: the commands against a bare import jax + a tiny jit
    def wall(cmd):
        best = []
        for _ in range(3):
            t0 = time.perf_counter()
            subprocess.run(cmd, check=True, capture_output=True)
            best.append(time.perf_counter() - t0)
        return float(np.median(best))
    bare = wall([sys.executable, "-c", "import jax; jax.config.update('jax_enable_x64', True); "
                 "jax.jit(lambda x: x + 1)(1.0).block_until_ready()"])
    tool = [sys.executable, "-m", "tendonsense.cli"]
    s = wall(tool + ["solve", str(robot_file), "--tension", "t1=2.0"])
    e = wall(tool + ["estimate", str(robot_file), "--displacement", "t1=-0.005", "--tension",
                     "t1=2.1", "--unknown", "0.25,0,0,-1"])
    print(f"start-up: bare import jax + tiny jit {bare:.2f} s; solve {s:.2f} s (+{s - bare:.2f}); "
          f"estimate {e:.2f} s (+{e - bare:.2f})")


if __name__ == "__main__":
    main()
