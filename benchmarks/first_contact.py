"""First contact (issue 24): how long a new user waits. Each figure is the median of
``--rounds`` runs of a new process, wall and CPU (user + system, children included).

- ``--help`` and a robot-file error (no JAX);
- a first ``solve`` and a first ``estimate --readings`` on an empty cache;
- warm start-up beyond ``import jax`` of ``solve``, ``estimate`` and ``estimate --readings``;
- the first streamed row's latency, the process started 8 s before the row arrives;
- a file log per sample past start-up through the CLI (2,000 rows less 200 rows), square and
  overdetermined (three measured tendons, one unknown).

``--code DIR`` runs another checkout's ``src`` (e.g. a ``git worktree`` of an older commit),
so that old and new are measured in one run::

    python benchmarks/first_contact.py --rounds 3
    python benchmarks/first_contact.py --rounds 3 --code /tmp/old
"""

from __future__ import annotations

import argparse
import csv
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
ROBOT = ROOT / "examples" / "paper_prototype.toml"


def run(cmd, env, stdin=None) -> tuple[float, float]:
    """(wall, CPU) seconds of a command."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(cmd, env=env, input=stdin, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def log_file(folder: Path, n: int, tendons=("t1",)) -> Path:
    """A log of ``n`` rows made by forward statics (t1 pulled 1 → 3 N, t2 and t3 slack or at
    0.3 N, a tip weight 0–20 gF), with read-out noise: its ``tendons`` measured."""
    from tendonsense import load_robot
    from tendonsense.tracking import solve_batch
    robot = load_robot(ROBOT)
    rng = np.random.default_rng(0)
    s = np.arange(n) / n
    T1 = 2.0 - np.cos(2 * np.pi * s)
    other = np.full(n, 0.3 if len(tendons) == 3 else 0.0)
    F = np.stack([0 * s, 0 * s, -0.2 * s], axis=1)
    out = solve_batch(robot, {"t1": T1, "t2": other, "t3": other}, [(0.25, F)])
    path = folder / f"log_{n}_{len(tendons)}.csv"
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["time", "tension_t1", "tension_t2", "tension_t3"]
                   + [f"displacement_{t}" for t in tendons])
        for k in range(n):
            y = [out.displacements[t][k] + rng.normal(0, 1e-4) for t in tendons]
            w.writerow([k * 0.01, T1[k], other[k], other[k], *y])
    return path


def first_row_latency(tool, env, wait: float) -> float:
    """Seconds from a row's arrival to its answer, the process started ``wait`` s before."""
    proc = subprocess.Popen(tool + ["estimate", str(ROBOT), "--readings", "-", "--unknown",
                                    "0.25,0,0,-1"], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                            bufsize=1, env=env)
    proc.stdin.write("time,tension_t1,tension_t2,tension_t3,displacement_t1\n")
    proc.stdin.flush()
    time.sleep(wait)
    t0 = time.perf_counter()
    proc.stdin.write("0.0,2.0,0,0,-0.0032\n")
    proc.stdin.flush()
    while True:
        line = proc.stdout.readline()
        if not line or line.startswith("1,"):
            break
    latency = time.perf_counter() - t0
    proc.stdin.close()
    proc.wait(timeout=60)
    return latency


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--code", type=Path, default=ROOT, help="the checkout whose src/ to run")
    ap.add_argument("--skip-cold", action="store_true")
    args = ap.parse_args()
    tool = [sys.executable, "-m", "tendonsense.cli"]
    base = dict(os.environ, PYTHONPATH=str(args.code / "src"))
    tmp = Path(tempfile.mkdtemp())
    warm = dict(base, TENDONSENSE_CACHE_DIR=str(tmp / "warm"))
    logs = {n: log_file(tmp, n) for n in (200, 2000)}
    over = {n: log_file(tmp, n, ("t1", "t2", "t3")) for n in (200, 2000)}
    bad = tmp / "bad.toml"
    bad.write_text(ROBOT.read_text().replace("length = 0.25", "length = -0.25"))
    solve = ["solve", str(ROBOT), "--tension", "t1=2.0"]
    estimate = ["estimate", str(ROBOT), "--displacement", "t1=-0.005", "--tension", "t1=2.1",
                "--unknown", "0.25,0,0,-1"]

    def readings(log):
        return ["estimate", str(ROBOT), "--readings", str(log), "--unknown", "0.25,0,0,-1",
                "-o", str(tmp / "out.csv"), "--quiet"]

    cases = {"--help": lambda: run(tool + ["--help"], warm),
             "robot-file error": lambda: run(tool + ["solve", str(bad)], warm),
             "import jax": lambda: run([sys.executable, "-c", "import jax"], warm)}
    if not args.skip_cold:
        def cold(cmd):
            return lambda: run(tool + cmd, dict(base, TENDONSENSE_CACHE_DIR=tempfile.mkdtemp()))
        cases["first solve, empty cache"] = cold(solve)
        cases["first estimate --readings (200 rows), empty cache"] = cold(readings(logs[200]))
    for cmd in (solve, estimate, readings(logs[200]), readings(logs[2000]),
                readings(over[200]), readings(over[2000])):
        run(tool + cmd, warm)  # fill the cache
    first_row_latency(tool, warm, 0.0)
    cases.update({
        "solve, warm": lambda: run(tool + solve, warm),
        "estimate, warm": lambda: run(tool + estimate, warm),
        "estimate --readings 200 rows, warm": lambda: run(tool + readings(logs[200]), warm),
        "estimate --readings 2000 rows, warm": lambda: run(tool + readings(logs[2000]), warm),
        "overdetermined 200 rows, warm": lambda: run(tool + readings(over[200]), warm),
        "overdetermined 2000 rows, warm": lambda: run(tool + readings(over[2000]), warm),
        "first streamed row, warm (started 8 s before)":
            lambda: (first_row_latency(tool, warm, 8.0), float("nan")),
    })
    results = {k: [] for k in cases}
    for _ in range(args.rounds):
        for k, f in cases.items():
            results[k].append(f())
    med = {k: (statistics.median(w for w, _ in v), statistics.median(c for _, c in v))
           for k, v in results.items()}
    print(f"code: {args.code}; medians of {args.rounds} rounds (wall s / CPU s)")
    for k, (w, c) in med.items():
        print(f"  {k:<50} {w:7.3f} / {c:7.3f}")
    jax_wall = med["import jax"][0]
    for k in ("solve, warm", "estimate, warm", "estimate --readings 200 rows, warm"):
        print(f"  beyond import jax: {k:<40} {med[k][0] - jax_wall:+.3f} s")
    for what, a, b in (("square", "estimate --readings 200 rows, warm",
                        "estimate --readings 2000 rows, warm"),
                       ("overdetermined", "overdetermined 200 rows, warm",
                        "overdetermined 2000 rows, warm")):
        print(f"  file log past start-up, {what}: "
              f"{(med[b][0] - med[a][0]) / 1800 * 1e3:.3f} ms/sample")


if __name__ == "__main__":
    main()
