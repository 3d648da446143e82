"""Sweeps, Monte Carlo and many logs on Dask (issue 28), on a real LocalCluster of 2 worker
processes: the same numbers as this process, a bad log named and the rest written, a worker
killed mid-job, no process left behind."""

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import PROTOTYPE
from tendonsense import cli
from tendonsense.distributed import (cluster, estimate_batch, estimate_logs, solve_batch,
                                     task_chunks)
from tendonsense.inputs import PointForceUnknown
from tendonsense.tracking import solve_batch as solve_here

pytest.importorskip("distributed")
psutil = pytest.importorskip("psutil")

TIP = [PointForceUnknown(0.25, (0, 0, -1))]


@pytest.fixture(scope="module")
def client():
    with cluster(2) as c:
        yield c


def _batch(n, seed):
    rng = np.random.default_rng(seed)
    return ({"t1": rng.uniform(1.0, 3.0, n), "t3": rng.uniform(0.0, 1.0, n)},
            {"young_modulus": rng.normal(1e6, 5e4, n), "friction": rng.uniform(0.3, 0.5, n)})


def _same(a, b, robot):
    np.testing.assert_array_equal(a.converged, b.converged)
    np.testing.assert_allclose(a.q, b.q, rtol=0, atol=1e-12)
    for m in robot.marker_names:
        np.testing.assert_allclose(a.markers[m], b.markers[m], rtol=0, atol=1e-12)
    for t in robot.tendon_names:
        np.testing.assert_allclose(a.displacements[t], b.displacements[t], rtol=0, atol=1e-12)


def test_a_batch_on_the_cluster_is_the_batch_here(client, prototype):
    """Chunks on two workers, put back in order: the same numbers as the same chunks solved
    in this process, and the whole batch solved at once to the solver's tolerance."""
    T, values = _batch(700, 1)
    assert [c.size for c in task_chunks(700, 250)] == [234, 233, 233]
    done = []
    there = solve_batch(client, prototype, T, values=values, task_size=250,
                        progress=lambda d, n: done.append((d, n)))
    here = solve_batch(None, prototype, T, values=values, task_size=250)
    assert there.converged.all() and done[-1] == (3, 3)
    _same(there, here, prototype)
    whole = solve_here(prototype, T, values=values)
    for m in prototype.marker_names:
        np.testing.assert_allclose(there.markers[m], whole.markers[m], rtol=0, atol=1e-9)
    with pytest.raises(ValueError, match="t9: no such tendon"):
        solve_batch(client, prototype, {"t9": [1.0]})


def test_readings_estimated_on_the_cluster_as_here(client, prototype):
    """Independent readings in chunks on two workers: the same estimates as the same chunks
    here, and the forces that made the readings."""
    rng = np.random.default_rng(4)
    f, T, mu = rng.uniform(0.1, 0.3, 250), rng.uniform(1.5, 2.5, 250), rng.uniform(0.3, 0.5, 250)
    made = solve_here(prototype, {"t1": T}, [(0.25, np.stack([0 * f, 0 * f, -f], 1))],
                      values={"friction": mu})
    disp = [{"t1": y} for y in made.displacements["t1"]]
    ten = [{"t1": t} for t in T]
    args = (prototype, ["t1"], TIP, disp, ten)
    there = estimate_batch(client, *args, values={"friction": mu}, task_size=100)
    here = estimate_batch(None, *args, values={"friction": mu}, task_size=100)
    assert all(e.converged for e in there) and len(there) == 250
    np.testing.assert_allclose([e.magnitudes[0] for e in there], f, rtol=1e-6)
    for a, b in zip(there, here):
        np.testing.assert_allclose(a.magnitudes, b.magnitudes, rtol=0, atol=1e-12)
        np.testing.assert_allclose(a.sigma, b.sigma, rtol=0, atol=1e-12)
        np.testing.assert_allclose(a.markers["tip"], b.markers["tip"], rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match="t2: no such tendon|need at least"):
        estimate_batch(client, prototype, ["t1"], TIP * 2, disp, ten)


