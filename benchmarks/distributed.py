"""Past one machine (issue 28): many logs and a Monte Carlo on a local Dask cluster against
one process.

    python benchmarks/distributed.py [--part logs|montecarlo|all] [--logs 20] [--samples 2000]
                                     [--solves 100000] [--workers 2]

Each run is a fresh Python process timed from its start to the end of its first job: the
one process (the logs one after another; the Monte Carlo's chunks one after another, and also
``tracking.solve_batch`` on its two threads), and the cluster (a LocalCluster of ``--workers``
processes started, every worker loading or compiling its programs once, the job). The same
job is then run again, warm, and timed alone; the cluster's shut-down is in neither. The
program cache is ``TENDONSENSE_CACHE_DIR`` as set (a fresh folder measures the
compiles as well). Scheduling overhead: the gaps between the tasks on each worker (Dask's task
stream) over the time the tasks took.
"""

from __future__ import annotations

import argparse
import csv
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

# this file's folder on the path would stand for the package distributed (Dask's)
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]

ROOT = Path(__file__).resolve().parents[1]
PROTOTYPE = ROOT / "examples" / "paper_prototype.toml"
TIP = "0.25,0,0,-1"


def make_logs(folder: Path, n_logs: int, samples: int):
    """``n_logs`` logs of a tip force and t1's tension changing over ``samples`` rows."""
    from tendonsense import load_robot
    from tendonsense.tracking import solve_batch
    robot = load_robot(PROTOTYPE)
    for k in range(n_logs):
        t = np.linspace(0, 1, samples)
        f = 0.2 + 0.1 * np.sin(2 * np.pi * (t + 0.05 * k))
        T = 2.0 + np.sin(2 * np.pi * t + 0.3 * k)
        out = solve_batch(robot, {"t1": T}, [(0.25, np.stack([0 * f, 0 * f, -f], 1))])
        with open(folder / f"log{k:02d}.csv", "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["time", "tension_t1", "tension_t2", "tension_t3", "displacement_t1"])
            w.writerows([[repr(float(t[i])), repr(float(T[i])), 0, 0,
                          repr(float(out.displacements["t1"][i]))]
                         for i in range(samples)])


def run_logs(folder: str, out: str, workers: int) -> dict:
    """One run: the logs in ``folder`` estimated into ``out`` (``workers`` 0: here)."""
    from contextlib import nullcontext

    from tendonsense import load_robot
    from tendonsense.distributed import cluster, estimate_logs
    from tendonsense.inputs import PointForceUnknown
    robot = load_robot(PROTOTYPE)
    logs = sorted(Path(folder).glob("*.csv"))
    with (cluster(workers) if workers else nullcontext()) as client:
        if client is not None:
            client.get_task_stream(start=time.time())
        times = []
        for _ in range(2):  # the second time warm: every program loaded, every worker up
            t = time.perf_counter()
            done = estimate_logs(client, robot, logs, out, [PointForceUnknown(0.25, (0, 0, -1))])
            times.append(time.perf_counter() - t)
        overhead = _overhead(client) if client is not None else None
    return {"samples": sum(s.samples for s in done), "converged": sum(s.converged for s in done),
            "failed": sum(bool(s.error) for s in done), "overhead": overhead, "times": times}


def run_montecarlo(n: int, workers: int) -> dict:
    """One run: ``n`` forward solves over E, μ and t1's tension (``workers`` 0: the same
    chunks here one after another; -1: ``tracking.solve_batch`` on two threads)."""
    from contextlib import nullcontext

    from tendonsense import load_robot
    from tendonsense.distributed import cluster, solve_batch
    from tendonsense.tracking import solve_batch as solve_here
    robot = load_robot(PROTOTYPE)
    rng = np.random.default_rng(0)
    T = {"t1": rng.uniform(1.0, 3.0, n)}
    values = {"young_modulus": rng.normal(1e6, 5e4, n), "friction": rng.uniform(0.3, 0.5, n)}
    with (cluster(workers) if workers > 0 else nullcontext()) as client:
        if client is not None:
            client.get_task_stream(start=time.time())
        times = []
        for _ in range(2):  # the second time warm
            t = time.perf_counter()
            out = (solve_here(robot, T, values=values) if workers < 0
                   else solve_batch(client, robot, T, values=values))
            times.append(time.perf_counter() - t)
        overhead = _overhead(client) if client is not None else None
    return {"converged": int(out.converged.sum()), "overhead": overhead, "times": times}


def _overhead(client) -> dict:
    """The gaps between tasks on each worker over the tasks' own time (Dask's task stream)."""
    spans: dict[str, list] = {}
    for task in client.get_task_stream():
        for part in task["startstops"]:
            if part["action"] == "compute":
                spans.setdefault(task["worker"], []).append((part["start"], part["stop"]))
    busy = sum(b - a for s in spans.values() for a, b in s)
    idle = sum(max(b for _, b in s) - min(a for a, _ in s) for s in spans.values()) - busy
    tasks = sum(len(s) for s in spans.values())
    return {"tasks": tasks, "task_s": busy / max(tasks, 1), "gaps_fraction": idle / busy}


def timed(*argv) -> tuple[float, dict]:
    """This script run as a fresh process with ``argv``: wall time and its JSON line."""
    t = time.perf_counter()
    p = subprocess.run([sys.executable, __file__, *map(str, argv)], capture_output=True,
                       text=True, check=True)
    return time.perf_counter() - t, json.loads(p.stdout.strip().splitlines()[-1])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--part", choices=("logs", "montecarlo", "all"), default="all")
    ap.add_argument("--logs", type=int, default=20)
    ap.add_argument("--samples", type=int, default=2000)
    ap.add_argument("--solves", type=int, default=100000)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--run", nargs="+", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.run:  # one timed run, in its own process
        kind, *rest = args.run
        result = (run_logs(rest[0], rest[1], int(rest[2])) if kind == "logs"
                  else run_montecarlo(int(rest[0]), int(rest[1])))
        print(json.dumps(result))
        return
    if args.part in ("logs", "all"):
        with tempfile.TemporaryDirectory() as tmp:
            folder = Path(tmp) / "logs"
            folder.mkdir()
            t = time.perf_counter()
            make_logs(folder, args.logs, args.samples)
            print(f"{args.logs} logs of {args.samples} samples made in "
                  f"{time.perf_counter() - t:.1f} s")
            rates = {}
            for workers in (0, args.workers):
                out = Path(tmp) / f"out{workers}"
                out.mkdir()
                wall, res = timed("--run", "logs", folder, out, workers)
                first, again = res["times"]
                wall -= again  # the process from its start to the end of the first job
                rates[workers] = (res["samples"] / wall, res["samples"] / again)
                where = f"{workers} workers" if workers else "one process"
                print(f"logs, {where}: {wall:.1f} s from the start ({first:.1f} s the job), "
                      f"{rates[workers][0]:.0f} samples/s; warm {again:.1f} s, "
                      f"{rates[workers][1]:.0f} samples/s "
                      f"({res['converged']} of {res['samples']} converged, {res['failed']} "
                      f"failed)" + (f"; {res['overhead']['tasks']} tasks of "
                                    f"{res['overhead']['task_s']:.2f} s, gaps between tasks "
                                    f"{100 * res['overhead']['gaps_fraction']:.1f} % of task "
                                    f"time" if res["overhead"] else ""))
            same = all((Path(tmp) / "out0" / p.name).read_bytes() == p.read_bytes()
                       for p in (Path(tmp) / f"out{args.workers}").iterdir())
            print(f"logs: {args.workers} workers / one process = "
                  f"{rates[args.workers][0] / rates[0][0]:.2f}x from the start, "
                  f"{rates[args.workers][1] / rates[0][1]:.2f}x warm; outputs identical: {same}")
    if args.part in ("montecarlo", "all"):
        rates = {}
        for workers in (0, -1, args.workers):
            wall, res = timed("--run", "montecarlo", args.solves, workers)
            first, again = res["times"]
            wall -= again
            rates[workers] = (args.solves / wall, args.solves / again)
            where = {0: "one process, one thread (the cluster's chunks)",
                     -1: "one process, tracking.solve_batch on two threads"}.get(
                         workers, f"{workers} workers")
            print(f"Monte Carlo, {where}: {wall:.1f} s from the start ({first:.1f} s the job), "
                  f"{rates[workers][0]:.0f} solves/s; warm {again:.1f} s, "
                  f"{rates[workers][1]:.0f} solves/s "
                  f"({res['converged']} converged)"
                  + (f"; {res['overhead']['tasks']} tasks of {res['overhead']['task_s']:.2f} "
                     f"s, gaps {100 * res['overhead']['gaps_fraction']:.1f} %"
                     if res["overhead"] else ""))
        w = args.workers
        print(f"Monte Carlo: {w} workers / one process = {rates[w][0] / rates[0][0]:.2f}x "
              f"from the start, {rates[w][1] / rates[0][1]:.2f}x warm (one thread); "
              f"{rates[w][0] / rates[-1][0]:.2f}x and {rates[w][1] / rates[-1][1]:.2f}x "
              f"(two threads)")


if __name__ == "__main__":
    main()
