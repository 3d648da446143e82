"""Live estimation (issue 9): the online estimator and streaming through the CLI."""

import csv
import io
import os
import subprocess
import sys
import time

import numpy as np
import pytest

from conftest import PROTOTYPE, ROOT
from tendonsense.estimation import PointForceUnknown, problem
from tendonsense.forward import solve
from tendonsense.online import OnlineEstimator
from tendonsense.settings import BLAS_THREADS


@pytest.fixture(scope="module")
def readings(prototype):
    F = np.linspace(0.1, 0.3, 12)
    T = np.linspace(1.5, 2.5, 12)
    y = [solve(prototype, {"t1": t}, [(0.25, (0, 0, -f))]).displacements["t1"]
         for f, t in zip(F, T)]
    return F, T, np.array(y)


def test_update_follows_the_readings_and_survives_bad_ones(prototype, readings):
    F, T, y = readings
    online = OnlineEstimator(problem(prototype, ["t1"], [PointForceUnknown(0.25, (0, 0, -1))]))
    bad = {3: (-5.0, T[3], "pulls in more"), 6: (y[6], -1.0, "negative"),
           8: (y[8], 1e6, "tensions are in newtons"), 9: (-0.1, T[9], "converge")}
    for k in range(len(F)):
        yk, Tk, why = bad.get(k, (y[k], T[k], None))
        t0 = time.perf_counter()
        est = online.update({"t1": yk}, {"t1": Tk})
        spent = time.perf_counter() - t0
        if why is None:
            assert est.converged, (k, est.note)
            assert est.magnitudes[0] == pytest.approx(F[k], rel=1e-8)
            assert 0 < est.sigma[0] < 0.05
        else:
            assert not est.converged and why in est.note
            assert np.isnan(est.magnitudes[0])
            assert spent < 1.0  # bounded work (the benchmark measures the milliseconds)


def test_a_fixed_rescue_budget_on_a_least_squares_stream_follows_the_file_log():
    """The first 200 rows of docs/motion.md's simulated log (three tendons measured, one
    force): with a fixed ``rescue_budget`` the stuck tendon's band ends not found are solved
    from the straight rod (a least-squares rescue was handed no readings: a TypeError at row
    136), and row 188, which the follower fails from its rescue's solution as well, is the
    rescue's estimate, as a file log keeps it (it was "did not converge within the work
    budget")."""
    from tendonsense import load_robot
    from tendonsense.logs import estimate_readings
    from tendonsense.readings import read_readings
    robot = load_robot(ROOT / "examples" / "paper_prototype_damped.toml")
    measured, samples = read_readings(ROOT / "tests" / "data" / "motion_rows_1_200.csv", robot)
    tip = [PointForceUnknown(0.25, (0, 0, -1))]
    online = OnlineEstimator(problem(robot, measured, tip), rescue_budget=200)
    kept, rescued = [], online._rescued  # (the rescue's estimate kept: row 188 only)
    online._rescued = lambda *a: kept.append(len(got)) or rescued(*a)
    got = []
    for s in samples:
        got.append(online.update(s.displacements, s.tensions))
    file = estimate_readings(robot, measured, samples, tip)
    assert all(e.converged for e in got) and all(e.converged for e in file)
    assert got[187].magnitudes[0] == pytest.approx(file[187].magnitudes[0], abs=1e-5)
    assert got[187].sliding == file[187].sliding == ("in", "in", "in")
    assert kept == [187]


def test_a_tension_the_material_cannot_take_is_refused(prototype):
    with pytest.raises(ValueError, match="would shorten the rod by more than half"):
        solve(prototype, {"t1": 40.0})  # E·A / 2 = 39.3 N at the tip
    assert solve(prototype, {"t1": 39.0}).converged
    with pytest.raises(ValueError, match="forces are in newtons"):  # 100 gF typed as N
        solve(prototype, {"t1": 2.0}, [(0.25, (0, 0, -100.0))])
    assert solve(prototype, {"t1": 2.0}, [(0.25, (0, 0, -38.0))]).converged


def stream(args, text):
    return subprocess.run([sys.executable, "-m", "tendonsense.cli", "estimate", str(PROTOTYPE),
                           "--readings", "-", *args], input=text, capture_output=True,
                          text=True, timeout=600)


def test_cli_streams_stdin_to_stdout(readings):
    F, T, y = readings
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["time", "tension_t1", "tension_t2", "tension_t3", "displacement_t1"])
    for k in range(len(F)):
        w.writerow([0.01 * k, T[k], 0, 0, "oops" if k == 4 else y[k]])
    p = stream(["--unknown", "0.25,0,0,-1"], buf.getvalue())
    assert p.returncode == 3, p.stderr  # row 5 was bad
    rows = list(csv.DictReader(io.StringIO(p.stdout)))
    assert len(rows) == len(F)
    for k, r in enumerate(rows):
        if k == 4:
            assert r["converged"] == "false" and "displacement_t1" in r["note"]
        else:
            assert r["converged"] == "true"
            assert float(r["magnitude_1"]) == pytest.approx(F[k], rel=1e-6)