def test_a_worker_killed_mid_job(client, prototype):
    """A worker process killed by its PID while it solves a chunk: the chunk is run again
    and the result is the same."""
    T, values = _batch(1200, 2)
    pids = client.run(os.getpid)
    killed = []

    def kill_one(done, total):
        if killed:
            return
        busy = [w for w, keys in client.processing().items() if keys]
        if busy:
            os.kill(pids[busy[0]], signal.SIGKILL)
            killed.append(pids[busy[0]])

    there = solve_batch(client, prototype, T, values=values, task_size=150, progress=kill_one)
    assert killed and _gone(killed)
    _same(there, solve_batch(None, prototype, T, values=values, task_size=150), prototype)
    deadline = time.monotonic() + 60
    while len(client.scheduler_info()["workers"]) < 2 and time.monotonic() < deadline:
        time.sleep(0.2)


@pytest.fixture(scope="module")
def logs(prototype, tmp_path_factory):
    """Three logs of a tip force under t1, and the forces behind them."""
    folder = tmp_path_factory.mktemp("logs")
    forces = {}
    for k in range(3):
        f = np.linspace(0.1, 0.3, 40) + 0.02 * k
        T = np.full(f.size, 2.0 + 0.1 * k)
        out = solve_here(prototype, {"t1": T}, [(0.25, np.stack([0 * f, 0 * f, -f], 1))])
        rows = [[0.01 * i, T[i], 0.0, 0.0, out.displacements["t1"][i]] for i in range(f.size)]
        with open(folder / f"run{k}.csv", "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["time", "tension_t1", "tension_t2", "tension_t3", "displacement_t1"])
            w.writerows(rows)
        forces[f"run{k}.csv"] = f
    (folder / "broken.csv").write_text("time,tension_t1,displacement_t9\n0,1,0\n")
    return folder, forces


def test_many_logs_a_bad_one_named_the_others_written(client, prototype, logs, tmp_path):
    folder, forces = logs
    paths = sorted(folder.glob("*.csv"))
    there, here = tmp_path / "there", tmp_path / "here"
    there.mkdir()
    here.mkdir()
    out = estimate_logs(client, prototype, paths, there, TIP)
    local = estimate_logs(None, prototype, paths, here, TIP)
    assert [s.log for s in out] == [str(p) for p in paths]
    bad = [s for s in out if s.error]
    assert len(bad) == 1 and "broken.csv" in bad[0].error and "displacement_t9" in bad[0].error
    assert sorted(p.name for p in there.iterdir()) == sorted(forces)  # no temporary files
    for s, s_here in zip(out, local):
        assert (s.samples, s.converged, s.skipped, s.error) == (
            s_here.samples, s_here.converged, s_here.skipped, s_here.error)
    for name, f in forces.items():
        assert (there / name).read_text() == (here / name).read_text()
        rows = list(csv.DictReader(open(there / name)))
        assert [r["converged"] for r in rows] == ["true"] * f.size
        np.testing.assert_allclose([float(r["magnitude_1"]) for r in rows], f, rtol=1e-6)


def test_many_logs_checked_before_anything_is_sent(prototype, logs, tmp_path):
    folder, _ = logs
    paths = sorted(folder.glob("run*.csv"))
    with pytest.raises(ValueError, match="outside the rod"):
        estimate_logs(None, prototype, paths, tmp_path, [PointForceUnknown(0.4, (0, 0, -1))])
    with pytest.raises(ValueError, match="no such folder"):
        estimate_logs(None, prototype, paths, tmp_path / "missing", TIP)
    with pytest.raises(ValueError, match="would overwrite a log"):
        estimate_logs(None, prototype, paths, folder, TIP)
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "run0.csv").write_text("")
    with pytest.raises(ValueError, match="same output"):
        estimate_logs(None, prototype, [paths[0], tmp_path / "a" / "run0.csv"], tmp_path, TIP)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a"]


