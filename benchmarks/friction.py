"""Friction that follows the tendon (issue 27): pull–hold–release–pull cycles of the prototype
under a known weight, the truth from the independent Cosserat BVP with per-disk stick/slip
(each disk keeps its segment's tension until the ratio across it leaves the Capstan band),
estimated from noisy readings with today's pulled-in law (a ``sliding_t1`` column of ``in``)
and with the friction history (no column). Also the single-reading ``out`` check against the
BVP paid out, and the warm cost of a log and of ``update()`` with and without a release.

    python benchmarks/friction.py [--seeds 5] [--part cycle|single|speed|all]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from cosserat_bvp import CosseratBVP  # noqa: E402
from tendonsense.estimation import PointForceUnknown, estimate, problem  # noqa: E402
from tendonsense.forward import solve  # noqa: E402
from tendonsense.logs import estimate_readings  # noqa: E402
from tendonsense.online import OnlineEstimator  # noqa: E402
from tendonsense.readings import Sample  # noqa: E402
from tendonsense.robot import load_robot  # noqa: E402

RICH = (("torsion", 4), ("bending_y", 8), ("bending_z", 8), ("elongation", 6),
        ("shear_y", 6), ("shear_z", 6))
ELEMENTS = (("torsion", 1), ("bending_y", 3), ("bending_z", 3), ("elongation", 2),
            ("shear_y", 2), ("shear_z", 2))  # per element, elements = the disks
WEIGHT = 0.637  # N, 65 gF
UNKNOWN = [PointForceUnknown(0.25, (0, 0, -1))]


def cycle_tensions():
    """t1: pulled 1 → 5 N, held, released to 1 N, held, pulled to 5 N (N)."""
    return np.concatenate([np.linspace(1.0, 5.0, 12), np.full(3, 5.0), np.linspace(5.0, 1.0, 20),
                           np.full(3, 1.0), np.linspace(1.0, 5.0, 12)])


def stick_slip_truth(robot, tensions, X):
    """Readings of the BVP with per-disk stick/slip through the tension history: (length
    changes of t1, segment tensions) per row."""
    held, prev, out = None, None, []
    for t in tensions:
        bvp = CosseratBVP(robot, (t, 0.0, 0.0), [(X, (0.0, 0.0, -WEIGHT))],
                          held=held)
        if prev is None:
            bvp.solve()
        else:
            mesh = np.linspace(0.0, 1.0, 41)  # the last solution as the start, on a fixed mesh
            bvp.solution = SimpleNamespace(x=mesh, y=prev.solution.sol(mesh))
            try:  # a mesh that must grow past 1,000 nodes: no solution near the last one
                bvp._solve((1.0,), 11, 1e-7, warm=True, max_nodes=1000)
            except RuntimeError:  # (a tendon slips far at once): in load steps, coarse each
                bvp = CosseratBVP(robot, (t, 0.0, 0.0), [(X, (0.0, 0.0, -WEIGHT))],
                                  held=held)
                bvp.solve(remesh=41)
        held, prev = {0: bvp.segment_tensions()[0]}, bvp
        out.append(bvp.tendon_length_changes()["t1"])
    return np.array(out)


def phases(T):
    """Row masks: pulled (tension rising or held after a rise) and released (falling or held
    after a fall)."""
    d = np.diff(T, prepend=T[0])
    trend = np.zeros_like(T)
    last = 1.0
    for k, v in enumerate(d):
        last = np.sign(v) if v != 0 else last
        trend[k] = last
    return trend > 0, trend < 0


def cycle(seeds: int):
    robot = load_robot(ROOT / "examples" / "paper_prototype.toml").replace(strain=RICH)
    for X, where in ((robot.rod.length, "tip"), (robot.rod.length / 2, "L/2")):
        T = cycle_tensions()
        t0 = time.perf_counter()
        y = stick_slip_truth(robot, T, X)
        print(f"# {where} weight: truth (BVP, per-disk stick/slip) "
              f"{time.perf_counter() - t0:.0f} s")
        pulled, released = phases(T)
        unknown = [PointForceUnknown(X, (0, 0, -1))]
        rows = {"today": [], "history": []}
        contained, widened, stuck_rows = 0, 0, 0
        for seed in range(seeds):
            rng = np.random.default_rng(seed)
            yn = y + 1e-4 * rng.standard_normal(y.size)
            Tn = T * (1 + 0.01 * rng.standard_normal(T.size))
            for law in rows:
                samples = [Sample(k + 1, 0.01 * k, {"t1": Tn[k], "t2": 0.0, "t3": 0.0},
                                  {"t1": yn[k]}, {},
                                  sliding={"t1": "in"} if law == "today" else {})
                           for k in range(T.size)]
                est = estimate_readings(robot, ["t1"], samples, unknown)
                err = np.array([e.magnitudes[0] / WEIGHT - 1 if e.converged else np.nan
                                for e in est]) * 100
                rows[law].append(err)
                if law == "history":
                    for e in est:
                        if e.converged and len(e.magnitude_range):
                            stuck_rows += 1
                            lo, hi = e.magnitude_range[0]
                            contained += bool(lo <= WEIGHT <= hi)
                            widened += bool(lo - 2 * e.sigma[0] <= WEIGHT <= hi + 2 * e.sigma[0])
        for law, errs in rows.items():
            e = np.array(errs)
            rms = lambda m: float(np.sqrt(np.nanmean(e[:, m] ** 2)))  # noqa: E731
            print(f"{where:4s} {law:8s} release rms {rms(released):6.2f} %   pull rms "
                  f"{rms(pulled):6.2f} %   all {rms(np.ones_like(pulled)):6.2f} %")
        print(f"{where:4s} stuck rows whose range holds the weight: {contained}/{stuck_rows}, "
              f"widened by 2 sigma: {widened}/{stuck_rows}")


def single():
    """Force error on BVP readings paid out against pulled in (the same loads), with one
    polynomial over the rod (RICH), with an element between every two disks, which follows
    the jumps of the strain at the disks (large near the tip paid out), and with two (the
    elements halved: how far each error is the basis's); t1 at 1.5, 2.4 and 3.0 N."""
    robot = load_robot(ROOT / "examples" / "paper_prototype.toml")
    inner = tuple(x for x in robot.tendons[0].disks if 0 < x < robot.rod.length)
    cuts = (0.0, *inner, robot.rod.length)
    halves = tuple(sorted({*inner, *((a + b) / 2 for a, b in zip(cuts, cuts[1:]))}))
    models = {"rich": robot.replace(strain=RICH),
              "elements": robot.replace(strain=ELEMENTS, elements=inner),
              "halved": robot.replace(strain=ELEMENTS, elements=halves)}
    for t1 in (1.5, 2.4, 3.0):
        errs, found = {}, {}
        for d in ("in", "out"):
            ref_robot = robot if d == "in" else robot.replace(tendons=tuple(
                dataclasses.replace(t, friction=-t.friction) if t.name == "t1" else t
                for t in robot.tendons))
            try:
                # small load steps from a coarse mesh each (paid out, the rod curls fast)
                ref = CosseratBVP(ref_robot, (t1, 0.0, 0.0), [(0.25, (0, 0, -0.3))]).solve(
                    steps=tuple(np.linspace(1 / 16, 1, 16)), remesh=61)
            except (RuntimeError, MemoryError) as exc:  # its mesh refined past memory
                print(f"single reading t1 = {t1} N, {d}: the reference BVP failed "
                      f"({type(exc).__name__}: {str(exc) or 'out of memory'})")
                break
            y = {"t1": ref.tendon_length_changes()["t1"]}
            for basis, model in models.items():
                r = estimate(model, y, {"t1": t1}, [PointForceUnknown(0.25, (0, 0, -1))],
                             sliding={"t1": d})
                errs[basis, d] = abs(r.magnitudes[0] / 0.3 - 1) * 100
                found[basis, d] = r.magnitudes[0], r.markers["tip"][2]
        else:  # both references solved
            for basis in models:
                e_in, e_out = errs[basis, "in"], errs[basis, "out"]
                (f_in, z_in), (f_out, z_out) = found[basis, "in"], found[basis, "out"]
                print(f"single reading t1 = {t1} N, 0.3 N at 0.25 m, {basis:8s}: force error "
                      f"in {e_in:.4f} %, out {e_out:.4f} % (ratio "
                      f"{e_out / max(e_in, 1e-12):.2f}; estimates {f_in:.4f} / {f_out:.4f} N, "
                      f"tip z {1e3 * z_in:.1f} / {1e3 * z_out:.1f} mm)")


def speed():
    """Warm cost of a 2,000-row log (median of 3) and of ``update()`` over its rows: a steady
    pull (every tendon pulled in) and a pull–release sine. For the figures before the friction
    history, run this with ``PYTHONPATH`` at an older checkout's ``src``."""
    robot = load_robot(ROOT / "examples" / "paper_prototype.toml")
    prob = problem(robot, ["t1"], UNKNOWN)
    n = 2000
    grid = np.linspace(0.9, 5.1, 43)
    ys = [solve(robot, {"t1": t}, [(0.25, (0, 0, -0.3))]).displacements["t1"] for t in grid]
    for name, T in (("steady pull", np.linspace(1.0, 5.0, n)),
                    ("pull-release", 3.0 + 2.0 * np.sin(np.linspace(0, 6 * np.pi, n)))):
        y = np.interp(T, grid, ys)
        samples = [Sample(k + 1, 0.001 * k, {"t1": T[k], "t2": 0.0, "t3": 0.0}, {"t1": y[k]}, {})
                   for k in range(n)]
        estimate_readings(robot, ["t1"], samples[:300], UNKNOWN)  # warm
        per = []
        for _ in range(3):
            t0 = time.perf_counter()
            estimate_readings(robot, ["t1"], samples, UNKNOWN)
            per.append((time.perf_counter() - t0) / n * 1e3)
        online = OnlineEstimator(prob)
        online.prepare()
        for s in samples[:300]:
            online.update(s.displacements, s.tensions)
        online.reset()
        times = []
        for s in samples:
            t0 = time.perf_counter()
            online.update(s.displacements, s.tensions)
            times.append(time.perf_counter() - t0)
        p50, p99 = np.percentile(times, [50, 99]) * 1e3
        print(f"{name:12s} log {np.median(per):.3f} ms/sample   update() p50 {p50:.3f} ms "
              f"p99 {p99:.3f} ms")


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--part", default="all", choices=("cycle", "single", "speed", "all"))
    a = ap.parse_args()
    if a.part in ("single", "all"):
        single()
    if a.part in ("speed", "all"):
        speed()
    if a.part in ("cycle", "all"):
        cycle(a.seeds)


if __name__ == "__main__":
    main()