def test_a_stream_cut_within_its_last_row_skips_that_row(readings):
    """A stream that ends within a row (the writer killed mid-line: ``0.0039`` cut to
    ``0.00``) skipped that row as a cut reading; it was estimated as a whole one (a force far
    from the true one, exit 0). A row with its line break is estimated as before."""
    F, T, y = readings
    text = "time,tension_t1,tension_t2,tension_t3,displacement_t1\n" + "".join(
        f"{0.01 * k},{float(T[k])!r},0,0,{float(y[k])!r}\n" for k in range(3))
    cut = text[:-1 - len(repr(float(y[2]))) + 4]  # the last displacement's first digits
    whole = stream(["--unknown", "0.25,0,0,-1"], text)
    p = stream(["--unknown", "0.25,0,0,-1"], cut)
    assert whole.returncode == 0 and p.returncode == 3, p.stderr
    rows = list(csv.DictReader(io.StringIO(p.stdout)))
    assert [r["converged"] for r in rows] == ["true", "true", "false"]
    assert "the input ended within this row" in rows[2]["note"]
    assert "row 3 skipped: the input ended within this row" in p.stderr
    assert whole.stdout.splitlines()[:3] == p.stdout.splitlines()[:3]


def test_cli_stream_stops_on_a_column_in_the_wrong_unit(readings, tmp_path):
    """A stream whose lengths are in mm (the readings' × 1000) stops after its first rows say
    so, as a file is refused: one line, exit 1, no output file (before, each row was skipped
    in a line of its own and the rows that passed were estimated as metres, some "converged");
    skipped rows are named up to 20, the rest counted, as a file's."""
    F, T, y = readings
    header = "time,tension_t1,tension_t2,tension_t3,displacement_t1\n"
    mm = header + "".join(f"{0.01 * k},{T[k]},0,0,{1000 * y[k]}\n" for k in range(len(F)))
    p = stream(["--unknown", "0.25,0,0,-1", "-o", tmp_path / "o.csv"], mm)
    assert p.returncode == 1 and "lengths are in metres" in p.stderr, p.stderr
    assert "its first 3 rows" in p.stderr and len(p.stderr.strip().splitlines()) <= 4
    assert not (tmp_path / "o.csv").exists()
    bad = header + "".join(f"{0.01 * k},{T[0]},0,0,oops\n" for k in range(25))
    p = stream(["--unknown", "0.25,0,0,-1"], bad + f"0.25,{T[0]},0,0,{y[0]}\n")
    lines = p.stderr.strip().splitlines()
    assert sum("skipped: " in line for line in lines) == 20, p.stderr
    assert "5 more rows skipped" in p.stderr and p.returncode == 3


def test_cli_stream_flushes_each_row_before_the_next_arrives(readings):
    """Each answer is on stdout while the input is still open."""
    F, T, y = readings
    proc = subprocess.Popen([sys.executable, "-m", "tendonsense.cli", "estimate",
                             str(PROTOTYPE), "--readings", "-", "--unknown", "0.25,0,0,-1"],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, bufsize=1)
    try:
        proc.stdin.write("time,tension_t1,tension_t2,tension_t3,displacement_t1\n")
        proc.stdin.flush()
        assert proc.stdout.readline().startswith("row,time,magnitude_1")
        for k in range(3):
            proc.stdin.write(f"{k},{float(T[k])!r},0,0,{float(y[k])!r}\n")
            proc.stdin.flush()
            row = proc.stdout.readline().split(",")
            assert row[0] == str(k + 1) and float(row[2]) == pytest.approx(F[k], rel=1e-6)
        proc.stdin.close()
        assert proc.wait(timeout=60) == 0
    finally:
        proc.kill()


def test_overdetermined_exact_samples_are_all_converged(prototype):
    """Three tendons read, one unknown force (least squares, eq. 17): exact, consistent
    readings must never be marked as failed."""
    from tendonsense.tracking import solve_batch
    names = prototype.tendon_names
    n = 40
    T = np.tile([1.0, 0.5, 0.7], (n, 1)) * np.linspace(1, 2, n)[:, None]
    f = np.linspace(0.1, 0.3, n)
    truth = solve_batch(prototype, T, [(0.25, np.stack([0 * f, 0 * f, -f], axis=1))])
    online = OnlineEstimator(problem(prototype, list(names),
                                     [PointForceUnknown(0.25, (0, 0, -1))]))
    for k in range(n):
        est = online.update({t: truth.displacements[t][k] for t in names}, dict(zip(names, T[k])))
        assert est.converged, k
        assert est.magnitudes[0] == pytest.approx(f[k], rel=1e-7)