def test_the_command_line_on_many_logs(client, logs, tmp_path, capsys):
    folder, forces = logs
    out = tmp_path / "out"
    code = cli.main(["estimate", PROTOTYPE, "--readings", str(folder / "*.csv"), "--unknown",
                     "0.25,0,0,-1", "-o", f"{out}/", "--scheduler", client.scheduler.address,
                     "--json", "--quiet"])
    captured = capsys.readouterr()
    assert code == 1
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and "broken.csv" in err[0] and "displacement_t9" in err[0], err
    assert err[0].startswith(f"tendonsense estimate: error: {folder / 'broken.csv'}: "), err
    summary = json.loads(captured.out)
    assert summary["failed"] == [str(folder / "broken.csv")]
    assert summary["samples"] == sum(f.size for f in forces.values())
    assert summary["converged"] == summary["samples"]
    assert sorted(p.name for p in out.iterdir()) == sorted(forces)


def test_many_logs_that_all_fail_write_nothing(logs, tmp_path, capsys):
    """Every log refused: each named, "nothing written", and no empty folder left behind
    (it said "wrote into" the empty folder it had made)."""
    folder, _ = logs
    empty = tmp_path / "empty.csv"
    empty.write_text("time,tension_t1,displacement_t1\n")
    out = tmp_path / "out"
    code = cli.main(["estimate", PROTOTYPE, "--readings", str(folder / "broken.csv"),
                     str(empty), "--unknown", "0.25,0,0,-1", "-o", f"{out}/", "--quiet"])
    captured = capsys.readouterr()
    assert code == 1 and len(captured.err.strip().splitlines()) == 2, captured.err
    assert captured.out.strip().endswith("2 failed; nothing written"), captured.out
    assert not out.exists()
    out.mkdir()  # a folder of the user's own is kept
    assert cli.main(["estimate", PROTOTYPE, "--readings", str(folder / "broken.csv"),
                     str(empty), "--unknown", "0.25,0,0,-1", "-o", f"{out}/", "--quiet",
                     "--json"]) == 1
    assert json.loads(capsys.readouterr().out)["output"] == "" and out.is_dir()
    # one log named twice is a slip (it was estimated once, without a word); patterns that
    # overlap give each log once
    assert cli.main(["estimate", PROTOTYPE, "--readings", str(empty), str(empty), "--unknown",
                     "0.25,0,0,-1", "-o", f"{out}/"]) == 2
    assert capsys.readouterr().err.strip().endswith(f"--readings {empty} given twice")


def test_handing_logs_to_a_cluster_loads_no_solver(client, logs, tmp_path):
    """A process that only hands logs to a cluster never imports JAX: its start-up (half a
    second and more) is not on the job's path; the workers do the work."""
    folder, forces = logs
    argv = ["estimate", str(PROTOTYPE), "--readings", str(folder / "run*.csv"), "--unknown",
            "0.25,0,0,-1", "-o", f"{tmp_path}/", "--scheduler", client.scheduler.address,
            "--quiet"]
    run = subprocess.run([sys.executable, "-c", "import sys\nfrom tendonsense import cli\n"
                          f"code = cli.main({argv!r})\nprint(code, 'jax' in sys.modules)"],
                         capture_output=True, text=True, timeout=600)
    assert run.stdout.splitlines()[-1] == "0 False", run.stdout + run.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(forces)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="forked workers: Linux")
