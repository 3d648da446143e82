"""Estimation in motion (issue 26): the filter on the damped model against the quasi-static
estimate, on readings logs simulated with inertia and damping; update() latency; simulate.

    python benchmarks/motion.py [--seeds 5] [--part accuracy|latency|simulate|inertia|all]

The paper's experiment of Fig. 7 on its prototype: t1 pulled from 1.9 N to 4.78 N and
released at three speeds (3.0, 4.2 and 12 mm/s of tendon travel, a little faster than the
paper's 2.5, 3.5 and 10 mm/s) with 1 s holds, a
65 gF weight at L/2 (the unknown, a force along −z there), logged at 100 Hz; and the same
weight stepping by −0.32 N in the middle of a pull. Relaxation time τ = 30 ms and 0.3 s;
read-out noise 0.1 mm and 1 % tension (5 seeds), and none. Errors are relative to the
weight; "moving" rows are those of the ramps, "rest" rows the last 0.3 s of every hold
(and the whole first hold, which starts at rest).
Prints a table; timings on the shared 2-core machine vary by about ±20 %.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
ROBOT = ROOT / "examples" / "paper_prototype_damped.toml"
WEIGHT = 0.065 * 9.81
X = 0.125
LOW, HIGH = 1.9, 4.78
SPEEDS = (0.47, 0.66, 1.9)  # N/s: 3.0, 4.2 and 12 mm/s of t1
HOLD = 1.0
DT = 0.01


def schedule():
    """Tension knots of t1 and the ramps' time intervals."""
    t, T, ramps = [0.0, HOLD], [LOW, LOW], []
    for rate in SPEEDS:
        for a, b in ((LOW, HIGH), (HIGH, LOW)):
            t0 = t[-1]
            t += [t0 + (HIGH - LOW) / rate, t0 + (HIGH - LOW) / rate + HOLD]
            T += [b, b]
            ramps.append((t0, t0 + (HIGH - LOW) / rate))
    return np.array(t), np.array(T), ramps


def robot_with(tau):
    from tendonsense import load_robot
    import dataclasses
    robot = load_robot(ROBOT)
    return robot.replace(rod=dataclasses.replace(robot.rod,
                                                 damping=tau * robot.rod.young_modulus / 3))


def simulated(robot, step: bool):
    """The motion with inertia from the equilibrium at t = 0; the weight (and its step)."""
    from tendonsense.forward import solve
    from tendonsense.simulation import simulate
    t, T, ramps = schedule()
    duration = t[-1]
    if step:  # −0.32 N in the middle of the second pull
        ts = 0.5 * sum(ramps[2])
        ft = np.array([0.0, ts, ts + 1e-3, duration])
        mag = np.array([WEIGHT, WEIGHT, WEIGHT - 0.32, WEIGHT - 0.32])
        force = (X, (ft, np.stack([0 * mag, 0 * mag, -mag], 1)))
    else:
        ts, ft, mag = None, np.array([0.0]), np.array([WEIGHT])
        force = (X, (0.0, 0.0, -WEIGHT))
    q0 = solve(robot, {"t1": LOW}, [(X, (0.0, 0.0, -WEIGHT))]).q
    sim = simulate(robot, {"t1": (t, T)}, [force], duration=duration, output_dt=DT, q0=q0)
    assert sim.ok
    truth = np.interp(sim.time, ft, mag)
    return sim, truth, ramps, ts