PINNED = """
import os, threading, jax.numpy as jnp
(jnp.ones(3) + 1).block_until_ready()  # XLA's thread pool exists now
from tendonsense.settings import pin, unpinned
def on(cores):
    return sorted({frozenset(os.sched_getaffinity(int(t))) == cores
                   for t in os.listdir("/proc/self/task")})
before = os.sched_getaffinity(0)
core = max(before)
pin({core})
print(on({core}))
with unpinned():  # as while compiling
    print(on(before))
    made = threading.Event()
    threading.Thread(target=made.wait).start()
print(on({core}))
made.set()
try:
    pin({os.cpu_count()})
except ValueError as exc:
    print(exc)
"""


@pytest.mark.skipif(not hasattr(os, "sched_getaffinity")
                    or len(os.sched_getaffinity(0)) < 2, reason="Linux, 2 cores or more")
def test_pin_keeps_every_thread_on_the_core():
    """A live estimator pinned to one core: XLA's pool threads move too (the calling thread
    alone is what ``os.sched_setaffinity(0, …)`` moves); while a program compiles, every
    thread runs on the cores the process had, and after it, also one made meanwhile, on the
    core again; a core the machine lacks is named."""
    out = subprocess.run([sys.executable, "-c", PINNED], capture_output=True, text=True,
                         check=True).stdout.splitlines()
    assert out[:3] == ["[True]"] * 3
    assert out[3] == f"cores [{os.cpu_count()}]: this machine's cores are 0 to {os.cpu_count() - 1}"


BLAS = """
import os, numpy  # numpy first, as in a notebook: SciPy's OpenBLAS (JAX's LU) loads later
import tendonsense, jax.numpy as jnp
(jnp.ones(3) + 1).block_until_ready()  # XLA's thread pools exist now
before = len(os.listdir("/proc/self/task"))
jnp.linalg.solve(jnp.eye(300) * 2.0, jnp.ones(300)).block_until_ready()
print(os.environ.get("OPENBLAS_NUM_THREADS"), len(os.listdir("/proc/self/task")) - before)
"""


@pytest.mark.skipif(not hasattr(os, "sched_getaffinity")
                    or len(os.sched_getaffinity(0)) < 2, reason="Linux, 2 cores or more")
def test_blas_runs_on_the_callers_thread_unless_told():
    """JAX's LU calls SciPy's OpenBLAS, whose threads spin between calls and take a core from
    a live estimator: importing tendonsense sets ``OPENBLAS_NUM_THREADS=1`` unless the user
    has set it (or ``OMP_NUM_THREADS``); the first solve then starts fewer threads than with
    the user's 2."""
    env = {k: v for k, v in os.environ.items() if k not in BLAS_THREADS}
    runs = [subprocess.run([sys.executable, "-c", BLAS], capture_output=True, text=True,
                           check=True, env=e).stdout.split()
            for e in (env, {**env, "OPENBLAS_NUM_THREADS": "2"}, {**env, "OMP_NUM_THREADS": "2"})]
    assert [r[0] for r in runs] == ["1", "2", "None"]
    assert int(runs[1][1]) > int(runs[0][1]) and int(runs[2][1]) > int(runs[0][1])


@pytest.mark.skipif(not hasattr(os, "sched_getaffinity")
                    or len(os.sched_getaffinity(0)) < 2, reason="Linux, 2 cores or more")
def test_cli_stream_pinned_to_a_core(readings):
    """``--cpu CORE``: the live stream's every thread (XLA's included) runs on that core, the
    answers are the same; a core the machine lacks, or --cpu on a file log, is refused."""
    F, T, y = readings
    core = max(os.sched_getaffinity(0))
    proc = subprocess.Popen([sys.executable, "-m", "tendonsense.cli", "estimate",
                             str(PROTOTYPE), "--readings", "-", "--unknown", "0.25,0,0,-1",
                             "--cpu", str(core)],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, bufsize=1)
    try:
        proc.stdin.write("time,tension_t1,tension_t2,tension_t3,displacement_t1\n")
        proc.stdin.flush()
        proc.stdout.readline()
        proc.stdin.write(f"0,{float(T[0])!r},0,0,{float(y[0])!r}\n")
        proc.stdin.flush()
        row = proc.stdout.readline().split(",")
        assert float(row[2]) == pytest.approx(F[0], rel=1e-6)
        tasks = os.listdir(f"/proc/{proc.pid}/task")
        assert len(tasks) > 1
        assert {frozenset(os.sched_getaffinity(int(t))) for t in tasks} == {frozenset({core})}
        proc.stdin.close()
        assert proc.wait(timeout=60) == 0
    finally:
        proc.kill()
    p = stream(["--unknown", "0.25,0,0,-1", "--cpu", str(os.cpu_count())], "")
    assert p.returncode == 1 and f"core {os.cpu_count()}: this machine's cores" in p.stderr
    p = subprocess.run([sys.executable, "-m", "tendonsense.cli", "estimate", str(PROTOTYPE),
                        "--readings", "x.csv", "--unknown", "0.25,0,0,-1", "--cpu", "0"],
                       capture_output=True, text=True, timeout=600)
    assert p.returncode == 2 and "--cpu goes with a live log" in p.stderr