def test_workers_forked_from_a_process_without_jax(prototype, logs, tmp_path):
    """From a process of one thread that has not loaded JAX (one that hands logs over), the
    local workers are forked: they start with this process's modules and values; the logs
    come out as here, and the workers are gone after. Dask's config restored, a worker
    started again is spawned, as is every worker of a process that has loaded JAX."""
    folder, forces = logs
    there, here = tmp_path / "there", tmp_path / "here"
    there.mkdir()
    here.mkdir()
    paths = sorted(str(p) for p in folder.glob("run*.csv"))
    script = (
        "import os, sys\n"
        "import dask\n"
        "import tendonsense.distributed as d\n"
        "from tendonsense.inputs import PointForceUnknown\n"
        "from tendonsense.robot import load_robot\n"
        f"robot = load_robot({str(PROTOTYPE)!r})\n"
        "d.NONCE = 12345\n"
        "def nonce():\n"
        "    import tendonsense.distributed as d\n"
        "    return getattr(d, 'NONCE', None)\n"
        "with d.cluster(2) as c:\n"
        "    forked = sorted(c.run(nonce).values(), key=str)\n"
        "    method = dask.config.get(d.START_METHOD)\n"
        "    pids = sorted(c.run(os.getpid).values())\n"
        f"    done = d.estimate_logs(c, robot, {paths!r}, {str(there)!r},\n"
        "                           [PointForceUnknown(0.25, (0, 0, -1))])\n"
        "import jax\n"
        "with d.cluster(2) as c:\n"
        "    spawned = sorted(c.run(nonce).values(), key=str)\n"
        "print(forked, method, [s.error for s in done], spawned, 'pids', *pids)\n")
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         timeout=600)
    assert run.returncode == 0, run.stderr
    result, pids = run.stdout.splitlines()[-1].split(" pids ")
    assert result == "[12345, 12345] spawn [None, None, None] [None, None]"
    assert _gone([int(p) for p in pids.split()])
    estimate_logs(None, prototype, [Path(p) for p in paths], here, TIP)
    for name in forces:
        assert (there / name).read_text() == (here / name).read_text()


@pytest.mark.parametrize("argv, message", [
    (["{logs}/*.csv"], "need -o OUTDIR/"),
    (["{logs}/*.csv", "-o", "{out}/", "--workers", "0"], "--workers 0"),
    (["{logs}/*.csv", "-o", "{out}/", "--workers", "2", "--scheduler", "tcp://127.0.0.1:1"],
     "not both"),
    (["{out}/nothing/*.csv", "-o", "{out}/"], "no file matches"),
    (["{logs}/run0.csv", "-o", "{out}/run0.csv", "--workers", "2"], "--workers goes with"),
    (["{logs}/*.csv", "-o", "{out}/a/b/"], "no folder"),
])
def test_the_command_line_checks_before_starting_a_cluster(argv, message, logs, tmp_path,
                                                           capsys):
    args = [a.format(logs=logs[0], out=tmp_path) for a in argv]
    code = cli.main(["estimate", PROTOTYPE, "--unknown", "0.25,0,0,-1", "--quiet",
                     "--readings", *args])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == (1 if message in ("no folder", "no file matches", "--workers 0") else 2), err
    assert len(err) == 1 and message in err[0], err
    assert list(tmp_path.iterdir()) == []