def estimates(robot, cols, dynamic, inertia=True):
    from tendonsense.estimation import problem
    from tendonsense.filtering import MotionFilter
    from tendonsense.inputs import Noise, PointForceUnknown
    from tendonsense.logs import estimate_readings
    from tendonsense.readings import Sample
    unknowns = [PointForceUnknown(X, (0, 0, -1))]
    prob = problem(robot, ["t1"], unknowns)
    noise = Noise(1e-4, 0.01)
    disp = [{"t1": v} for v in cols["displacement_t1"]]
    ten = [{n: cols[f"tension_{n}"][k] for n in robot.tendon_names} for k in range(len(disp))]
    if dynamic:
        f = MotionFilter(prob, noise, inertia=inertia)
        out = [f.update(d, T, t) for d, T, t in zip(disp, ten, cols["time"])]
    else:  # estimate --readings: friction following each tendon's history
        rows = [Sample(k + 1, t, T, d, {})
                for k, (d, T, t) in enumerate(zip(disp, ten, cols["time"]))]
        out = estimate_readings(robot, ["t1"], rows, unknowns, noise=noise)
    return np.array([e.magnitudes[0] if e.converged else np.nan for e in out])


def accuracy(seeds):
    print("| τ | log | estimator | moving: mean abs / rms (%) | rest: rms (%) | step to 90 % |")
    print("|---|---|---|---|---|---|")
    for tau in (0.03, 0.3):
        robot = robot_with(tau)
        for step in (False, True):
            sim, truth, ramps, ts = simulated(robot, step)
            t = sim.time
            moving = np.zeros(t.shape, bool)
            for a, b in ramps:
                moving |= (t > a) & (t < b)
            rest = ~moving  # the last 0.3 s of every hold: the ringing of a ramp's end gone
            for a, b in ramps:
                rest &= ~((t >= a) & (t < b + HOLD - 0.3))
            if step:  # the step's own transient is judged by its 90 % time
                moving &= ~((t >= ts) & (t < ts + 0.3))
            logs = [("no noise", sim.readings())] + [
                (f"noise seed {s}", sim.readings(1e-4, 0.01, seed=s)) for s in range(seeds)]
            for dyn in (False, True):
                rows = []
                for _, cols in logs:
                    est = estimates(robot, cols, dyn)
                    err = 100 * (est - truth) / WEIGHT
                    t90 = np.nan
                    if step:
                        after = (t >= ts) & (est <= truth[0] - 0.9 * 0.32)
                        t90 = t[after][0] - ts if after.any() else np.inf
                    rows.append((np.nanmean(np.abs(err[moving])),
                                 np.sqrt(np.nanmean(err[moving] ** 2)),
                                 np.sqrt(np.nanmean(err[rest] ** 2)), t90))
                name = "filter (--dynamic)" if dyn else "quasi-static"
                clean, noisy = rows[0], np.array(rows[1:])
                step_s = (f"{clean[3]:.3f} s / {np.median(noisy[:, 3]):.3f} s" if step
                          else "")
                print(f"| {tau:g} s | {'step' if step else 'Fig. 7'} | {name} | "
                      f"{clean[0]:.3f} / {clean[1]:.3f}; noisy {np.mean(noisy[:, 0]):.3f} / "
                      f"{np.mean(noisy[:, 1]):.3f} | {clean[2]:.3f}; noisy "
                      f"{np.mean(noisy[:, 2]):.3f} | {step_s} |", flush=True)


def inertia():
    """The filter's error while moving at τ = 30 ms (no noise) on the Fig. 7 log simulated
    with and without inertia, the filter with and without it; the tendon's speed in each
    ramp."""
    from tendonsense.forward import solve
    from tendonsense.simulation import simulate
    robot = robot_with(0.03)
    t, T, ramps = schedule()
    q0 = solve(robot, {"t1": LOW}, [(X, (0.0, 0.0, -WEIGHT))]).q
    for with_inertia in (False, True):
        sim = simulate(robot, {"t1": (t, T)}, [(X, (0.0, 0.0, -WEIGHT))], duration=t[-1],
                       output_dt=DT, q0=q0, inertia=with_inertia)
        moving = np.zeros(sim.time.shape, bool)
        for a, b in ramps:
            moving |= (sim.time > a) & (sim.time < b)
        y = sim.displacements["t1"]
        speeds = [abs(np.polyfit(sim.time[m], y[m], 1)[0]) * 1e3 for m in
                  ((sim.time > a) & (sim.time < b) for a, b in ramps)]
        for in_filter in (False, True):
            est = estimates(robot, sim.readings(), True, inertia=in_filter)
            err = 100 * np.abs(est - WEIGHT) / WEIGHT
            print(f"simulated with inertia={with_inertia}, filter with inertia={in_filter}: "
                  f"mean abs error while moving {err[moving].mean():.3f} %", flush=True)
        print(f"t1's speed per ramp {', '.join(f'{v:.1f}' for v in speeds)} mm/s", flush=True)