def test_no_output_folder_without_a_cluster(logs, tmp_path, capsys):
    """A scheduler that cannot be reached: one line, exit 1, no OUTDIR made."""
    code = cli.main(["estimate", PROTOTYPE, "--unknown", "0.25,0,0,-1", "--quiet", "--readings",
                     str(logs[0] / "*.csv"), "-o", f"{tmp_path}/out/", "--scheduler",
                     "tcp://127.0.0.1:9"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1 and "cannot connect" in err[0], err
    assert list(tmp_path.iterdir()) == []


def _gone(pids, wait=10.0) -> bool:
    """Whether every process ``pids`` has ended (and been reaped) within ``wait`` s."""
    deadline = time.monotonic() + wait
    while time.monotonic() < deadline:
        if not any(psutil.pid_exists(p) for p in pids):
            return True
        time.sleep(0.1)
    return False


def _profiling(dask_worker):
    return "profile" in dask_worker.periodic_callbacks


def _cores():
    return set().union(*(os.sched_getaffinity(int(t)) for t in os.listdir("/proc/self/task")))


def test_a_cluster_closes_with_its_processes():
    with cluster(2) as c:
        pids = list(c.run(os.getpid).values())
        assert len(pids) == 2 and all(psutil.pid_exists(p) for p in pids)
        # the local workers run without Dask's stack sampler (a fifth of a task's time)
        assert not any(c.run(_profiling).values())
        # and each on a core of its own, every thread of it (XLA's pool too)
        if len(os.sched_getaffinity(0)) >= 2:
            cores = c.run(_cores)
            assert sorted(map(len, cores.values())) == [1, 1]
            assert len(set().union(*cores.values())) == 2
    assert _gone(pids)
    assert not [p for p in psutil.Process().children(recursive=True) if p.pid in pids]


def _sets(path, n, seed):
    rng = np.random.default_rng(seed)
    E, mu, T = rng.normal(1e6, 5e4, n), rng.uniform(0.2, 0.5, n), rng.uniform(1.0, 3.0, n)
    f = rng.uniform(0.0, 0.3, n)
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["id", "tension_t1", "young_modulus", "friction_t1", "load_X", "load_fx",
                    "load_fy", "load_fz"])
        w.writerows([[f"s{k}", T[k], E[k], mu[k], 0.25, 0, 0, -f[k]] for k in range(n)])
    return E, mu, T, f


@pytest.mark.parametrize("where", ["here", "cluster"])
def test_a_sweep_of_paid_out_tendons(where, client, prototype, tmp_path, capsys):
    """sweep --sliding t1=out: every set solved with t1 paid out, as solve --sliding t1=out
    (a sweep had no friction direction: a sliding_t1 column was refused, no option)."""
    from tendonsense.forward import solve
    E, mu, T, f = _sets(tmp_path / "sets.csv", 12, 7)
    out = tmp_path / "results.csv"
    extra = ["--scheduler", client.scheduler.address, "--task-size", "5"] \
        if where == "cluster" else []
    code = cli.main(["sweep", PROTOTYPE, tmp_path / "sets.csv", "-o", out, "--json", "--quiet",
                     "--sliding", "t1=out", *extra])
    assert code == 0 and json.loads(capsys.readouterr().out)["converged"] == 12
    rows = list(csv.DictReader(open(out)))
    assert {r["sliding_t1"] for r in rows} == {"out"}  # the results say how they were made
    for k in (0, 5, 11):
        robot = prototype.with_parameters(young_modulus=E[k], friction={"t1": mu[k]})
        loads = [(0.25, (0, 0, -f[k]))]
        paid = solve(robot, {"t1": T[k]}, loads, sliding={"t1": "out"})
        assert float(rows[k]["displacement_t1"]) == pytest.approx(
            paid.displacements["t1"], rel=1e-9)
        pulled = solve(robot, {"t1": T[k]}, loads).displacements["t1"]
        assert abs(float(rows[k]["displacement_t1"]) - pulled) > 1e-3
    with pytest.raises(ValueError, match="sliding t1=stuck"):
        solve_here(prototype, {"t1": T}, sliding={"t1": "stuck"})
    assert cli.main(["sweep", PROTOTYPE, tmp_path / "sets.csv", "-o", tmp_path / "r2.csv",
                     "--sliding", "t1=stuck"]) == 1  # a value refused: bad input
    assert not (tmp_path / "r2.csv").exists()


@pytest.mark.parametrize("where", ["here", "cluster"])
def test_a_sweep_writes_one_row_per_set(where, client, prototype, tmp_path, capsys):
    from tendonsense.forward import solve
    E, mu, T, f = _sets(tmp_path / "sets.csv", 300, 5)
    out = tmp_path / "results.csv"
    extra = ["--scheduler", client.scheduler.address, "--task-size", "120"] \
        if where == "cluster" else []
    code = cli.main(["sweep", PROTOTYPE, tmp_path / "sets.csv", "-o", out, "--json", "--quiet",
                     *extra])
    assert code == 0 and json.loads(capsys.readouterr().out)["converged"] == 300
    rows = list(csv.DictReader(open(out)))
    assert [r["id"] for r in rows] == [f"s{k}" for k in range(300)]
    values = {"young_modulus": E, "friction": np.stack([mu, 0.4 + 0 * mu, 0.4 + 0 * mu], 1)}
    T3 = np.stack([T, 0 * T, 0 * T], 1)
    loads = [(np.full(300, 0.25), np.stack([0 * f, 0 * f, -f], 1))]
    expected = (solve_batch(None, prototype, T3, loads, values, task_size=120)
                if where == "cluster" else solve_here(prototype, T3, loads, values))
    for k, r in enumerate(rows):
        assert r["converged"] == "true"
        tip = [float(r[f"marker_tip_{a}"]) for a in "xyz"]
        np.testing.assert_allclose(tip, expected.markers["tip"][k], rtol=0, atol=1e-12)
        assert float(r["displacement_t1"]) == pytest.approx(expected.displacements["t1"][k],
                                                             rel=0, abs=1e-12)
    k = 17
    one = solve(prototype.with_parameters(young_modulus=E[k], friction={"t1": mu[k]}),
                {"t1": T[k]}, [(0.25, (0, 0, -f[k]))])
    np.testing.assert_allclose([float(rows[k][f"marker_tip_{a}"]) for a in "xyz"],
                               one.markers["tip"], rtol=0, atol=1e-9)


@pytest.mark.parametrize("where", ["here", "cluster"])
def test_a_sweep_marks_the_sets_at_unstable_equilibria(where, client, prototype, tmp_path,
                                                       capsys):
    """The prototype with 1.2 N hanging at its tip: at t1 = 10 N its planar shape is one the
    rod leaves (test_dynamics), at 3 N not — the sweep says so as solve does (column
    unstable, the note, a count; a sweep said converged without a word); --skip-stability
    leaves the column blank; --settle gives the state it comes to rest in."""
    from tendonsense.forward import solve
    (tmp_path / "sets.csv").write_text("id,tension_t1,load_X,load_fx,load_fy,load_fz\n"
                                       "a,3.0,0.25,0,0,-1.2\nb,10.0,0.25,0,0,-1.2\n")
    extra = ["--scheduler", client.scheduler.address] if where == "cluster" else []
    out = tmp_path / "results.csv"
    code = cli.main(["sweep", PROTOTYPE, tmp_path / "sets.csv", "-o", out, "--json",
                     "--quiet", *extra])
    assert code == 0 and json.loads(capsys.readouterr().out)["unstable"] == 1
    rows = list(csv.DictReader(open(out)))
    assert [(r["converged"], r["unstable"]) for r in rows] == [("true", "false"),
                                                               ("true", "true")]
    said = solve(prototype, {"t1": 10.0}, [(0.25, (0, 0, -1.2))]).extra["note"]
    assert rows[1]["solver_note"].startswith("unstable equilibrium")
    assert float(rows[1]["solver_note"].split("stiffness ratio ")[1].split(";")[0]) == \
        pytest.approx(float(said.split("stiffness ratio ")[1].split(";")[0]), rel=1e-3)
    assert rows[0]["solver_note"] == ""
    assert cli.main(["sweep", PROTOTYPE, tmp_path / "sets.csv", "-o", out, "--quiet",
                     *extra]) == 0
    assert "1 of them at unstable equilibria" in capsys.readouterr().out
    assert cli.main(["sweep", PROTOTYPE, tmp_path / "sets.csv", "-o", out, "--json",
                     "--quiet", "--skip-stability", *extra]) == 0
    assert json.loads(capsys.readouterr().out)["unstable"] is None
    assert {r["unstable"] for r in csv.DictReader(open(out))} == {""}
    # --settle: the unstable set is the state the rod comes to rest in, as solve --settle
    assert cli.main(["sweep", PROTOTYPE, tmp_path / "sets.csv", "-o", out, "--json",
                     "--quiet", "--settle", *extra]) == 0
    assert json.loads(capsys.readouterr().out) | {"output": ""} == {
        "sets": 2, "converged": 2, "unstable": 0, "settled": 1, "output": ""}
    rows = list(csv.DictReader(open(out)))
    assert [(r["converged"], r["unstable"]) for r in rows] == [("true", "false")] * 2
    held = solve(prototype, {"t1": 10.0}, [(0.25, (0, 0, -1.2))], settle=True)
    assert rows[1]["solver_note"] == held.extra["note"] and rows[0]["solver_note"] == ""
    np.testing.assert_allclose([float(rows[1][f"marker_tip_{a}"]) for a in "xyz"],
                               held.markers["tip"], rtol=0, atol=1e-9)
    assert cli.main(["sweep", PROTOTYPE, tmp_path / "sets.csv", "-o", out, "--settle",
                     "--skip-stability", *extra]) == 2


def test_a_set_with_no_solution_is_marked_with_why(tmp_path, capsys):
    """38 N at the tip has no solution within 2 solver iterations a stage: its row says why,
    the others are solved and say nothing; exit status 3."""
    (tmp_path / "short.toml").write_text(PROTOTYPE.read_text()
                                         + "\n[solver]\nmax_iterations = 2\n")
    (tmp_path / "sets.csv").write_text("id,tension_t1,load_X,load_fx,load_fy,load_fz\n"
                                       "a,2.0,0.25,0,0,0\nb,2.0,0.25,0,0,-38\nc,3.0,0.25,0,0,0\n")
    code = cli.main(["sweep", tmp_path / "short.toml", tmp_path / "sets.csv", "-o",
                     tmp_path / "r.csv", "--quiet"])
    assert code == 3 and "2 converged" in capsys.readouterr().out
    rows = list(csv.DictReader(open(tmp_path / "r.csv")))
    assert [(r["id"], r["converged"]) for r in rows] == [("a", "true"), ("b", "false"),
                                                         ("c", "true")]
    assert rows[1]["solver_note"].startswith("the solver stopped after")
    assert rows[1]["marker_tip_x"] == "" and rows[0]["solver_note"] == rows[2]["solver_note"] == ""
    assert [r["unstable"] for r in rows] == ["false", "", "false"]  # not known where unsolved


def test_a_task_size_without_a_cluster_is_refused(tmp_path, capsys):
    (tmp_path / "sets.csv").write_text("tension_t1\n2.0\n")
    code = cli.main(["sweep", PROTOTYPE, tmp_path / "sets.csv", "-o", tmp_path / "r.csv",
                     "--task-size", "10"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "--task-size goes with --workers" in err[0], err
    assert not (tmp_path / "r.csv").exists()


def test_a_sets_tensions_are_bounded_by_its_own_modulus(tmp_path, capsys):
    """50 N is within half of E·A at the tip with the set's E = 2 MPa (78.5 N), 30 N is not with
    0.1 MPa (3.9 N): refused by the set's number, though under the robot file's 39 N."""
    (tmp_path / "sets.csv").write_text("tension_t1,young_modulus\n50,2e6\n30,1e5\n")
    code = cli.main(["sweep", PROTOTYPE, tmp_path / "sets.csv", "-o", tmp_path / "r.csv"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1, err
    assert "set 2: tension t1 = 30 N would shorten the rod" in err[0] and "7.85 N" in err[0]


@pytest.mark.parametrize("column,good,value,why", [
    ("young_modulus", "1e6", "-5", "must be > 0"), ("young_modulus", "1e6", "2.5", "is in Pa"),
    ("density", "10", "1.34", "in kg/m³"), ("friction_t1", "0", "-0.1", "must be >= 0"),
    ("friction", "2", "40", "not a percentage")])
def test_a_bad_parameter_set_is_named_and_nothing_written(tmp_path, capsys, column, good, value,
                                                          why):
    (tmp_path / "sets.csv").write_text(f"tension_t1,{column}\n2.0,{good}\n2.0,{value}\n")
    code = cli.main(["sweep", PROTOTYPE, tmp_path / "sets.csv", "-o", tmp_path / "r.csv"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1 and f"set 2: {column}: " in err[0] and why in err[0]
    assert not (tmp_path / "r.csv").exists()