def latency(n):
    from tendonsense import load_robot
    from tendonsense.estimation import problem
    from tendonsense.filtering import MotionFilter
    from tendonsense.inputs import Noise, PointForceUnknown
    from tendonsense.simulation import simulate
    import sys
    sys.path.insert(0, str(Path(__file__).parent))
    from elements import ELEMENTS
    base = load_robot(ROBOT)
    for label, robot in (("15 coordinates", base),
                         ("elements basis", base.replace(**ELEMENTS))):
        tt = np.linspace(0.0, n * 1e-3, 50)
        T = 2.0 + 1.2 * np.sin(2 * np.pi * 0.2 * tt + 0.3)
        F = 0.2 + 0.1 * np.sin(2 * np.pi * 0.3 * tt)
        sim = simulate(robot, {"t1": (tt, T)}, [(0.25, (tt, np.stack([0 * F, 0 * F, -F], 1)))],
                       duration=n * 1e-3, output_dt=1e-3, inertia=False)
        cols = sim.readings(1e-4, 0.01, seed=0)
        f = MotionFilter(problem(robot, ["t1"], [PointForceUnknown(0.25, (0, 0, -1))]),
                         Noise(1e-4, 0.01))
        reads = [({"t1": cols["displacement_t1"][k]},
                  {name: cols[f"tension_{name}"][k] for name in robot.tendon_names},
                  cols["time"][k]) for k in range(len(cols["time"]))]
        f.update(*reads[0])
        lat, fails = [], 0
        for r in reads[1:]:
            t0 = time.perf_counter()
            e = f.update(*r)
            lat.append(time.perf_counter() - t0)
            fails += not e.converged
        print(f"update() with dynamics, {label} ({robot_nq(robot)} coordinates): p50 "
              f"{1e3 * np.median(lat):.3f} ms, p99 {1e3 * np.percentile(lat, 99):.3f} ms over "
              f"{len(lat)} samples, {fails} not converged", flush=True)


def robot_nq(robot):
    from tendonsense.forward import model_for
    return model_for(robot).nq


def simulate_time():
    from tendonsense import load_robot
    from tendonsense.simulation import simulate
    robot = load_robot(ROBOT)
    for inertia in (True, False):
        args = dict(duration=3.0, output_dt=1e-3, inertia=inertia)
        simulate(robot, {"t1": ([0, 1.5, 3.0], [1.9, 4.78, 1.9])}, **args)
        runs = []
        for _ in range(3):
            t0 = time.perf_counter()
            simulate(robot, {"t1": ([0, 1.5, 3.0], [1.9, 4.78, 1.9])}, **args)
            runs.append(time.perf_counter() - t0)
        print(f"simulate 3 s at 1 kHz output, inertia={inertia}: median "
              f"{np.median(runs):.2f} s warm (of 3)", flush=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--samples", type=int, default=10000)
    ap.add_argument("--part", default="all",
                    choices=("accuracy", "latency", "simulate", "inertia", "all"))
    args = ap.parse_args(argv)
    if args.part in ("latency", "all"):
        latency(args.samples)
    if args.part in ("simulate", "all"):
        simulate_time()
    if args.part in ("inertia", "all"):
        inertia()
    if args.part in ("accuracy", "all"):
        accuracy(args.seeds)


if __name__ == "__main__":
    main()
