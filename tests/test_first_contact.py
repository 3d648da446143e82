"""Trust at first contact (issue 24): one rule for every reading on every path, checks before
computing (JAX not started), a result that is not a solution never dressed as one, a
consistent command line."""

import csv
import json
import os
import subprocess
import sys
import time
import warnings

import numpy as np
import pytest

from conftest import PROTOTYPE, ROOT
from tendonsense import inputs, load_robot
from tendonsense.estimation import Noise, PointForceUnknown, estimate, problem
from tendonsense.forward import forward_kinematics, solve
from tendonsense.identification import Snapshot, SnapshotError, identify
from tendonsense.online import OnlineEstimator
from tendonsense.simulation import simulate
from tendonsense.tracking import estimate_series, solve_batch

TIP = PointForceUnknown(0.25, (0, 0, -1))


def cli(*args, cwd=None, stdin=None):
    return subprocess.run([sys.executable, "-m", "tendonsense.cli", *map(str, args)],
                          capture_output=True, text=True, timeout=600, cwd=cwd, input=stdin)


def refused_before_jax(*args, cwd=None) -> tuple[int, str, bool]:
    """(exit status, stderr, whether JAX was imported) of the CLI in a fresh interpreter, run
    in ``cwd``."""
    code = ("import sys, contextlib, io\nfrom tendonsense.cli import main\nerr = io.StringIO()\n"
            "with contextlib.redirect_stderr(err):\n    rc = main(sys.argv[1:])\n"
            "print(rc, 'jax' in sys.modules)\nprint(err.getvalue(), end='')\n")
    p = subprocess.run([sys.executable, "-c", code, *map(str, args)], capture_output=True,
                       text=True, timeout=120, cwd=cwd)
    assert p.stderr == "", p.stderr
    first, *err = p.stdout.splitlines()
    rc, jax_loaded = first.split()
    return int(rc), "\n".join(err), jax_loaded == "True"


# ------------------------------------------------------------------ the rules, on every path

READINGS_SLIPS = [  # (displacements, tensions, words the message must have)
    ({"t1": -0.005}, {}, "tension t1: missing"),
    ({"t1": -0.005}, {"t1": -2.1}, "tension t1 = -2.1 N is negative"),
    ({"t1": -0.005}, {"t1": 204.0}, "tensions are in newtons"),  # gram-force typed
    ({"t1": -5.0}, {"t1": 2.1}, "pulls in more than the tendon's whole length"),
    ({"t1": 0.3}, {"t1": 2.1}, "pays out more than the tendon's whole length"),
    ({"t1": float("nan")}, {"t1": 2.1}, "displacement t1"),
    ({"t1": -0.005}, {"t1": float("inf")}, "tension t1"),
    ({"t1": -0.005}, {"t1": 2.1, "t9": 1.0}, "tension t9: no such tendon"),
]


@pytest.mark.parametrize("y, T, words", READINGS_SLIPS)
def test_a_bad_reading_is_refused_by_the_python_api(prototype, y, T, words):
    with pytest.raises(ValueError, match=words.replace("(", r"\(")):
        inputs.readings(prototype, y, T)
    with pytest.raises(ValueError, match=words.split(":")[0].split(" =")[0]):
        estimate(prototype, y, T, [TIP])


@pytest.mark.parametrize("y, T, words", READINGS_SLIPS[:5])
def test_a_bad_reading_is_marked_by_the_online_estimator_and_a_series(prototype, y, T, words):
    online = OnlineEstimator(problem(prototype, ["t1"], [TIP]))
    est = online.update(y, T)
    assert not est.converged and words in est.note and np.isnan(est.magnitudes).all()
    good = solve(prototype, {"t1": 2.0}, [(0.25, (0, 0, -0.1))]).displacements["t1"]
    series = estimate_series(problem(prototype, ["t1"], [TIP]), [{"t1": good}, y],
                             [{"t1": 2.0}, T])
    assert series[0].converged and series[0].magnitudes[0] == pytest.approx(0.1, rel=1e-6)
    assert not series[1].converged and words in series[1].note


def test_a_series_checks_its_readings_as_one_reading_is_checked(prototype):
    # the rules on arrays (a series) against inputs.readings on each (one reading)
    prob = problem(prototype, ["t1"], [TIP])
    rows = [({"t1": -0.005}, {"t1": 2.1}), ({"t1": "-0.005"}, {"t1": " 2.1 "}),
            ({"t1": np.float32(-0.005)}, {"t1": np.float64(2.1), "t2": np.int64(0)}),
            ({"t1": -0.005}, {"t1": [2.1], "t2": [0.0], "t3": [0.0]}),
            ({"t1": np.array([-0.005]), "t2": np.array([0.0])}, {"t1": 2.1, "t2": 0.0}),
            ({"t1": -0.005}, {"t1": None}), ({}, {"t1": 2.1}), ({"t2": 0.0}, {"t2": 1.0}),
            ({"t1": -0.005}, {"t1": 2.1, "t9": 1.0}), ({"t1": -0.005}, {"t1": 40.0}),
            ({"t1": -0.005}, {"t1": True}), *((d, t) for d, t, _ in READINGS_SLIPS)]
    T, y, errors = prob.many_readings([d for d, _ in rows], [t for _, t in rows])
    for k, (d, t) in enumerate(rows):
        try:
            one = prob.readings(d, t)
        except ValueError as exc:
            assert errors.get(k) == str(exc), (d, t)
        else:
            assert k not in errors and np.array_equal(one, (T[k], y[k])), (d, t)
    assert {3, 4, 5, 6, 7} <= set(errors)  # sequences, None and missing lengths refused
    assert 0 not in errors and 1 not in errors and 2 not in errors
    assert errors[10] == "tension t1: not a number: True"  # (was 1 N)
    _, _, errors = prob.many_readings([{"t1": -0.005}] * 2, [{"t1": True}, {"t1": 2.1}])
    assert errors == {0: "tension t1: not a number: True"}
    # every value a sequence (numpy makes a table of them)
    _, _, errors = prob.many_readings([{"t1": -0.005}] * 2,
                                      [{"t1": [2.1], "t2": [0.0], "t3": [0.0]}] * 2)
    assert set(errors) == {0, 1} and "tension t1: not a number" in errors[0]
    _, _, errors = prob.many_readings([dict.fromkeys(("t1", "t2", "t3"), np.zeros(1))] * 2,
                                      [{"t1": 2.1, "t2": 0.0, "t3": 0.0}] * 2)
    assert set(errors) == {0, 1} and "displacement t1: not a number" in errors[0]
    with pytest.raises(ValueError, match="2 displacement and 3 tension readings"):
        prob.many_readings([d for d, _ in rows[:2]], [t for _, t in rows[:3]])


@pytest.mark.parametrize("call, words", [
    (lambda r: solve(r, [2.0]), "tensions: a mapping {tendon: value} such as {'t1': 2.0}, not a "
                                "list"),
    (lambda r: solve(r, {"t1": 2.0}, [0.25, 0, 0, -0.1]), "point force 1: a pair (X, (fx, fy, "
                                                          "fz)), got 0.25"),
    (lambda r: estimate(r, [-0.005], {"t1": 2.1}, [TIP]), "displacements: a mapping"),
    (lambda r: estimate(r, {"t1": -0.005}, {"t1": 2.1}, TIP), "unknowns: a list such as "
                                                              "[PointForceUnknown(…)], not a "
                                                              "PointForceUnknown"),
    (lambda r: problem(r, "t1", [TIP]), "measured tendons: a list such as ['t1'], not a str"),
    (lambda r: identify(r, [Snapshot(dict(t1=0.0), {"tip": np.zeros(3)})], "young_modulus"),
     "parameters to fit: a list such as ('young_modulus',), not a string"),
    (lambda r: Noise(length=-1e-4), "length noise: must be a positive number of metres"),
    (lambda r: Noise(length=float("nan")), "length noise"),
    (lambda r: Noise(tension=2.5), "tension noise: relative, must be a fraction under 1"),
    (lambda r: estimate(r, {"t1": -0.005}, {"t1": 2.1}, [TIP], noise=0.01), "noise: a Noise("),
    (lambda r: problem(r, iter(["t1"]), [TIP]), "not a list_iterator"),
    (lambda r: solve(r, {"t1": 2.0}, (0.25, (0, 0, -0.1))), "a list of pairs"),
    (lambda r: r.with_parameters(density=1.34), "density: 1.34 kg/m³ is lighter"),
    (lambda r: simulate(r, {"t1": 1.0}, duration=0.1, output_dt=0.2),
     "output_dt 0.2 s is longer than the duration 0.1 s"),
    (lambda r: problem(r, ["t1", "t1"], [TIP, PointForceUnknown(0.1, (0, 0, -1))]),
     "measured tendons: t1 listed twice"),
    (lambda r: solve_batch(r, {"t1": [1.0, 2.0, 3.0], "t2": [1.0, 2.0]}),
     "every tendon's tensions are one value or 3 (one a sample), got t2 (2)"),
    # a series or a batch: one {tendon: value} a sample or {tendon: (N,) values}, not a bare
    # array (it raised "'numpy.float64' object is not iterable", or took 2.0 for a tendon)
    (lambda r: estimate_series(problem(r, ["t1"], [TIP]), np.array([-4e-3, -5e-3]),
                               np.array([2.0, 2.1])),
     "displacements: one {tendon: value} a sample (a list of them) or {tendon: (N,) values}, "
     "not an array of shape (2,)"),
    (lambda r: estimate_series(problem(r, ["t1"], [TIP]), {"t1": -4e-3}, {"t1": 2.0}),
     "not one value a tendon (a single reading is estimate()'s)"),
    (lambda r: estimate_series(problem(r, ["t1"], [TIP]), {"t1": [-4e-3, -5e-3]},
                               {"t1": [2.0, 2.1, 2.2]}), "2 displacement and 3 tension readings"),
    (lambda r: solve_batch(r, {"t1": np.full((5, 1), 2.0)}),
     "batch: tension t1: one value or (N,) values (one a sample), not an array of shape (5, 1)"),
    (lambda r: solve_batch(r, np.full(5, 2.0)),
     "batch: tensions as an array are (N, 3), a column per tendon (t1, t2, t3), not of shape "
     "(5,)"),
    (lambda r: solve_batch(r, [{"t1": 2.0}, {"t1": float("nan")}]),
     "batch: sample 2: tension t1: must be finite"),
    (lambda r: solve_batch(r, []), "batch: no samples"),
    (lambda r: r.with_parameters(friction={"T1": 0.3}),
     "friction T1: no such tendon (robot has t1, t2, t3)"),
    (lambda r: Noise(tension=0.0), "tension noise: must be a positive fraction"),
])
def test_the_python_api_says_what_it_expected(prototype, call, words):
    """A value of the wrong kind is named with what was expected, not a Python internal
    (an AttributeError, "cannot unpack", "no such tendon t")."""
    with pytest.raises(ValueError) as e:
        call(prototype)
    assert words in str(e.value)


def test_forward_problems_refuse_a_pushing_tendon_and_an_impossible_length(prototype):
    with pytest.raises(ValueError, match="tension t1 = -2 N is negative"):
        solve(prototype, {"t1": -2.0})
    with pytest.raises(ValueError, match="pulls in more"):
        forward_kinematics(prototype, {"t1": -5.0})


def test_identify_refuses_a_negative_tension_in_a_snapshot(prototype):
    snap = Snapshot(dict(t1=-1.0, t2=0.0, t3=0.0), {"tip": np.zeros(3)})
    with pytest.raises(SnapshotError, match="snapshot 1: tension t1 = -1 N is negative"):
        identify(prototype, [snap], ("young_modulus",))


def test_a_file_says_every_tendons_tension(tmp_path):
    """A missing tension column is an error, never a slack tendon (log, stream, snapshots)."""
    log = tmp_path / "log.csv"
    log.write_text("time,tension_t1,displacement_t1\n0,2.0,-0.004\n")
    rc, err, jax_loaded = refused_before_jax("estimate", PROTOTYPE, "--readings", log,
                                             "--unknown", "0.25,0,0,-1", "-o", tmp_path / "o.csv")
    assert rc == 1 and "no column tension_t2, tension_t3" in err and "zeros" in err
    assert not jax_loaded and not (tmp_path / "o.csv").exists()
    p = cli("estimate", PROTOTYPE, "--readings", "-", "--unknown", "0.25,0,0,-1",
            stdin=log.read_text())
    assert p.returncode == 1 and "no column tension_t2" in p.stderr and p.stdout == ""
    snaps = tmp_path / "snaps.csv"
    snaps.write_text("tension_t2,tension_t3,marker_tip_x,marker_tip_y,marker_tip_z\n"
                     "0,0,0.24,0,-0.05\n")
    rc, err, jax_loaded = refused_before_jax("identify", PROTOTYPE, "--snapshots", snaps)
    assert rc == 1 and "no column tension_t1" in err and not jax_loaded


def test_snapshots_in_millimetres_are_refused(prototype, tmp_path):
    """Marker positions typed in mm: refused by the snapshot's row before JAX, and through the
    Python API (it ran 50 iterations to μ = 1.9e10)."""
    snaps = tmp_path / "snaps.csv"
    snaps.write_text("tension_t1,tension_t2,tension_t3,marker_tip_x,marker_tip_y,marker_tip_z\n"
                     "0,0,0,240,0,-50\n")
    rc, err, jax_loaded = refused_before_jax("identify", PROTOTYPE, "--snapshots", snaps)
    assert rc == 1 and not jax_loaded and len(err.strip().splitlines()) == 1, err
    assert "snapshot row 1: marker tip at 245 m from the base" in err and "metres" in err
    snap = Snapshot(dict(t1=0.0, t2=0.0, t3=0.0), {"tip": np.array([240.0, 0.0, -50.0])})
    with pytest.raises(SnapshotError, match="snapshot 1: marker tip at 245 m .* are in metres"):
        identify(prototype, [snap], ("young_modulus",))


def test_a_marker_noise_in_mm_and_a_parameter_twice_are_refused(prototype):
    """identify --marker-noise 0.5 (0.5 mm meant; it fitted E = 1.07e6 ± 2.2e6 Pa with a
    warning) and --param density twice (silently once): refused before JAX; the noise in
    Python too."""
    snaps = ROOT / "examples" / "tutorial" / "snapshots.csv"
    for args, status, why in ((["--marker-noise", "0.5"], 1, "--marker-noise 0.5 m is not under "
                                                            "a tenth of the rod's length"),
                              (["--param", "density", "--param", "density"], 2,
                               "--param density given twice")):  # usage, as any option twice
        rc, err, jax_loaded = refused_before_jax("identify", PROTOTYPE, "--snapshots", snaps,
                                                 *args)
        assert rc == status and why in err and not jax_loaded, err
    snap = Snapshot(dict(t1=0.0, t2=0.0, t3=0.0), {"tip": np.array([0.24, 0.0, -0.05])})
    with pytest.raises(ValueError, match="marker noise 0.5 m is not under a tenth"):
        identify(prototype, [snap], ("young_modulus",), marker_noise=0.5)


def test_a_simulation_far_past_its_loads_is_refused(prototype, tmp_path):
    """simulate --duration 3000 (3 s meant in ms) for a schedule that ends at 3 s ran 344 s
    into 300,001 rows: refused before JAX, and in Python; 63 s is still simulated."""
    ramp = ROOT / "examples" / "ramp_t1.csv"
    rc, err, jax_loaded = refused_before_jax("simulate", PROTOTYPE, "--tensions", ramp,
                                             "--duration", "3000", "-o", tmp_path / "m.csv")
    assert rc == 1 and not jax_loaded and "durations are in seconds" in err, err
    assert "runs 2997 s past the last change of the loads (at 3 s)" in err
    assert not (tmp_path / "m.csv").exists()
    # a table in ms whose last row holds its value: the loads last change at its ramp's end
    ms = tmp_path / "ms.csv"
    ms.write_text("time,tension_t1\n0,1.9\n500,1.9\n1500,4.78\n2000,4.78\n")
    rc, err, jax_loaded = refused_before_jax("simulate", PROTOTYPE, "--tensions", ms,
                                             "--duration", "2000", "-o", tmp_path / "m.csv")
    assert rc == 1 and not jax_loaded, err
    assert "runs 500 s past the last change of the loads (at 1500 s)" in err, err
    assert not (tmp_path / "m.csv").exists()
    with pytest.raises(ValueError, match="duration 61 s runs 61 s past"):
        simulate(prototype, {"t1": 2.0}, duration=61.0)
    with pytest.raises(ValueError, match=r"duration 100 s runs 99 s past .* \(at 1 s\)"):
        simulate(prototype, {"t1": ([0.0, 1.0, 100.0], [2.0, 3.0, 3.0])}, duration=100.0)
    from tendonsense.inputs import duration_error
    assert duration_error("duration", 63.0, 3.0) is None
    sim = simulate(prototype, {"t1": 2.0}, duration=0.02)
    for seed in (-1, 2.5, "3"):  # numpy's own message did not name the seed
        with pytest.raises(ValueError, match="seed: a whole number >= 0 or None"):
            sim.readings(1e-4, seed=seed)


def test_a_log_row_breaking_a_rule_is_marked_and_the_rest_estimated(prototype, tmp_path):
    y = solve(prototype, {"t1": 2.0}, [(0.25, (0, 0, -0.1))]).displacements["t1"]
    log = tmp_path / "log.csv"
    log.write_text("time,tension_t1,tension_t2,tension_t3,displacement_t1\n"
                   f"0,2.0,0,0,{y!r}\n0.1,2.0,0,0,-5\n0.2,-2.0,0,0,{y!r}\n0.3,2.0,0,0,{y!r}\n"
                   f"0.4,2.O,0,0,{y!r}\n0.5,,0,0,{y!r}\n0.6,2.0,0,0,nan\n")
    p = cli("estimate", PROTOTYPE, "--readings", log, "--unknown", "0.25,0,0,-1")
    assert p.returncode == 3
    rows = list(csv.DictReader(p.stdout.splitlines()))
    assert [r["converged"] for r in rows] == ["true", "false", "false", "true"] + ["false"] * 3
    assert "pulls in more" in rows[1]["note"] and "negative" in rows[2]["note"]
    assert float(rows[3]["magnitude_1"]) == pytest.approx(0.1, rel=1e-6)
    assert rows[4]["note"].endswith("column tension_t1: '2.O' is not a number")
    assert rows[5]["note"].endswith("column tension_t1: missing value")
    assert rows[6]["note"].endswith("column displacement_t1: 'nan' is not a finite number")


def test_output_files_are_readable_as_the_users_own(prototype, tmp_path):
    """Outputs are written atomically beside their place, with the permissions of a file the
    user makes (0o666 less the umask), not a temporary file's private ones."""
    from tendonsense.plotting import shape
    from tendonsense.readings import write_bytes_atomic, write_text_atomic
    old = os.umask(0o022)
    try:
        write_text_atomic(tmp_path / "rows.csv", "a,b\n")
        write_bytes_atomic(tmp_path / "raw.bin", b"\0")
        shape(solve(prototype, {"t1": 1.0}), tmp_path / "shape.png", prototype)
    finally:
        os.umask(old)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["raw.bin", "rows.csv", "shape.png"]
    assert all(p.stat().st_mode & 0o777 == 0o644 for p in tmp_path.iterdir())
    (tmp_path / "rows.csv").chmod(0o600)  # a file made private stays so when rewritten
    write_text_atomic(tmp_path / "rows.csv", "a,b\n1,2\n")
    assert (tmp_path / "rows.csv").stat().st_mode & 0o777 == 0o600


def test_an_output_into_a_named_pipe_or_device_is_written_into_it(tmp_path):
    """``-o`` onto a named pipe (or ``/dev/null``) writes into it: moved into place, the
    finished file replaced the pipe (as root, ``-o /dev/null`` replaced the device), and the
    program reading the pipe got nothing. The estimates of a log are read from the pipe."""
    import stat
    import threading

    from tendonsense.cli import main
    pipe = tmp_path / "pipe"
    os.mkfifo(pipe)
    got = []
    reader = threading.Thread(target=lambda: got.append(pipe.read_text()), daemon=True)
    reader.start()
    code = main(["estimate", str(PROTOTYPE), "--readings",
                 str(ROOT / "examples" / "tutorial" / "readings.csv"), "--unknown", "0.25,0,0,-1",
                 "-o", str(pipe), "--quiet"])
    reader.join(timeout=60)
    assert code == 0 and stat.S_ISFIFO(pipe.stat().st_mode)
    assert got and got[0].startswith("row,time,magnitude_1") and got[0].count("\n") == 301
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pipe"]  # no file left beside
    # a symbolic link is written through (it was replaced by a file: ``-o /dev/stdout``
    # sent to a file replaced /dev/stdout, as root)
    from tendonsense.readings import write_text_atomic
    (tmp_path / "real").mkdir()
    (tmp_path / "link.csv").symlink_to("real/target.csv")
    write_text_atomic(tmp_path / "link.csv", "a,b\n")
    assert (tmp_path / "link.csv").is_symlink()
    assert (tmp_path / "real" / "target.csv").read_text() == "a,b\n"


@pytest.mark.parametrize("table, words", [
    ("case,tendon,unknown\n", "no column tension_N"),
    ("case,tendon,unknown,force_X,tension_N,displacement_m,applied\n", "no data rows"),
    ("case,tendon,unknown,force_X,tension_N,displacement_m,applied\n"
     "a,t1,point_force,0.25,abc,-0.001,0.1\n", "row 1 (case 'a'): tension_N: not a number"),
    ("case,tendon,unknown,force_X,tension_N,displacement_m,applied\n"
     "a,t1,point_force,0.25,-1,-0.001,0.1\n", "row 1 (case 'a'): tension t1 = -1 N"),
    ("case,tendon,unknown,force_X,tension_N,displacement_m,applied\n"
     "a,t9,point_force,0.25,1,-0.001,0.1\n", "row 1 (case 'a'): displacement t9: no such"),
    ("case,tendon,unknown,force_X,tension_N,displacement_m,applied\n"
     "a,t1,point_force,0.25\n", "row 1 (case 'a'): 1 tendons, 0 tensions"),
    ("case,tendon,unknown,force_X,tension_N,displacement_m,applied\n"
     "a,t1 t1,point_force,0.25,1 2,-0.001 -0.002,0.1\n", "a tendon named twice"),
    # any kind but gravity was a point force, any with "3d" in it a 3-D one
    ("case,tendon,unknown,force_X,tension_N,displacement_m,applied\n"
     "a,t1,pointforce,0.25,1,-0.001,0.1\n",
     "row 1 (case 'a'): unknown 'pointforce': one of point_force, point_force_3d, gravity"),
])
def test_an_experiments_table_is_checked_before_jax(tmp_path, table, words):
    path = tmp_path / "table.csv"
    path.write_text(table)
    for command in ("experiments", "compare"):
        out = tmp_path / "results"
        rc, err, jax_loaded = refused_before_jax(command, PROTOTYPE, path, "-o", out) \
            if command == "compare" else refused_before_jax(command, PROTOTYPE, path)
        assert rc == 1 and words in err and len(err.strip().splitlines()) == 1, err
        assert not jax_loaded and not out.exists()


def test_several_logs_name_their_skipped_rows(tmp_path):
    """Several logs report a bad row as one log does: the log, the row and the reason."""
    rows = (ROOT / "examples" / "tutorial" / "readings.csv").read_text().splitlines()[:6]
    good, bad = tmp_path / "good.csv", tmp_path / "bad.csv"
    good.write_text("\n".join(rows) + "\n")
    cells = rows[2].split(",")
    cells[1] = "-1"
    bad.write_text("\n".join([*rows[:2], ",".join(cells), *rows[3:]]) + "\n")
    p = cli("estimate", PROTOTYPE, "--readings", good, bad, "--unknown", "0.25,0,0,-1",
            "-o", f"{tmp_path / 'out'}/")
    assert p.returncode == 3, p.stderr
    assert p.stderr.splitlines() == [
        f"tendonsense: {bad}: row 2 skipped: tension t1 = -1 N is negative (a tendon cannot "
        f"push; slack is 0)", "tendonsense: not every solve converged (marked converged = false)"]
    assert "1 skipped" in p.stdout


def test_a_logs_summary_counts_the_rows_not_converged(tmp_path):
    """A row with no equilibrium (t1 pulled in 10 cm) is counted as not converged, not left
    out of the summary: one log into a file, and several into a folder."""
    rows = (ROOT / "examples" / "tutorial" / "readings.csv").read_text().splitlines()[:6]
    cells = rows[2].split(",")
    cells[rows[0].split(",").index("displacement_t1")] = "-0.1"
    log = tmp_path / "log.csv"
    log.write_text("\n".join([*rows[:2], ",".join(cells), *rows[3:]]) + "\n")
    p = cli("estimate", PROTOTYPE, "--readings", log, "--unknown", "0.25,0,0,-1",
            "-o", tmp_path / "e.csv")
    assert p.returncode == 3 and "5 samples: 4 converged, 1 not converged, 0 skipped" in p.stdout
    p = cli("estimate", PROTOTYPE, "--readings", log, ROOT / "examples" / "tutorial" /
            "readings.csv", "--unknown", "0.25,0,0,-1", "-o", f"{tmp_path / 'out'}/")
    assert p.returncode == 3 and "(305 samples: 304 converged, 1 not converged, 0 skipped)" \
        in p.stdout, p.stdout


def test_a_live_log_into_a_file(tmp_path):
    """``--readings - -o FILE``: the rows go into FILE (atomically, at the end), standard
    output says what was written."""
    rows = (ROOT / "examples" / "tutorial" / "readings.csv").read_text().splitlines()[:6]
    out = tmp_path / "live.csv"
    p = cli("estimate", PROTOTYPE, "--readings", "-", "--unknown", "0.25,0,0,-1", "-o", out,
            stdin="\n".join(rows) + "\n")
    assert p.returncode == 0, p.stderr
    assert p.stdout == f"estimated 5 samples: 5 converged, 0 skipped; wrote {out}\n"
    written = list(csv.DictReader(open(out)))
    assert [r["row"] for r in written] == ["1", "2", "3", "4", "5"]


class _Interrupted:
    """Standard input that gives ``lines`` and then Ctrl-C."""

    def __init__(self, lines):
        self.lines = lines

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def __iter__(self):
        yield from self.lines
        raise KeyboardInterrupt


def test_a_live_log_into_a_file_interrupted(tmp_path, monkeypatch, capsys):
    """Ctrl-C ends a live log into a file with the rows answered so far, counted; before its
    first row it writes nothing (a file already there stays as it was)."""
    from tendonsense import cli as tcli
    rows = (ROOT / "examples" / "tutorial" / "readings.csv").read_text().splitlines(True)[:5]
    out = tmp_path / "live.csv"
    args = ["estimate", PROTOTYPE, "--readings", "-", "--unknown", "0.25,0,0,-1", "-o", out,
            "--json"]
    monkeypatch.setattr(sys, "stdin", _Interrupted(rows))
    assert tcli.main(args) == 0
    assert json.loads(capsys.readouterr().out) == {"samples": 4, "converged": 4, "skipped": 0,
                                                   "output": str(out)}
    assert len(list(csv.DictReader(open(out)))) == 4
    out.write_text("kept\n")
    monkeypatch.setattr(sys, "stdin", _Interrupted(rows[:1]))
    assert tcli.main(args) == 0
    assert "no row answered; nothing written" in capsys.readouterr().err
    assert out.read_text() == "kept\n" and [p.name for p in tmp_path.iterdir()] == ["live.csv"]


def test_a_failed_range_hands_over_the_chunks_before_it_and_raises(prototype, monkeypatch):
    """A chunk's range that fails: the chunks before it are handed over, in order, and its
    error raised; no chunk after it (their rows were handed over as None)."""
    from tendonsense import logs
    from tendonsense.readings import Sample
    samples = [Sample(i + 1, None, {"t1": 2.0, "t2": 0.0, "t3": 0.0}, {"t1": -0.005}, {})
               for i in range(350)]

    def chunks(prob, displacements, tensions, noise, chunk, **kw):
        for first in range(0, 350, 100):
            time.sleep(0.3)  # the ranges before are done (or failed) meanwhile
            yield first, [str(first)] * min(100, 350 - first)

    def ranges(prob, rows, estimates, noise, *a):
        if estimates[0] == "100":
            raise RuntimeError("the range failed")
        return [e + "r" for e in estimates]

    monkeypatch.setattr(logs, "series_chunks", chunks)
    monkeypatch.setattr(logs, "_stuck_ranges", ranges)
    got = []
    with pytest.raises(RuntimeError, match="the range failed"):
        for first, estimates in logs.estimate_chunks(prototype, ["t1"], samples, [TIP]):
            got.append((first, estimates))
    assert got == [(0, ["0r"] * 100)]


def test_a_logs_chunks_done_before_a_failure_are_handed_over(prototype, monkeypatch):
    """With the friction history a chunk is handed over once its stuck rows have their range
    (on a second thread, while the next chunk is scanned); a failure of the scan still hands
    over the chunks done before it, in order."""
    from tendonsense import logs
    from tendonsense.readings import Sample
    samples = [Sample(i + 1, None, {"t1": 2.0, "t2": 0.0, "t3": 0.0}, {"t1": -0.005}, {})
               for i in range(250)]

    def chunks(prob, displacements, tensions, noise, chunk, **kw):
        yield 0, ["a"] * 100
        yield 100, ["b"] * 100
        raise RuntimeError("the scan failed")

    monkeypatch.setattr(logs, "series_chunks", chunks)
    monkeypatch.setattr(logs, "_stuck_ranges", lambda prob, rows, estimates, noise, *a: [
        e.upper() for e in estimates])
    got = []
    with pytest.raises(RuntimeError, match="the scan failed"):
        for first, estimates in logs.estimate_chunks(prototype, ["t1"], samples, [TIP]):
            got.append((first, estimates))
    assert got == [(0, ["A"] * 100), (100, ["B"] * 100)]


def test_a_header_only_log_is_an_error(tmp_path):
    log = tmp_path / "log.csv"
    log.write_text("time,tension_t1,tension_t2,tension_t3,displacement_t1\n")
    rc, err, jax_loaded = refused_before_jax("estimate", PROTOTYPE, "--readings", log,
                                             "--unknown", "0.25,0,0,-1", "-o", tmp_path / "o.csv")
    assert rc == 1 and "no data rows" in err and not jax_loaded
    p = cli("estimate", PROTOTYPE, "--readings", "-", "--unknown", "0.25,0,0,-1",
            stdin=log.read_text())
    assert p.returncode == 1 and "no data rows" in p.stderr


# ------------------------------------------------------------ the command line, before JAX

@pytest.mark.parametrize("args, status, words", [
    (("solve", PROTOTYPE, "--tension", "t1=-2.0"), 1, "tension t1 = -2 N is negative"),
    (("fk", PROTOTYPE, "--displacement", "t1=-5"), 1, "pulls in more"),
    (("fk", PROTOTYPE, "--displacement", "t1=-0.01", "--tension", "t2=-1"), 1, "negative"),
    (("estimate", PROTOTYPE, "--displacement", "t1=-0.005", "--unknown", "0.25,0,0,-1"), 1,
     "tension t1: missing"),
    (("estimate", PROTOTYPE, "--displacement", "t1=-5", "--tension", "t1=2.1", "--unknown",
      "0.25,0,0,-1"), 1, "pulls in more"),
    (("solve", PROTOTYPE, "--tension", "t1=2", "--tension", "t1=3"), 2,
     "--tension t1 given twice"),
    (("estimate", PROTOTYPE, "--displacement", "t1=-0.005", "--displacement", "t1=-0.004",
      "--tension", "t1=2", "--unknown", "0.25,0,0,-1"), 2, "--displacement t1 given twice"),
    (("solve", PROTOTYPE, "--tension", "t1=2", "--plot", "no/such/folder/shape.png"), 1,
     "--plot no/such/folder/shape.png: no folder"),
    (("solve", PROTOTYPE, "--tension", "t1=2", "--plot", PROTOTYPE / "shape.png"), 1,
     f"'{PROTOTYPE}' is a file, not a folder"),
    (("estimate", PROTOTYPE, "--readings", ROOT / "examples" / "tutorial" / "readings.csv",
      "--unknown", "0.25,0,0,-1", "-o", "no/such/folder/out.csv"), 1,
     "-o/--estimates no/such/folder/out.csv: no folder"),
    (("identify", PROTOTYPE, "--snapshots", ROOT / "examples" / "tutorial" / "snapshots.csv",
      "--param", "stiffness"), 1, "--param stiffness: not a parameter"),
    (("solve", PROTOTYPE, "--point-force", "-0.1,0,0,-1"), 1,
     "point force 1: X = -0.1 m is outside the rod"),
    (("solve", PROTOTYPE, "--point-force", "250,0,0,-1"), 1,
     "point force 1: X = 250 m is outside the rod [0, 0.25 m] (lengths are in metres)"),
    (("estimate", PROTOTYPE, "--displacement", "t1=-0.005", "--tension", "t1=2", "--unknown",
      "0.3,0,0,-1"), 1, "unknown force: X = 0.3 m is outside the rod [0, 0.25 m]"),
    (("estimate", PROTOTYPE, "--displacement", "t1=-0.005", "--tension", "t1=2", "--unknown",
      "?,0,0,-1"), 1, "need at least 2 tendons"),
    (("estimate", PROTOTYPE, "--readings", ROOT / "examples" / "tutorial" / "readings.csv",
      "--unknown", "0.25,0,0,-1", "--json"), 2, "--json: the rows go to standard output"),
    (("estimate", PROTOTYPE, "--readings", ROOT / "examples" / "tutorial" / "readings.csv",
      "--readings", ROOT / "examples" / "tutorial" / "readings.csv", "--unknown",
      "0.25,0,0,-1"), 2, "--readings given twice"),
    (("solve", PROTOTYPE, "--tension", "t1=2", "--plot", "a.png", "--plot", "b.png"), 2,
     "--plot given twice"),
    (("estimate", PROTOTYPE, "--displacement", "t1=-0.005", "--tension", "t1=2", "--unknown",
      "0.25,0,0,-1", "--length-noise", "-1e-4"), 1,
     "--length-noise: must be a positive number, got '-1e-4'"),  # not taken for an option
    (("estimate", PROTOTYPE, "--displacement", "t1=-0.005", "--tension", "t1=2", "--unknown",
      "0.25,0,0,-1", "--tension-noise", "2.5"), 1, "must be a fraction under 1"),  # per cent
    # a value its option's type refuses is a bad value (1), as one refused later is (it was 2)
    (("solve", PROTOTYPE, "--tension", "t1=2,0"), 1, "--tension: t1: not a number: '2,0'"),
    (("sensitivity", "--points", "nine"), 1, "--points: invalid int value: 'nine'"),
    (("sensitivity", "--points", "0"), 1, "--points 0: at least 1"),  # (it was 2)
    # a slip in a parent's name made a tree of folders (at the file system's root, once)
    (("sensitivity", "-o", "missing/x"), 1,
     "-o/--out-dir missing/x: no folder 'missing' (the output folder is made in one that "
     "exists)"),
    (("resolution", "-o", ""), 1, "-o/--out-dir: an empty name"),  # (it wrote into ".")
    (("sweep", PROTOTYPE, ROOT / "examples" / "sweep_sets.csv", "-o", ""), 1,
     "-o/--results: an empty name (a file name is needed)"),
    (("sweep", PROTOTYPE, ROOT / "examples" / "sweep_sets.csv", "-o", "o.png"), 1,
     "-o/--results o.png: writes a CSV table, not a figure"),  # (it wrote the CSV there)
    (("solve", PROTOTYPE, "--tension", "t1=2", "--tensoin", "t2=1"), 2,
     "unrecognized arguments: --tensoin t2=1 (--tensoin: did you mean --tension? see "),
    # a required option mistyped was said to be missing
    (("estimate", PROTOTYPE, "--displacement", "t1=-0.005", "--tension", "t1=2", "--unknwn",
      "0.25,0,0,-1"), 2, "unrecognized arguments: --unknwn (--unknwn: did you mean --unknown?"),
    (("solve", PROTOTYPE, "--tension", "t1=2", "--json", "--json"), 2, "--json given twice"),
    (("solve", PROTOTYPE, "--tension", "t1=2", "--sliding", "t1=stuck"), 1,
     "depends on its history"),  # a value refused, as --sliding t1=up (it was 2)
    (("solve", PROTOTYPE, "--tension", "t1=204"), 1, "tensions are in newtons"),  # gF
    (("simulate", PROTOTYPE, "--tension", "t1=2", "--duration", "1", "--noise-tension", "1.5",
      "-o", "s.csv"), 1, "--noise-tension 1.5: relative, must be a fraction under 1"),
    (("simulate", PROTOTYPE, "--tension", "t1=2", "--duration", "1", "--seed", "-1", "-o",
      "s.csv"), 1, "--seed -1: must be a whole number >= 0"),
    (("estimate", PROTOTYPE, "--readings", ROOT / "examples" / "tutorial" / "readings.csv",
      ROOT / "examples" / "sweep_sets.csv", "--unknown", "0.25,0,0,-1", "-o", "e.csv"), 2,
     "several logs write one output each into a folder: -o e.csv/ makes it"),
    (("estimate", PROTOTYPE, "--displacement", "t1=-0.005", "--displacement", "t2=-0.004",
      "--tension", "t1=2", "--tension", "t2=1", "--unknown", "0.2,0,0,-1", "--unknown",
      "0.2,0,0,-2"), 1, "unknowns 1 and 2: one force"),
    (("estimate", PROTOTYPE, "--displacement", "t1=-0.005", "--displacement", "t2=-0.004",
      "--tension", "t1=2", "--tension", "t2=1", "--unknown", "?,0,0,-1", "--sliding",
      "t1=stuck"), 1, "estimated for forces at known points"),
    (("estimate", PROTOTYPE, "--displacement", "t1=-0.005", "--tension", "t1=2", "--unknown",
      "0.25,0,0,-1", "--sliding", "t2=stuck"), 1, "t2 is slack (0 N)"),
    (("estimate", PROTOTYPE, "--displacement", "t1=-0.005", "--tension", "t1=2", "--tension",
      "t2=-1", "--unknown", "0.25,0,0,-1", "--sliding", "t2=stuck"), 1,
     "tension t2 = -1 N is negative"),  # the tension's own rule, not "slack"
])
def test_a_slip_is_refused_in_one_line_before_jax_starts(tmp_path, args, status, words):
    rc, err, jax_loaded = refused_before_jax(*args, cwd=tmp_path)  # relative outputs land here
    assert rc == status, err
    assert words in err
    assert len(err.strip().splitlines()) == 1
    assert not jax_loaded
    assert list(tmp_path.iterdir()) == []


def test_version_usage_and_descriptions():
    from tendonsense import __version__
    from tendonsense.cli import build_parser
    p = cli("--version")
    assert p.returncode == 0 and p.stdout.strip() == f"tendonsense {__version__}"
    p = cli()
    assert p.returncode == 2 and "usage: tendonsense" in p.stderr and "solve" in p.stderr
    sub = next(a for a in build_parser()._actions if a.dest == "command")
    for name, parser in sub.choices.items():
        assert parser.description and len(parser.description) > 40, name
    estimate_help = sub.choices["estimate"].format_help()
    assert "'?'" in estimate_help and "'A:B'" in estimate_help


def test_the_analyses_run_from_any_folder(tmp_path):
    """Their default robots and experiments table come with the package."""
    code = ("from tendonsense.cli import build_parser, _resolve_robot\n"
            "from tendonsense import load_robot\nfrom pathlib import Path\n"
            "for cmd in ('sensitivity', 'resolution', 'compare', 'experiments'):\n"
            "    args = build_parser().parse_args([cmd])\n    _resolve_robot(args)\n"
            "    load_robot(args.robot)\n"
            "    assert not hasattr(args, 'csv') or Path(args.csv).is_file(), args.csv\n"
            "print('ok')\n")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       cwd=tmp_path, timeout=120)
    assert p.stdout.strip() == "ok", p.stderr


# ------------------------------------------------------ a result that is not a solution

def short_of_iterations(folder):
    """The prototype with a solver cut short (2 iterations a stage): 38 N at the tip, within
    the rules, is then not solved (the full solver solves it)."""
    robot = folder / "short.toml"
    robot.write_text(PROTOTYPE.read_text() + "\n[solver]\nmax_iterations = 2\n")
    return robot


def test_a_solve_that_did_not_converge_is_not_dressed_as_one(tmp_path):
    robot = short_of_iterations(tmp_path)
    tmp_path = tmp_path / "run"
    tmp_path.mkdir()
    p = cli("solve", robot, "--tension", "t1=2", "--point-force=0.25,0,0,-38", cwd=tmp_path)
    assert p.returncode == 3
    head, *rest = p.stdout.splitlines()
    assert "NOT CONVERGED: " in head and len(head.split("NOT CONVERGED: ")[1]) > 20
    assert "residual" in head or "strain" in head
    assert not any("markers" in line or "tip (X" in line for line in rest)
    assert "Warning" not in p.stderr, p.stderr  # the command line says it its own way
    assert list(tmp_path.iterdir()) == []  # nothing written without --plot
    p = cli("solve", robot, "--tension", "t1=2", "--point-force=0.25,0,0,-38", "--json",
            "--plot", tmp_path / "s.png")
    out = json.loads(p.stdout)
    assert out["converged"] is False and out["note"] and p.returncode == 3
    assert (tmp_path / "s.png").stat().st_size > 10_000  # asked for: drawn, stamped


@pytest.mark.parametrize("stage", [2, 6])
def test_a_solve_that_did_not_converge_gives_its_last_iterate(tmp_path, stage):
    """The result of a solve that did not converge is the last point accepted under the full
    load, its residual the one there (it was the restart of a failed continuation, the
    straight rod under 38 N, with another point's residual 5.7e-2), and its note says how far
    the continuation came."""
    from tendonsense.forward import _statics_drive, model_for
    from tendonsense.result import NotConvergedWarning
    from tendonsense.statics import Unknowns, residual, scaling
    robot = tmp_path / "short.toml"
    robot.write_text(PROTOTYPE.read_text() + f"\n[solver]\nmax_iterations = {stage}\n")
    robot = load_robot(robot)
    loads = [(0.25, (0.0, 0.0, -38.0))]
    with pytest.warns(NotConvergedWarning):
        r = solve(robot, {"t1": 2.0}, loads)
    model, drive = model_for(robot), _statics_drive(robot, {"t1": 2.0}, loads)
    v = model.values
    rr, size = residual(model.structure, v, (), r.q, drive, Unknowns.none(3, 1), 1.0,
                        scaling(v, ()))
    floor = v.energy_floor * np.sqrt(v.young_modulus)
    assert float(np.linalg.norm(rr) / (size + floor)) == pytest.approx(r.residual, rel=1e-9)
    assert r.note.startswith("the solver stopped after ") and f"{r.residual:.2e}" in r.note
    if stage == 6:  # its continuation solved a part of the load; its last iterate coiled
        assert "it solved 32% of the load" in r.note and r.note.endswith(
            "; at the last iterate: strain outside the model's range (a fibre compressed to "
            "nothing)")


def test_a_simulation_whose_start_is_no_solution_says_so(tmp_path):
    """`simulate --from-equilibrium` from an equilibrium that did not converge names why (it
    stopped on an AttributeError: Result had no note)."""
    robot = tmp_path / "short.toml"
    robot.write_text((ROOT / "examples" / "paper_prototype_damped.toml").read_text()
                     + "\n[solver]\nmax_iterations = 2\n")
    out = tmp_path / "m.csv"
    p = cli("simulate", robot, "--tensions", ROOT / "examples" / "ramp_t1.csv", "--duration",
            "1", "--from-equilibrium", "--point-force=0.25,0,0,-38", "-o", out)
    assert p.returncode == 3 and "Traceback" not in p.stderr, p.stderr
    assert p.stderr.startswith("tendonsense simulate: the equilibrium at t = 0 did not "
                               "converge (the solver stopped after "), p.stderr
    assert not out.exists()


def test_series_and_batches_take_readings_in_either_form(prototype):
    """One {tendon: value} a sample, or {tendon: (N,) values} (a tendon's one value held):
    the same estimates; solve_batch takes the list form too."""
    prob = problem(prototype, ["t1"], [TIP])
    ys, ts = [-0.004, -0.005, -0.006], [2.0, 2.1, 2.2]
    rows = estimate_series(prob, [{"t1": y} for y in ys], [{"t1": t, "t2": 0.0} for t in ts])
    cols = estimate_series(prob, {"t1": np.array(ys)}, {"t1": ts, "t2": 0.0})
    assert [e.magnitudes[0] for e in rows] == [e.magnitudes[0] for e in cols]
    assert estimate_series(prob, [], []) == estimate_series(prob, {}, {}) == []
    a = solve_batch(prototype, [{"t1": t} for t in ts]).displacements["t1"]
    np.testing.assert_array_equal(a, solve_batch(prototype, {"t1": ts}).displacements["t1"])


def test_every_result_dumps_to_json(prototype):
    """Each result object's ``to_json`` is plain JSON (lists, null for NaN) with its fields'
    values: a series' samples (a bad row among them), a batch, a simulation, derivatives."""
    from tendonsense.forward import solution_derivatives
    prob = problem(prototype, ["t1"], [TIP])
    series = estimate_series(prob, [{"t1": -0.004}, {"t1": 0.4}], [{"t1": 2.0}, {"t1": 2.0}])
    batch = solve_batch(prototype, {"t1": [1.0, 2.0]})
    sim = simulate(prototype, {"t1": 2.0}, duration=0.02)
    d = solution_derivatives(prototype, {"t1": 2.0}, wrt=("young_modulus", "tensions"))
    for result in (*series, batch, sim, d):
        back = json.loads(json.dumps(result.to_json(), allow_nan=False))
        assert "robot" not in back
        for name, value in back.items():
            mine = getattr(result, name)
            if isinstance(mine, dict):
                for k, v in mine.items():
                    np.testing.assert_array_equal(np.array(back[name][k], float), v)
            elif np.asarray(mine).dtype.kind in "fbiu":  # ([] for an empty array of any
                # shape; flags and counts as JSON's true/false and integers)
                np.testing.assert_array_equal(np.array(value, float).reshape(np.shape(mine)),
                                              mine)
                kind = {"b": bool, "i": int, "u": int}.get(np.asarray(mine).dtype.kind, float)
                assert all(type(x) is kind for x in np.ravel(np.array(value, object))
                           if x is not None), (name, value)
            else:
                assert value == (list(mine) if isinstance(mine, (tuple, np.ndarray)) else mine)
    assert back["q"].keys() == {"young_modulus", "tensions"}
    bad = series[1].to_json()
    assert bad["magnitudes"] == [None] and "0.4 m" in bad["note"]
    assert batch.to_json()["notes"] == ["", ""]


def test_a_python_result_that_is_no_solution_says_so(prototype, tmp_path):
    """From Python, a solve or an estimate without a solution warns (its result is the last
    iterate: a script printing its magnitudes read -1.48 N ± 1.17 N without a word); a
    solution does not; a stuck tendon's estimate gives its range as SampleEstimate does."""
    from tendonsense.result import NotConvergedWarning
    with pytest.warns(NotConvergedWarning, match=r"^estimate did not converge: the solver "
                      r"stopped after \d+ iterations .*no solution \(result.converged is "
                      r"False\)$"):
        est = estimate(prototype, {"t1": -0.05}, {"t1": 2.1}, [TIP])
    assert not est.converged and est.note == est.extra["note"] and est.note
    with pytest.warns(NotConvergedWarning, match="^solve did not converge: "):
        assert not solve(load_robot(short_of_iterations(tmp_path)), {"t1": 2.0},
                         [(0.25, (0, 0, -38.0))]).converged
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert solve(prototype, {"t1": 2.0}).note == ""
        stuck = estimate(prototype, {"t1": -0.005}, {"t1": 2.1}, [TIP], sliding={"t1": "stuck"})
    assert stuck.magnitude_range.shape == (1, 2) and (
        stuck.magnitude_range[0, 0] < stuck.magnitudes[0] < stuck.magnitude_range[0, 1])
    assert solve(prototype, {"t1": 2.0}).magnitude_range.shape == (0, 2)


def test_a_least_squares_fit_short_of_its_minimum_says_so(prototype, monkeypatch):
    """An overdetermined estimate stopped by its step limit names the fit, not the
    equilibrium's residual (which is within its tolerance: no contradiction)."""
    from tendonsense import estimation
    T = {"t1": 2.0, "t2": 1.0, "t3": 0.5}
    truth = solve(prototype, T, [(0.25, (0.0, 0.0, -0.3))]).displacements
    y = {n: v + d for (n, v), d in zip(truth.items(), (2e-4, -3e-4, 1e-4))}
    unknown = [PointForceUnknown(0.25, (0, 0, -1))]
    assert estimate(prototype, y, T, unknown).converged
    monkeypatch.setattr(estimation, "LM_STEPS", 1)
    with pytest.warns(UserWarning, match="did not converge"):
        est = estimate(prototype, y, T, unknown)
    assert not est.converged
    assert est.extra["note"].startswith("the least-squares fit took its 1 steps without "
                                        "reaching a minimum (relative offset ")
    assert "residual" not in est.extra["note"]


def test_a_fitted_robot_file_keeps_its_comments_and_says_how_it_was_made(tmp_path):
    guess = ROOT / "examples" / "tutorial" / "robot_guess.toml"
    p = cli("identify", guess, "--snapshots", ROOT / "examples" / "tutorial" / "snapshots.csv",
            "-o", tmp_path / "fitted.toml")
    assert p.returncode == 0, p.stderr
    text = (tmp_path / "fitted.toml").read_text()
    assert text.startswith("# fitted by tendonsense identify")
    assert "snapshots.csv (" in text and "marker RMSE" in text
    comments = [line for line in guess.read_text().splitlines() if line.startswith("#")]
    assert comments and all(c in text for c in comments)


def test_a_skipped_row_keeps_its_time(prototype):
    """A bad row is marked with its reason and keeps its time stamp (the output's `time` is
    copied from the input); a bad time itself is not kept."""
    from tendonsense.readings import output_row, parse_header, parse_row
    columns = parse_header(["time", "tension_t1", "tension_t2", "tension_t3",
                            "displacement_t1"], prototype, "log.csv")
    s = parse_row(50, ["1.0", "abc", "0", "0", "-0.003"], columns, prototype)
    assert s.error and s.time == 1.0
    assert output_row(prototype, s, None, 1, False)[:2] == [50, "1.0"]
    assert parse_row(51, ["soon", "2.0", "0", "0", "-0.003"], columns, prototype).time is None


@pytest.mark.parametrize("column, scale, unit", [("displacement_t1", 1000, "metres"),
                                                 ("tension_t1", 1000 / 9.80665, "newtons")])
def test_a_column_in_another_unit_is_refused_before_jax(tmp_path, column, scale, unit):
    """Lengths typed in mm or tensions in gram-force: the log is refused up front in one line
    (its rows would each be skipped, or worse, the few that pass estimated: with tensions in
    gF half the tutorial's rows "converged" to a tip force of 42–86 N)."""
    rows = (ROOT / "examples" / "tutorial" / "readings.csv").read_text().splitlines()
    header = rows[0].split(",")
    k = header.index(column)
    other = [rows[0]] + [",".join(c if j != k else repr(scale * float(c))
                                  for j, c in enumerate(r.split(","))) for r in rows[1:]]
    path = tmp_path / "other.csv"
    path.write_text("\n".join(other) + "\n")
    rc, err, jax_loaded = refused_before_jax("estimate", PROTOTYPE, "--readings", path,
                                             "--unknown", "0.25,0,0,-1", "-o", tmp_path / "e.csv")
    assert rc == 1 and not jax_loaded and len(err.strip().splitlines()) == 1, err
    assert column in err and f"are in {unit}" in err and not (tmp_path / "e.csv").exists()


def test_a_file_log_names_its_first_skipped_rows_and_counts_the_rest(tmp_path):
    rows = (ROOT / "examples" / "tutorial" / "readings.csv").read_text().splitlines()[:41]
    k = rows[0].split(",").index("tension_t1")
    bad = [rows[0]] + [",".join(c if j != k or i > 25 else "-1"
                                for j, c in enumerate(r.split(",")))
                       for i, r in enumerate(rows[1:], start=1)]
    path = tmp_path / "bad.csv"
    path.write_text("\n".join(bad) + "\n")
    p = cli("estimate", PROTOTYPE, "--readings", path, "--unknown", "0.25,0,0,-1",
            "-o", tmp_path / "e.csv")
    err = [line for line in p.stderr.splitlines() if line.startswith("tendonsense:")]
    assert p.returncode == 3 and len(err) == 22, p.stderr
    assert "row 20 skipped" in err[19] and "5 more rows skipped" in err[20]
    assert "not every solve converged" in err[21]
    assert "40 samples: 15 converged, 25 skipped" in p.stdout


def test_results_echo_in_a_few_lines(prototype):
    """A notebook echoes a result readably: long arrays by their shape, the rest in full."""
    from tendonsense.tracking import solve_batch
    r = solve(prototype, {"t1": 2.0})
    text = repr(r)
    assert len(text) < 600 and "backbone=<array (101, 3)>" in text and "converged=True" in text
    assert "'tip': [" in text  # a marker's position in full
    b = repr(solve_batch(prototype, {"t1": np.linspace(1.0, 2.0, 50)}))
    assert len(b) < 600 and "q=<array (50, 15)>" in b


def test_the_papers_experiments_on_another_robot_say_so(capsys):
    """The paper's readings estimated with another robot file: a line says the errors also
    measure how far that robot is from the prototype; with the prototype, no such line."""
    from tendonsense.cli import main
    main(["experiments", ROOT / "examples" / "soromox_tentacle.toml"])
    assert "note: these are the readings" in capsys.readouterr().err  # not in the table
    main(["experiments", PROTOTYPE])
    assert "is not its robot file" not in capsys.readouterr().err


def test_an_experiment_without_an_estimate_says_why(tmp_path, capsys, monkeypatch):
    """A row the estimator cannot answer (a force across the plane t1 bends the rod in) said
    "-" and "nan%" without a reason: now its reason on standard error and in --json, "n/a"
    for its error; compare's table and figure say it too."""
    from tendonsense.cli import main
    from tendonsense.experiments import ExperimentRow
    table = tmp_path / "table.csv"
    table.write_text("case,tendon,unknown,force_X,direction,tension_N,displacement_m,applied\n"
                     "unseen-1,t1,point_force,0.125,0 1 0,3.45,-0.011,0.64\n")
    assert main(["experiments", PROTOTYPE, table]) == 3
    out, err = capsys.readouterr()
    assert "nan" not in out and "unseen-1" in out
    assert ("tendonsense: case unseen-1: no estimate: the measured tendon (t1) does not "
            "change length with unknown 1") in err
    main(["experiments", PROTOTYPE, table, "--json"])
    case, = json.loads(capsys.readouterr().out)["cases"]
    assert case["estimate"] is None and "does not change length" in case["note"]
    rows = [ExperimentRow("mid-1", np.array([0.6]), np.array([0.7]), None, True),
            ExperimentRow("unseen-1", np.array([0.6]), None, None, False, "why")]
    from tendonsense import plotting
    drawn = []
    monkeypatch.setattr(plotting, "_save", lambda fig, path, tight=True: drawn.append(fig))
    plotting.comparison({"GVS": rows, "3D-PC": rows}, tmp_path / "c.png")
    ax = drawn[0].axes[0]
    assert [t.get_text() for t in ax.texts] == ["no estimate"] * 2  # one a model
    assert [t.get_text() for t in ax.get_xticklabels()] == [
        "mid\n(1 row)", "unseen\n(1 row, 0 estimated)"]
    lo, hi = ax.get_xlim()
    assert all(lo < t.get_position()[0] < hi for t in ax.texts)  # (they fell off its left)


@pytest.mark.parametrize("kind, header, named", [
    ("log", "time,tension_t1,tension_t2,tension_t3,displacement_T1", "no tendon 'T1'"),
    ("log", "tension_t1,tension_t2,tension_t3,displacement_t1,marker_tp_x,marker_tp_y,"
            "marker_tp_z", "no marker 'tp' in the robot (its markers: mid, three_quarter, tip)"),
    ("snapshots", "tension_T1,tension_t2,tension_t3,marker_tip_x,marker_tip_y,marker_tip_z",
     "no tendon 'T1'"),
    ("sets", "young_modulus,friction_T2", "no tendon 'T2'")])
def test_a_column_naming_another_tendon_lists_the_robots(prototype, tmp_path, kind, header,
                                                        named):
    """A mistyped tendon or marker in a column is named with the robot's own, on each reader
    (a log, snapshots, parameter sets)."""
    from tendonsense.readings import read_parameter_sets, read_readings, read_snapshots
    path = tmp_path / f"{kind}.csv"
    path.write_text(header + "\n" + ",".join(["0.1"] * len(header.split(","))) + "\n")
    read = {"log": read_readings, "snapshots": read_snapshots, "sets": read_parameter_sets}
    with pytest.raises(ValueError) as e:
        read[kind](path, prototype)
    assert named in str(e.value)
    if "tendon" in named:
        assert "(its tendons: t1, t2, t3)" in str(e.value)


def test_an_output_that_is_an_input_is_refused_and_the_input_kept(tmp_path):
    """``-o`` or ``--plot`` naming one of the command's own inputs (the log, the sets, the
    schedule, the robot file) is refused before anything runs, the input unchanged; and so
    in Python for a log's estimates."""
    from tendonsense import load_robot
    from tendonsense.logs import estimate_file
    robot = tmp_path / "robot.toml"
    robot.write_text(PROTOTYPE.read_text())
    log = tmp_path / "log.csv"
    log.write_text("time,tension_t1,tension_t2,tension_t3,displacement_t1\n0,2,0,0,-0.003\n")
    sets = tmp_path / "sets.csv"
    sets.write_text("tension_t1\n2\n")
    schedule = tmp_path / "schedule.csv"
    schedule.write_text("time,tension_t1\n0,2\n")
    before = {p: p.read_bytes() for p in (robot, log, sets, schedule)}
    for args, named in (
            (["estimate", robot, "--readings", log, "--unknown", "0.25,0,0,-1", "-o",
              tmp_path / "." / "log.csv"], "is --readings"),
            (["sweep", robot, sets, "-o", sets], "is the parameter sets"),
            (["simulate", robot, "--tensions", schedule, "--duration", "1", "-o", schedule],
             "is --tensions"),
            (["solve", robot, "--tension", "t1=2", "--plot", robot], "is the robot file"),
            (["identify", robot, "--snapshots", log, "-o", log], "is --snapshots")):
        p = subprocess.run([sys.executable, "-m", "tendonsense.cli", *map(str, args)],
                           capture_output=True, text=True, timeout=60)
        assert p.returncode == 1 and named in p.stderr and "overwrite" in p.stderr, p.stderr
    rc, err, jax_loaded = refused_before_jax("sweep", robot, sets, "-o", sets)
    assert rc == 1 and "overwrite" in err and not jax_loaded
    # an analysis writes fixed names into its folder: the table there is one of them
    table = tmp_path / "compare.csv"
    table.write_bytes((ROOT / "src" / "tendonsense" / "data" / "paper_experiments.csv")
                      .read_bytes())
    before[table] = table.read_bytes()
    rc, err, jax_loaded = refused_before_jax("compare", robot, table, "-o", tmp_path)
    assert rc == 1 and "writes compare.csv, which is the table" in err and not jax_loaded
    summary = estimate_file(load_robot(robot), log, log, [PointForceUnknown(0.25, (0, 0, -1))])
    assert "the log itself" in summary.error
    assert {p: p.read_bytes() for p in before} == before


def test_a_load_in_gram_force_is_refused_on_every_path(prototype, tmp_path):
    """A known load of 65 gF typed as 65 N (over half of E·A = 78.5 N at the tip) is refused
    like such a tension: on the command line, in Python, in a sweep set (with the set's own E:
    at 2 MPa it is taken), a snapshot and a batch."""
    from tendonsense.readings import read_parameter_sets, read_snapshots
    from tendonsense.tracking import solve_batch
    p = cli("solve", PROTOTYPE, "--tension", "t1=2", "--point-force=0.25,0,0,-65",
            cwd=tmp_path)
    assert p.returncode == 1 and "forces are in newtons" in p.stderr and not p.stdout
    with pytest.raises(ValueError, match="point force 1 of 65 N"):
        solve(prototype, {"t1": 2.0}, [(0.25, (0, 0, -65.0))])
    sets = tmp_path / "sets.csv"
    sets.write_text("tension_t1,young_modulus,load_X,load_fx,load_fy,load_fz\n"
                    "2,2e6,0.25,0,0,-65\n2,1e6,0.25,0,0,-65\n")
    with pytest.raises(ValueError, match="set 2: the load of 65 N"):
        read_parameter_sets(sets, prototype)
    snaps = tmp_path / "snaps.csv"
    snaps.write_text("tension_t1,tension_t2,tension_t3,displacement_t1,load_X,load_fx,load_fy,"
                     "load_fz\n2,0,0,-0.003,0.25,0,0,-65\n")
    with pytest.raises(ValueError, match="snapshot row 1: the load of 65 N"):
        read_snapshots(snaps, prototype)
    with pytest.raises(ValueError, match="sample 2: point force 1 of 65 N"):
        solve_batch(prototype, np.full((2, 3), 1.0),
                    [(0.25, np.array([[0, 0, -0.5], [0, 0, -65.0]]))])


def test_a_length_noise_in_millimetres_is_refused(prototype, tmp_path):
    """A length read-out noise of 0.1 (0.1 mm typed as metres: 40 % of a tendon's length) is
    refused on the command line (simulate's and estimate's) and in Python (an estimate, the
    live estimator, a calibration)."""
    for args in (["simulate", PROTOTYPE, "--tension", "t1=2", "--duration", "0.5",
                  "--noise-length", "0.1", "-o", tmp_path / "sim.csv"],
                 ["estimate", PROTOTYPE, "--displacement", "t1=-0.003", "--tension", "t1=2",
                  "--unknown", "0.25,0,0,-1", "--length-noise", "0.1"]):
        p = cli(*args)
        assert p.returncode == 1 and "lengths are in metres" in p.stderr, p.stderr
    assert list(tmp_path.iterdir()) == []
    prob = problem(prototype, ["t1"], [PointForceUnknown(0.25, (0, 0, -1))])
    with pytest.raises(ValueError, match="of the shortest tendon's length"):
        estimate(prototype, {"t1": -0.003}, {"t1": 2.0}, [PointForceUnknown(0.25, (0, 0, -1))],
                 noise=Noise(length=0.1))
    with pytest.raises(ValueError, match="of the shortest tendon's length"):
        OnlineEstimator(prob, Noise(length=0.05))
    with pytest.raises(ValueError, match="of the shortest tendon's length"):
        identify(prototype, [Snapshot(dict(t1=2.0, t2=0.0, t3=0.0),
                                      displacements={"t1": -0.003})], length_noise=0.1)
    assert OnlineEstimator(prob, Noise(length=1e-3)).noise.length == 1e-3


def test_time_stamps_in_milliseconds_are_caught(prototype, tmp_path):
    """A log stamped in ms (rows 10 s apart as seconds) is refused for a motion (--dynamic,
    a damping fit) on the command line and in Python; a tension schedule in ms is simulated
    with a note that only its start falls within --duration."""
    from tendonsense.identification import identify_damping
    from tendonsense.logs import estimate_readings
    from tendonsense.readings import read_readings
    log = tmp_path / "ms.csv"
    log.write_text("time,tension_t1,tension_t2,tension_t3,displacement_t1\n"
                   + "".join(f"{10 * k},2,0,0,-0.003\n" for k in range(5)))
    for args in (["estimate", PROTOTYPE, "--readings", log, "--unknown", "0.25,0,0,-1",
                  "--dynamic", "-o", tmp_path / "e.csv"],
                 ["identify", PROTOTYPE, "--readings", log, "-o", tmp_path / "f.toml"]):
        p = cli(*args)
        assert p.returncode == 1 and "rows 10 s apart" in p.stderr, p.stderr
    measured, samples = read_readings(log, prototype)
    with pytest.raises(ValueError, match="not seconds"):
        identify_damping(prototype, samples)
    with pytest.raises(ValueError, match="not seconds"):
        estimate_readings(prototype, measured, samples, [PointForceUnknown(0.25, (0, 0, -1))],
                          dynamic=True)
    assert not (tmp_path / "e.csv").exists() and not (tmp_path / "f.toml").exists()
    # a 1 kHz log in ms: rows exactly 1 apart (it was taken, and a damping fit on it ran for
    # minutes)
    khz = tmp_path / "khz.csv"
    khz.write_text("time,tension_t1,tension_t2,tension_t3,displacement_t1\n"
                   + "".join(f"{k},2,0,0,-0.003\n" for k in range(5)))
    with pytest.raises(ValueError, match="rows 1 s apart"):
        identify_damping(prototype, read_readings(khz, prototype)[1])
    schedule = tmp_path / "ms_ramp.csv"
    schedule.write_text("time,tension_t1\n0,1.9\n500,4.78\n1500,1.9\n")
    p = cli("simulate", PROTOTYPE, "--tensions", schedule, "--duration", "0.05", "-o",
            tmp_path / "sim.csv")
    assert p.returncode == 0 and "its second row is at 500 s, after --duration" in p.stderr


def test_a_motion_out_of_time_order_is_refused(prototype, tmp_path):
    """Rows in reverse order, or a stamp twice, are refused for a motion (--dynamic, a damping
    fit) up front, in one line naming the row, on the command line and in Python."""
    from tendonsense.identification import identify_damping
    from tendonsense.logs import estimate_readings
    from tendonsense.readings import read_readings
    for name, times, row in (("backwards", [0.04, 0.03, 0.02, 0.01], 2),
                             ("twice", [0, 0.01, 0.01, 0.02], 3)):
        log = tmp_path / f"{name}.csv"
        log.write_text("time,tension_t1,tension_t2,tension_t3,displacement_t1\n"
                       + "".join(f"{t},2,0,0,-0.003\n" for t in times))
        for args in (["estimate", PROTOTYPE, "--readings", log, "--unknown", "0.25,0,0,-1",
                      "--dynamic", "-o", tmp_path / "e.csv"],
                     ["identify", PROTOTYPE, "--readings", log, "-o", tmp_path / "f.toml"]):
            p = cli(*args)
            assert p.returncode == 1 and f"row {row}: time" in p.stderr, p.stderr
            assert "in time order" in p.stderr and len(p.stderr.strip().splitlines()) == 1
        if name == "backwards":  # any log, static too (its friction follows the rows)
            with pytest.raises(ValueError, match=f"row {row}: time .* in time order"):
                read_readings(log, prototype)
            continue
        measured, samples = read_readings(log, prototype)
        with pytest.raises(ValueError, match="in time order"):
            identify_damping(prototype, samples)
        with pytest.raises(ValueError, match="in time order"):
            estimate_readings(prototype, measured, samples,
                              [PointForceUnknown(0.25, (0, 0, -1))], dynamic=True)
    assert not (tmp_path / "e.csv").exists() and not (tmp_path / "f.toml").exists()


def test_many_logs_in_motion_on_a_robot_without_damping_say_so(tmp_path):
    """--dynamic over several logs on a robot without damping notes, as over one log, that it
    filters the quasi-static model (it said nothing)."""
    for name in ("a", "b"):
        (tmp_path / f"{name}.csv").write_text(
            "time,tension_t1,tension_t2,tension_t3,displacement_t1\n"
            + "".join(f"{10 * k},2,0,0,-0.003\n" for k in range(3)))
    (tmp_path / "out").mkdir()
    p = cli("estimate", PROTOTYPE, "--readings", tmp_path / "*.csv", "--unknown",
            "0.25,0,0,-1", "--dynamic", "-o", f"{tmp_path / 'out'}/")
    assert p.stderr.count("has no [rod] damping: --dynamic filters the quasi-static model") == 1
    assert "NoDampingWarning" not in p.stderr  # the library's warning: said once, above
    assert p.returncode == 1 and p.stderr.count("rows 10 s apart") == 2, p.stderr


def test_estimation_in_motion_on_a_robot_without_damping_warns_in_python(prototype, tmp_path):
    """The command line notes that --dynamic on a robot without damping filters the
    quasi-static model; the Python API said nothing: the estimator in motion warns
    (:class:`~tendonsense.inputs.NoDampingWarning`), many logs once, a damped robot not."""
    from tendonsense.distributed import estimate_logs
    tip = [PointForceUnknown(0.25, (0, 0, -1))]
    with pytest.warns(inputs.NoDampingWarning, match="no \\[rod\\] damping"):
        OnlineEstimator(problem(prototype, ["t1"], tip), dynamic=True)
    damped = load_robot(ROOT / "examples" / "paper_prototype_damped.toml")
    with warnings.catch_warnings():
        warnings.simplefilter("error", inputs.NoDampingWarning)
        OnlineEstimator(problem(damped, ["t1"], tip), dynamic=True)
        OnlineEstimator(problem(prototype, ["t1"], tip))  # at rest: no damping needed
    logs = []
    for name in ("a", "b"):
        logs.append(tmp_path / f"{name}.csv")
        logs[-1].write_text("time,tension_t1,tension_t2,tension_t3,displacement_t1\n"
                            + "".join(f"{0.01 * k},2,0,0,-0.003\n" for k in range(3)))
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        (tmp_path / "out").mkdir()
        summaries = estimate_logs(None, prototype, logs, tmp_path / "out", tip, dynamic=True)
    assert [s.error for s in summaries] == [None, None]
    assert [w.category for w in said] == [inputs.NoDampingWarning], [str(w.message) for w in said]


def test_a_column_twice_is_named_and_a_schedule_has_a_value_per_time(prototype, tmp_path):
    from tendonsense.readings import read_parameter_sets, read_snapshots, read_tension_schedule
    for read, header in ((read_tension_schedule, "time,tension_t1,tension_t1"),
                         (read_parameter_sets, "tension_t1,tension_t1"),
                         (read_snapshots, "tension_t1,tension_t2,tension_t3,tension_t1,"
                                          "displacement_t1")):
        path = tmp_path / "f.csv"
        path.write_text(header + "\n" + ",".join(["1"] * len(header.split(","))) + "\n")
        with pytest.raises(ValueError, match="column 'tension_t1' appears twice"):
            read(path, prototype)
    with pytest.raises(ValueError, match="tension t1: 2 times and 3 values"):
        simulate(prototype, {"t1": ([0.0, 0.7], [1.9, 4.78, 1.9])}, duration=0.1)


def test_a_sliding_column_in_another_vocabulary_and_one_log_as_a_path(prototype, tmp_path):
    """A sliding column of other words ('pull') is refused as a whole (every row would be
    skipped); a capitalised direction is read on the command line as in a log; estimate_logs
    given one path (not a list) says what it expects."""
    from tendonsense.distributed import estimate_logs
    from tendonsense.readings import read_readings
    log = tmp_path / "sl.csv"
    log.write_text("time,tension_t1,tension_t2,tension_t3,displacement_t1,sliding_t1\n"
                   + "".join(f"{0.01 * k},2,0,0,-0.003,pull\n" for k in range(5)))
    with pytest.raises(ValueError, match="column sliding_t1: 5 of 5 rows are not in, out or"):
        read_readings(log, prototype)
    p = cli("solve", PROTOTYPE, "--tension", "t1=2", "--sliding", "t1=Out", "--json")
    assert p.returncode == 0 and json.loads(p.stdout)["converged"]
    with pytest.raises(ValueError, match="logs is a list of paths"):
        estimate_logs(None, prototype, str(log), tmp_path, [PointForceUnknown(0.25, (0, 0, -1))])


def test_a_sweeps_and_a_schedules_loads_are_bounded_with_their_own_modulus(prototype,
                                                                          tmp_path):
    """--point-force on a sweep is bounded by each set's E, before JAX (15 N at E/4 breaks the
    rule: refused naming the set; 50 N at 2 E does not); every row of a simulated load's
    schedule is bounded, not only its first; a simulation's length read-out noise too."""
    sets = tmp_path / "sets.csv"
    sets.write_text("tension_t1,young_modulus\n1,1e6\n1,0.25e6\n")
    rc, err, jax_loaded = refused_before_jax("sweep", PROTOTYPE, sets, "-o",
                                             tmp_path / "r.csv", "--point-force=0.25,0,0,-15")
    assert rc == 1 and "set 2: --point-force 1 of 15 N" in err and not jax_loaded, err
    sets.write_text("tension_t1,young_modulus\n1,2e6\n")
    p = cli("sweep", PROTOTYPE, sets, "-o", tmp_path / "r.csv", "--point-force=0.25,0,0,-50")
    assert p.returncode == 0, p.stderr
    with pytest.raises(ValueError, match="point force 1 of 65 N"):
        simulate(prototype, {"t1": 1.0}, [(0.25, ([0.0, 0.1], [[0, 0, 0], [0, 0, -65.0]]))],
                 duration=0.02)
    sim = simulate(prototype, {"t1": 1.0}, duration=0.02)
    with pytest.raises(ValueError, match="lengths are in metres"):  # 0.1 mm typed as 0.1
        sim.readings(noise_length=0.1)
    assert "robot" not in repr(sim) and sim.readings(noise_length=1e-4)["time"].size == 3


def test_a_run_that_compiles_says_so_once_on_a_terminal(tmp_path):
    """A first run on an empty cache compiles for seconds: on a terminal it says so once (not
    taken for a hang); a run that loads its programs, or whose stderr is not a terminal, says
    nothing."""
    code = ("import io, sys\nfrom tendonsense.cli import main\n"
            "class Err(io.StringIO):\n    def isatty(self):\n        return TTY\n"
            "err = sys.stderr = Err()\nrc = main(sys.argv[1:])\n"
            "sys.__stdout__.write(f'\\n@@{rc}\\n' + err.getvalue())\n")
    args = ("fk", PROTOTYPE, "--displacement", "t1=-0.01")

    def run(cache, tty):
        env = dict(os.environ, TENDONSENSE_CACHE_DIR=str(tmp_path / cache))
        p = subprocess.run([sys.executable, "-c", code.replace("TTY", str(tty)), *args],
                           capture_output=True, text=True, timeout=300, env=env)
        rc, *err = p.stdout.rsplit("\n@@", 1)[-1].split("\n", 1)
        assert rc == "0" and p.stderr == "", p.stdout + p.stderr
        return err[0] if err else ""

    first = run("a", True)
    assert first.count("compiling") == 1 and str(tmp_path / "a") in first, first
    assert run("a", True) == ""  # loaded from the cache
    assert run("b", False) == ""  # compiled, but not on a terminal


def test_a_static_log_in_time_order_and_a_stream_row_out_of_it(tmp_path):
    """Two logs joined (time going back) are refused as a file, named by the row, before
    JAX; a live stream skips and marks such a row and goes on."""
    rows = (ROOT / "examples" / "tutorial" / "readings.csv").read_text().splitlines()
    joined = tmp_path / "joined.csv"
    joined.write_text("\n".join([*rows[:4], rows[1], rows[4]]) + "\n")
    rc, err, jax_loaded = refused_before_jax("estimate", PROTOTYPE, "--readings", joined,
                                             "--unknown", "0.25,0,0,-1", "-o",
                                             tmp_path / "e.csv")
    assert rc == 1 and not jax_loaded and len(err.splitlines()) == 1, err
    assert "row 4: time 0 s is before the row before (0.04 s)" in err
    assert "in time order" in err and not (tmp_path / "e.csv").exists()
    p = cli("estimate", PROTOTYPE, "--readings", "-", "--unknown", "0.25,0,0,-1",
            stdin=joined.read_text())
    out = list(csv.DictReader(p.stdout.splitlines()))
    assert p.returncode == 3 and len(out) == 5, p.stderr
    assert [r["converged"] for r in out] == ["true"] * 3 + ["false", "true"]
    assert out[3]["note"] == "skipped: time 0 s is before the row before (0.04 s)"


def test_every_error_line_has_one_form(tmp_path):
    """A usage slip, an input slip and a parser's own error: ``tendonsense COMMAND: error:``
    (``tendonsense: error:`` before a command is known)."""
    for args, status, line in (
            (("solve", PROTOTYPE, "--tension", "t1=2", "--tension", "t1=3"), 2,
             "tendonsense solve: error: --tension t1 given twice (2 and 3)"),
            (("solve", PROTOTYPE, "--plot", "a.png", "--plot", "b.png"), 2,
             "tendonsense solve: error: --plot given twice"),
            (("fk", PROTOTYPE, "--displacement", "t1=-5"), 1,
             "tendonsense fk: error: displacement t1 = -5 m pulls in more"),
            (("bogus",), 2, "tendonsense: error: argument COMMAND: invalid choice"),
            (("sweep", PROTOTYPE, "sets.csv", "-o", "r.csv", "--plot", "r.png"), 2,
             "tendonsense sweep: error: unrecognized arguments: --plot r.png (see tendonsense "
             "sweep --help)")):
        rc, err, _ = refused_before_jax(*args, cwd=tmp_path)
        assert rc == status and err.startswith(line) and len(err.splitlines()) == 1, err


def test_a_simulation_ends_at_its_duration_and_says_a_coarse_step(prototype, tmp_path):
    """--output-dt that does not divide --duration: the last row at the duration (not short
    of it); a step longer than the run refused before JAX; a step too long for the rod's
    relaxation time (τ/5) said, on standard error and as a Python warning."""
    damped = ROOT / "examples" / "paper_prototype_damped.toml"
    rc, err, jax_loaded = refused_before_jax("simulate", damped, "--tension", "t1=2",
                                             "--duration", "0.1", "--max-step", "0.5", "-o",
                                             tmp_path / "s.csv")
    assert rc == 1 and not jax_loaded and "--max-step 0.5 s is longer than --duration" in err
    p = cli("simulate", damped, "--tension", "t1=2", "--duration", "0.1", "--output-dt",
            "0.03", "--max-step", "0.01", "-o", tmp_path / "s.csv")
    assert p.returncode == 0 and "simulated 0.1 s, 5 rows every 0.03 s (the last after 0.01 " \
                                 "s)" in p.stdout, p.stdout + p.stderr
    assert p.stderr.startswith("tendonsense simulate: warning: a step of 0.01 s is longer "
                               "than 0.2 of the rod's relaxation time (τ = 3η/E = 0.03 s)")
    times = [float(r["time"]) for r in csv.DictReader(open(tmp_path / "s.csv"))]
    assert times == [0.0, 0.03, 0.06, 0.09, 0.1]
    from tendonsense.robot import load_robot
    with pytest.warns(UserWarning, match="resolved coarsely"):
        sim = simulate(load_robot(damped), {"t1": 2.0}, duration=0.1, output_dt=0.03,
                       max_step=0.01)
    assert sim.time[-1] == 0.1 and sim.time.size == 5


def test_a_simulation_from_equilibrium_starts_with_its_tendons_friction(tmp_path):
    """simulate --from-equilibrium --sliding t1=out starts at the paid-out equilibrium (as
    solve --sliding t1=out), so that a tension held constant holds the rod still (it started
    at the pulled-in one and moved 13 mm of tendon under the constant tension)."""
    damped = ROOT / "examples" / "paper_prototype_damped.toml"
    p = cli("simulate", damped, "--tension", "t1=1.9", "--sliding", "t1=out",
            "--from-equilibrium", "--duration", "0.1", "--output-dt", "0.05", "--max-step",
            "0.01", "-o", tmp_path / "s.csv")
    assert p.returncode == 0, p.stderr
    y = [float(r["displacement_t1"]) for r in csv.DictReader(open(tmp_path / "s.csv"))]
    paid_out = solve(load_robot(damped), {"t1": 1.9}, sliding={"t1": "out"})
    pulled_in = solve(load_robot(damped), {"t1": 1.9})
    assert abs(paid_out.displacements["t1"] - pulled_in.displacements["t1"]) > 5e-3
    assert y[0] == pytest.approx(paid_out.displacements["t1"], abs=1e-9)
    assert max(abs(v - y[0]) for v in y) < 1e-5, y


def test_a_slack_tendons_sliding_direction_is_said_to_change_nothing():
    """solve --sliding t2=out where t2 is slack: the result as without it, and a note that
    the direction changes nothing (estimate refuses such a tendon stuck); none for t1."""
    p = cli("solve", PROTOTYPE, "--tension", "t1=2", "--sliding", "t2=out", "--sliding",
            "t1=out")
    assert p.returncode == 0, p.stderr
    assert ("tendonsense solve: note: --sliding t2=out: t2 is slack (0 N), its friction "
            "changes nothing (another tendon meant?)") in p.stderr.splitlines()
    assert "t1 is slack" not in p.stderr
    assert p.stdout == cli("solve", PROTOTYPE, "--tension", "t1=2", "--sliding",
                           "t1=out").stdout
    p = cli("fk", PROTOTYPE, "--displacement", "t1=-0.01", "--sliding", "t1=out")
    assert p.returncode == 0 and "slack" not in p.stderr, p.stderr  # t1 measured: pulled


def test_a_length_off_the_rod_in_millimetres_says_the_unit():
    """X = 250 on a 0.25 m rod (millimetres typed as metres) says lengths are in metres; a
    slip within ten rod lengths (0.3 m) does not guess a unit."""
    assert inputs.outside_rod("load_X", 250.0, 0.25).endswith("(lengths are in metres)")
    assert inputs.outside_rod("X", 0.3, 0.25) == "X = 0.3 m is outside the rod [0, 0.25 m]"
    assert "metres" not in inputs.outside_rod("X", -250.0, 0.25)


def test_a_coordinate_that_rounds_to_zero_is_printed_without_a_sign_slip():
    from tendonsense.cli import _signed
    assert [_signed(v, 4) for v in (-1e-7, 0.0, -0.00006, 0.12345)] == [
        "+0.0000", "+0.0000", "-0.0001", "+0.1235"]


def test_a_figure_or_fitted_file_of_the_wrong_kind_is_refused_before_computing(tmp_path):
    """--plot a.txt (matplotlib writes no .txt) and identify -o fitted.png (TOML under an
    image's name): refused before JAX, nothing written; a figure in another format drawn."""
    snaps = ROOT / "examples" / "tutorial" / "snapshots.csv"
    damped = ROOT / "examples" / "paper_prototype_damped.toml"
    for args, why in (
            (("solve", PROTOTYPE, "--tension", "t1=2", "--plot", "a.txt"),
             "--plot a.txt: .txt is not a figure format"),
            (("identify", PROTOTYPE, "--snapshots", snaps, "-o", "f.toml", "--plot", "c.txt"),
             "--plot c.txt: .txt is not a figure format"),
            (("simulate", damped, "--tension", "t1=2", "--duration", "0.1", "-o", "s.csv",
              "--plot", "m.txt"), "--plot m.txt: .txt is not a figure format"),
            (("identify", PROTOTYPE, "--snapshots", snaps, "-o", "fitted.png"),
             "-o/--fitted-robot fitted.png: the fitted robot is a robot file, written as "
             "TOML")):
        rc, err, jax_loaded = refused_before_jax(*args, cwd=tmp_path)
        assert rc == 1 and why in err and not jax_loaded and len(err.splitlines()) == 1, err
    assert list(tmp_path.iterdir()) == []
    p = cli("solve", PROTOTYPE, "--tension", "t1=2", "--plot", "a.PDF", cwd=tmp_path)
    assert p.returncode == 0 and (tmp_path / "a.PDF").read_bytes().startswith(b"%PDF")


def test_a_spreadsheets_byte_order_mark_is_read_and_other_text_refused(prototype, tmp_path):
    """A CSV saved as "CSV UTF-8" (a byte-order mark before the header) reads as without it;
    a file that is not UTF-8 is refused with one line naming it."""
    from tendonsense.readings import read_parameter_sets, read_readings
    plain = (ROOT / "examples" / "tutorial" / "readings.csv").read_text()
    marked = tmp_path / "marked.csv"
    marked.write_bytes("\ufeff".encode() + plain.replace("\n", "\r\n").encode())
    assert read_readings(marked, prototype) == read_readings(
        ROOT / "examples" / "tutorial" / "readings.csv", prototype)
    sets = tmp_path / "sets.csv"
    sets.write_bytes(b"\xef\xbb\xbftension_t1\n2\n")
    assert len(read_parameter_sets(sets, prototype).rows) == 1
    latin = tmp_path / "latin.csv"
    latin.write_bytes(b"time,tension_t1\n0,1.9\n0.5,2\xb0\n")
    rc, err, jax_loaded = refused_before_jax("simulate", PROTOTYPE, "--tensions", latin,
                                             "--duration", "1", "-o", tmp_path / "s.csv")
    assert rc == 1 and not jax_loaded and len(err.splitlines()) == 1, err
    assert f"{latin}: not UTF-8 text: save it as CSV in UTF-8" in err


def test_a_damping_fit_names_the_rows_it_leaves_out(tmp_path):
    """identify --readings with rows the reader skips (a negative tension): each named on
    standard error, as estimate --readings does, not left out silently."""
    log = tmp_path / "step.csv"
    log.write_text("time,tension_t1,tension_t2,tension_t3,displacement_t1\n"
                   "0,1.9,0,0,-0.001\n0.01,-1.9,0,0,-0.001\n0.02,2.1,0,0,-0.0012\n"
                   "0.03,-2.2,0,0,-0.0013\n0.04,2.2,0,0,-0.0013\n")
    p = cli("identify", ROOT / "examples" / "paper_prototype_damped.toml", "--readings", log,
            "--param", "damping", cwd=tmp_path)
    lines = p.stderr.splitlines()
    assert lines[0] == (f"tendonsense: {log}: row 2 skipped: tension t1 = -1.9 N is negative "
                        f"(a tendon cannot push; slack is 0)")
    assert lines[1].startswith(f"tendonsense: {log}: row 4 skipped: tension t1 = -2.2 N")
    assert f"from {log} (3 rows, 2 skipped)" in p.stdout  # (too short a log to pin it down)


def test_an_undamped_simulation_says_it_rings(tmp_path):
    """simulate on a robot without damping: a note on standard error (its log rings on);
    with damping none."""
    for robot, noted in ((PROTOTYPE, True),
                         (ROOT / "examples" / "paper_prototype_damped.toml", False)):
        p = cli("simulate", robot, "--tension", "t1=2", "--duration", "0.02", "-o",
                tmp_path / "s.csv")
        assert p.returncode == 0, p.stderr
        assert ("has no damping ([rod] damping = 0): nothing takes the motion's energy out"
                in p.stderr) == noted, p.stderr


def test_the_figure_is_written_when_the_reader_of_standard_output_goes_away(tmp_path):
    """``solve … --plot s.png | true``: the printing stopped at a closed pipe before the
    figure was drawn, so no figure and no word; the figure now comes first."""
    cmd = [sys.executable, "-m", "tendonsense.cli", "solve", str(PROTOTYPE), "--tension",
           "t1=2", "--plot", str(tmp_path / "s.png")]
    p = subprocess.run(" ".join(f"'{c}'" for c in cmd) + " | true", shell=True,
                       capture_output=True, text=True)
    assert p.returncode == 0 and (tmp_path / "s.png").stat().st_size > 5000, p.stderr


def test_a_log_that_starts_with_a_release_is_noted(prototype, tmp_path):
    """The tutorial's log cut at 4 s, in the middle of t1's release: its first rows read the
    friction of a pull (12.6 gF for 20 gF, 25 σ off) without a word. The file log says so
    (and each of many logs in its summary); the whole log, which starts with a pull, and the
    cut one whose first row gives t1's direction, do not."""
    from tendonsense.logs import estimate_file
    from tendonsense.readings import read_readings, released_at_start
    rows = (ROOT / "examples" / "tutorial" / "readings.csv").read_text().splitlines()
    cut = tmp_path / "cut.csv"
    cut.write_text("\n".join([rows[0]] + rows[201:260]) + "\n")
    note = released_at_start(read_readings(cut, prototype)[1], prototype)
    assert note.startswith("t1's tension falls from the log's first row (2.489 N at row 1")
    assert released_at_start(read_readings(ROOT / "examples" / "tutorial" / "readings.csv",
                                           prototype)[1], prototype) == ""
    given = tmp_path / "given.csv"
    given.write_text("\n".join([rows[0] + ",sliding_t1", rows[201] + ",stuck"]
                               + [r + "," for r in rows[202:260]]) + "\n")
    assert released_at_start(read_readings(given, prototype)[1], prototype) == ""
    p = cli("estimate", PROTOTYPE, "--readings", cut, "--unknown", "0.25,0,0,-1", "-o",
            tmp_path / "o.csv")
    assert p.returncode == 0 and f"tendonsense: {cut}: note: {note}" in p.stderr
    # a note only once every check passed (it came before the error of an output path)
    p = cli("estimate", PROTOTYPE, "--readings", cut, "--unknown", "0.25,0,0,-1", "-o", cut)
    assert p.returncode == 1 and len(p.stderr.strip().splitlines()) == 1, p.stderr
    assert "would overwrite an input" in p.stderr
    assert estimate_file(prototype, cut, tmp_path / "o2.csv", [TIP]).note == note
    # a slack tendon's sensor offset falling (t2 at 12 then 8 mN beside t1 pulled) is no
    # release
    offset = tmp_path / "offset.csv"
    offset.write_text("\n".join([rows[0]] + [r.replace(",0,0,", f",{t2},0,") for r, t2 in
                                             zip(rows[1:60], [0.012, 0.008] * 30)]) + "\n")
    samples = read_readings(offset, prototype)[1]
    assert samples[1].tensions["t2"] == 0.008
    assert released_at_start(samples, prototype) == ""
    # a live stream says the same, once, at the row where the tension has fallen (it said
    # nothing)
    from tendonsense.readings import ReleaseWatch

    def watched(path):
        watch = ReleaseWatch(prototype)
        return [n for s in read_readings(path, prototype)[1] if (n := watch(s))]

    assert watched(cut) == [note]
    assert watched(ROOT / "examples" / "tutorial" / "readings.csv") == watched(given) == \
        watched(offset) == []
    p = cli("estimate", PROTOTYPE, "--readings", "-", "--unknown", "0.25,0,0,-1",
            stdin=cut.read_text())
    assert p.stderr.count(f"tendonsense: <stdin>: note: {note}") == 1, p.stderr


def test_a_simulation_that_did_not_converge_leaves_its_shape_empty(tmp_path):
    """A sample simulate could not solve was written as the straight rod (its last iterate),
    which the estimator then read as a converged 0.11 N for 30 N: its lengths and markers are
    empty, the estimator skips it, and the lines at the end are the last converged sample's."""
    robot = tmp_path / "short.toml"
    robot.write_text((ROOT / "examples" / "paper_prototype_damped.toml").read_text()
                     + "\n[solver]\nmax_iterations = 2\n")
    log = tmp_path / "sim.csv"
    p = cli("simulate", robot, "--tension", "t1=2", "--point-force", "0.25,0,0,-30",
            "--duration", "0.05", "--no-inertia", "-o", log)
    assert p.returncode == 3 and "marker tip at t = 0 s, the last converged sample" in p.stdout
    assert "NOT CONVERGED at 5 of 6 samples" in p.stdout and "are empty in" in p.stdout
    rows = list(csv.DictReader(log.open()))
    assert rows[0]["displacement_t1"] and rows[0]["marker_tip_z"]
    assert all(r["displacement_t1"] == r["marker_tip_z"] == "" and r["tension_t1"] == "2.0"
               for r in rows[1:])
    p = cli("estimate", robot, "--readings", log, "--unknown", "0.25,0,0,-1", "-o",
            tmp_path / "o.csv")
    assert p.returncode == 3 and "5 skipped" in p.stdout
    assert b"\r" not in log.read_bytes() + (tmp_path / "o.csv").read_bytes()


def test_two_loads_the_readings_cannot_tell_apart_are_said_to_be_confounded(prototype):
    """Two forces 10 mm apart read by three tendons: each one's 1-σ band is many times what
    it is alone and every path says the two are confounded (a combination is fixed, not each);
    forces the readings do separate carry no such note."""
    near = [TIP, PointForceUnknown(0.24, (0, 0, -1))]
    apart = [TIP, PointForceUnknown(0.15, (0, 1, 0))]
    T = {"t1": 2.1, "t2": 0.5, "t3": 0.5}
    y = solve(prototype, T, [(0.25, (0, 0, -0.1))]).displacements
    r = estimate(prototype, y, T, near)
    assert r.converged and min(r.sigma) > 100 * estimate(prototype, y, T, [TIP]).sigma[0]
    assert "confounded: magnitudes 1 and 2 (correlation -1.0000)" in r.extra["note"]
    assert "confounded" not in estimate(prototype, y, T, apart).extra.get("note", "")
    # a log on the compiled scan, the online estimator and its stream
    prob = problem(prototype, list(y), near)
    online = OnlineEstimator(prob)
    for e in [*estimate_series(prob, [y] * 3, [T] * 3), online.update(y, T),
              online.update(y, T)]:
        assert e.converged and e.note.startswith("confounded: magnitudes 1 and 2"), e.note
    assert not any(e.note for e in estimate_series(problem(prototype, list(y), apart), [y] * 3,
                                                   [T] * 3))


def test_a_force_beyond_a_tonne_is_written_in_powers_of_ten():
    from tendonsense.units import newtons
    assert newtons(0.0759, 0.0027) == "0.0759 N (7.7 gF) ± 0.0027 N (0.3 gF)"
    assert newtons(0.044, 5.1e5) == "0.044 N (4.5 gF) ± 5.1e+05 N (5.2e+07 gF)"


def test_a_number_and_its_limit_are_written_apart():
    """identify's warning read "1.2 times the noise assumed, where noise explains at most 1.2
    times": a ratio and its limit to the digits that tell them apart."""
    from tendonsense.units import apart
    assert apart(1.2404, 1.2370) == ("1.240", "1.237")
    assert apart(1.23, 1.18) == ("1.23", "1.18")
    assert apart(1.27, 1.18) == ("1.3", "1.2") and apart(7.0, 1.2) == ("7", "1.2")
    assert apart(2.0, 2.0) == ("2.00000", "2.00000")


def test_a_sweeps_results_record_the_loads_given_beside_the_table(tmp_path):
    """A force given with --point-force acts in every set: the results say so, in columns of
    their own, and one set is one set."""
    sets = tmp_path / "sets.csv"
    sets.write_text("id,tension_t1\nonly,2.0\n")
    p = cli("sweep", PROTOTYPE, sets, "-o", tmp_path / "r.csv", "--point-force",
            "0.25,0,0,-0.1", "--quiet")
    assert p.returncode == 0, p.stderr
    assert "solved 1 parameter set: 1 converged" in p.stdout
    row, = csv.DictReader(open(tmp_path / "r.csv"))
    assert [float(row[f"point_force_1_{c}"]) for c in ("X", "fx", "fy", "fz")] == [
        0.25, 0.0, 0.0, -0.1]
    assert float(row["marker_tip_z"]) < -0.02  # the force acted


def test_a_calibration_to_small_loads_in_gram_force_is_refused_by_its_density(prototype,
                                                                                tmp_path):
    """The tutorial's snapshots with their loads (5–20 gF) typed in gF in the newton columns:
    within what a rod carries, but the fit needs a rod three times denser than osmium; it is
    refused with the reason and no robot file is written. The robot file has the same bound."""
    rows = list(csv.reader(open(ROOT / "examples" / "tutorial" / "snapshots.csv")))
    cols = [rows[0].index(c) for c in ("load_fx", "load_fy", "load_fz")]
    for row in rows[1:]:
        for i in cols:
            row[i] = row[i] and repr(float(row[i]) / 9.80665e-3)
    with open(tmp_path / "snaps.csv", "w", newline="") as fh:
        csv.writer(fh).writerows(rows)
    p = cli("identify", ROOT / "examples" / "tutorial" / "robot_guess.toml", "--snapshots",
            tmp_path / "snaps.csv", "--param", "young_modulus", "--param", "density",
            "--param", "friction", "--marker-noise", "0.0005", "-o", tmp_path / "fitted.toml")
    assert p.returncode == 1 and "is denser than any solid" in p.stderr, p.stderr
    assert "check the snapshots' units (N, m) and loads" in p.stderr
    assert not (tmp_path / "fitted.toml").exists()
    with pytest.raises(ValueError, match="density: 30000 kg/m³ is denser than any solid"):
        prototype.with_parameters(density=30000.0)


@pytest.mark.parametrize("errors", ["strict", "surrogateescape"])
def test_a_live_log_with_a_byte_that_is_not_utf8_skips_its_row(errors):
    """Whatever the locale makes of standard input: a row with a byte that is not UTF-8 is
    skipped and named, the others answered; such a header is refused in one line."""
    env = dict(os.environ, PYTHONIOENCODING=f"utf-8:{errors}")
    head = b"time,tension_t1,tension_t2,tension_t3,displacement_t1\n"
    rows = b"0,2.0,0,0,-0.0032\n0.01,2.0,0,0,-0.0032\xe9\n0.02,2.0,0,0,-0.0032\n"
    args = [sys.executable, "-m", "tendonsense.cli", "estimate", PROTOTYPE, "--readings", "-",
            "--unknown", "0.25,0,0,-1"]
    p = subprocess.run(args, input=head + rows, capture_output=True, env=env, timeout=600)
    out = list(csv.DictReader(p.stdout.decode().splitlines()))
    assert [r["converged"] for r in out] == ["true", "false", "true"], p.stderr
    assert out[1]["note"] == "skipped: not UTF-8 text: save it as CSV in UTF-8"
    assert "row 2 skipped: not UTF-8 text" in p.stderr.decode()
    p = subprocess.run(args, input=head.replace(b"_t1\n", b"_\xe91\n") + rows,
                       capture_output=True, env=env, timeout=600)
    assert p.returncode == 1 and not p.stdout
    assert p.stderr.decode().strip() == (
        "tendonsense estimate: error: <stdin>: header: not UTF-8 text: save it as CSV in UTF-8")


def test_only_a_tendon_under_tension_is_stuck_on_every_path(prototype, tmp_path):
    """A stuck tendon with no tension has no friction band (its "range" was a point, or the
    other tendons' ends): refused for a single reading, a sample of a stream or a filter, a
    log's row, and a log whose column says so throughout."""
    with pytest.raises(ValueError, match="t2 is slack"):
        estimate(prototype, {"t1": -0.005}, {"t1": 2.0}, [TIP], sliding={"t2": "stuck"})
    for dynamic in (False, True):
        with warnings.catch_warnings():  # (no damping: the filter's quasi-static model)
            warnings.simplefilter("ignore", inputs.NoDampingWarning)
            online = OnlineEstimator(problem(prototype, ["t1"], [TIP]), dynamic=dynamic)
        got = online.update({"t1": -0.005}, {"t1": 2.0}, 0.0, {"t2": "stuck"})
        assert not got.converged and "t2 is slack" in got.note
    rows = (ROOT / "examples" / "tutorial" / "readings.csv").read_text().splitlines()
    log = tmp_path / "log.csv"
    log.write_text("\n".join([rows[0] + ",sliding_t2"] + [r + ",stuck" for r in rows[1:]]))
    rc, err, jax_loaded = refused_before_jax("estimate", PROTOTYPE, "--readings", log,
                                             "--unknown", "0.25,0,0,-1", "-o", tmp_path / "o.csv")
    assert rc == 1 and "column sliding_t2: 300 of 300 rows say stuck where t2 is slack" in err
    assert not jax_loaded and not (tmp_path / "o.csv").exists()
    from tendonsense.readings import read_readings
    log.write_text("\n".join([rows[0] + ",sliding_t2", rows[1] + ",stuck"]
                             + [r + "," for r in rows[2:]]))
    samples = read_readings(log, prototype)[1]
    assert samples[0].error.startswith("column sliding_t2: stuck: t2 is slack")
    assert not any(s.error for s in samples[1:])
    # a live stream is not refused for its first rows: each such row is skipped
    head = "\n".join([rows[0] + ",sliding_t2"] + [r + ",stuck" for r in rows[1:4]]
                     + [r + "," for r in rows[4:8]]) + "\n"
    p = cli("estimate", PROTOTYPE, "--readings", "-", "--unknown", "0.25,0,0,-1", stdin=head)
    assert p.returncode == 3 and p.stderr.count("t2 is slack") == 3, p.stderr
    assert len(p.stdout.strip().splitlines()) == 1 + 7


def test_stuck_rows_with_a_force_of_unknown_location_are_refused(prototype, tmp_path):
    """A file log (its force searched sample by sample) took a stuck row as pulled in without a
    word, where a stream marks each such row: the log is refused, naming the row."""
    from tendonsense.logs import estimate_file, estimate_readings
    from tendonsense.readings import read_readings
    rows = (ROOT / "examples" / "tutorial" / "readings.csv").read_text().splitlines()
    log = tmp_path / "log.csv"
    log.write_text("\n".join([rows[0] + ",displacement_t2,sliding_t1"]
                             + [r + ",-0.001," for r in rows[1:5]] + [rows[5] + ",-0.001,stuck"]
                             + [r + ",-0.001," for r in rows[6:9]]) + "\n")
    located = [PointForceUnknown(None, (0, 0, -1))]
    with pytest.raises(ValueError, match="row 5: column sliding_t1: stuck: the range over a "
                                         "friction band is estimated for forces at known"):
        estimate_readings(prototype, ["t1", "t2"], read_readings(log, prototype)[1], located)
    assert estimate_file(prototype, log, tmp_path / "o.csv", located).error.startswith(
        f"{log}: row 5: column sliding_t1: stuck")
    rc, err, jax_loaded = refused_before_jax("estimate", PROTOTYPE, "--readings", log,
                                             "--unknown", "?,0,0,-1", "-o", tmp_path / "o.csv")
    assert rc == 1 and f"{log}: row 5: column sliding_t1: stuck" in err and not jax_loaded
    assert not (tmp_path / "o.csv").exists()


def test_marker_columns_in_millimetres_are_refused(tmp_path):
    """A log's marker columns in mm (every marker hundreds of metres from the base) were
    estimated with a shape misfit of 190 m, and fitted a damping of 3e5 Pa s: the log is
    refused, as the snapshots are; a row off the robot alone is skipped."""
    from tendonsense.readings import read_readings
    from tendonsense.robot import load_robot
    rows = (ROOT / "examples" / "tutorial" / "readings.csv").read_text().splitlines()[:40]
    log = tmp_path / "log.csv"
    log.write_text("\n".join([rows[0] + ",marker_tip_x,marker_tip_y,marker_tip_z"]
                             + [r + ",245.0,0.0,-40.0" for r in rows[1:]]))
    for args in (("estimate", PROTOTYPE, "--readings", log, "--unknown", "0.25,0,0,-1", "-o",
                  tmp_path / "o.csv"),
                 ("identify", PROTOTYPE, "--readings", log, "--param", "damping",
                  "--no-inertia", "-o", tmp_path / "fit.toml")):
        rc, err, jax_loaded = refused_before_jax(*args)
        assert rc == 1 and "marker tip: 39 of 39 rows are off the robot" in err, err
        assert "positions are in metres" in err and not jax_loaded
    assert sorted(p.name for p in tmp_path.iterdir()) == ["log.csv"]
    log.write_text("\n".join([rows[0] + ",marker_tip_x,marker_tip_y,marker_tip_z",
                              rows[1] + ",245.0,0.0,-40.0"]
                             + [r + ",0.245,0.0,-0.040" for r in rows[2:]]))
    samples = read_readings(log, load_robot(PROTOTYPE))[1]
    assert "positions are in metres" in samples[0].error
    assert not any(s.error for s in samples[1:])


def test_a_length_change_only_a_pushing_tendon_makes_is_no_solution(prototype):
    """Forward kinematics with a tendon longer than it is slack: a tension below zero is no
    solution (it was reported converged at −3.03 N)."""
    r = forward_kinematics(prototype, {"t1": 0.02})
    assert not r.converged and r.tensions["t1"] < 0 and "push" in r.extra["note"]
    assert "+0.020000 m would need" in forward_kinematics(prototype, {"t1": "0.02"}).extra["note"]
    assert forward_kinematics(prototype, {"t1": 0.002}).converged  # gravity stretches t1
    p = cli("fk", PROTOTYPE, "--displacement", "t1=0.02")
    assert p.returncode == 3 and "would need it to push" in p.stdout


def test_an_estimated_force_the_model_cannot_hold_is_no_estimate(prototype, tmp_path):
    """A force estimated beyond the bound a known force is held to (half the rod's axial
    stiffness E·A): not converged, the note says why (it was 6891 N ± 210 N, converged), on
    the single path, a log and a live stream; an unknown force at the clamp and an unknown
    gravity of a weightless robot are refused before computing."""
    near = PointForceUnknown(0.001, (0, 0, -1))
    r = estimate(prototype, {"t1": -0.005}, {"t1": 2.1}, [near])
    assert not r.converged and r.magnitudes[0] > 1000 and "axial stiffness" in r.extra["note"]
    assert estimate(prototype, {"t1": -0.005}, {"t1": 2.1}, [TIP]).converged
    readings = [{"t1": -0.005}] * 2, [{"t1": 2.1}] * 2
    series = estimate_series(problem(prototype, ["t1"], [near]), *readings)
    # no estimate, and none reads as one: its magnitudes are NaN (they were 6891 N)
    assert not any(e.converged for e in series) and np.isnan(series[0].magnitudes).all()
    assert all(e.converged for e in estimate_series(problem(prototype, ["t1"], [TIP]),
                                                    *readings))
    live = OnlineEstimator(problem(prototype, ["t1"], [near])).update({"t1": -0.005},
                                                                     {"t1": 2.1})
    assert not live.converged and "axial stiffness" in live.note
    for args, words in ((("--unknown", "0,0,0,-1"), "clamped base"),
                        (("--unknown", "gravity"), "no weight")):
        robot = PROTOTYPE
        if words == "no weight":
            robot = tmp_path / "weightless.toml"
            robot.write_text(PROTOTYPE.read_text().replace("density = 1340.0", "density = 0.0"))
        code, err, jax_loaded = refused_before_jax(
            "estimate", robot, "--displacement", "t1=-0.005", "--tension", "t1=2.1", *args)
        assert code == 1 and words in err and not jax_loaded, err


def test_a_force_the_measured_tendons_cannot_see_is_named(prototype):
    """A force across the plane in which the measured tendon bends the rod (t1 bends it in
    x–z; a force along y changes t1's length at second order only): not converged, the note
    names the unknown and why, its σ unbounded (it was "relative residual 1.05e+00", σ 0),
    on the single path, a series and a live stream; a force t1 sees has no such note."""
    from tendonsense.problem import unseen
    side = PointForceUnknown(0.25, (0, 1, 0))
    r = estimate(prototype, {"t1": -0.005}, {"t1": 2.1}, [side])
    words = "does not change length with unknown 1 (the force along (0, 1, 0) at X = 0.25 m)"
    assert not r.converged and words in r.extra["note"] and np.isinf(r.sigma[0])
    assert r.to_json()["sigma"] == [None]
    readings = [{"t1": -0.005}] * 2, [{"t1": 2.1}] * 2
    assert all(words in e.note for e in estimate_series(problem(prototype, ["t1"], [side]),
                                                        *readings))
    live = OnlineEstimator(problem(prototype, ["t1"], [side])).update({"t1": -0.005},
                                                                     {"t1": 2.1})
    assert not live.converged and words in live.note
    seen = estimate(prototype, {"t1": -0.005}, {"t1": 2.1}, [TIP])
    prob = problem(prototype, ["t1"], [TIP])
    T, y = prob.readings({"t1": -0.005}, {"t1": 2.1})
    drive = prob.drive(T, y[list(prob.measured)])
    assert unseen(prob, seen.extra["x"], drive, prob.model.values) == ((), "")
    assert unseen(prob, 0 * seen.extra["x"], drive, prob.model.values) == ((), "")


def test_a_log_says_misfits_only_beyond_chance():
    """Each row's misfit test lets 0.1 % of rows through by chance: a log's summary counts
    them only where there are more than the binomial's 99.9 % quantile (4 of 3,103 rows is
    chance: the paper's Fig. 7 logs under --dynamic have 0–4); the rows keep their notes."""
    from scipy.stats import binom

    from tendonsense.logs import chance, misfit_rows
    for rows in (1, 12, 301, 3103, 10**5, 10**6):
        for p, q in ((1e-3, 0.999), (0.3, 0.5)):
            assert chance(rows, p, q) == binom.ppf(q, rows, p), (rows, p, q)
    assert misfit_rows(4, 3103) == "" and misfit_rows(1, 12) == "" and misfit_rows(0, 5) == ""
    assert misfit_rows(2, 12).startswith("2 of 12 rows: the readings disagree beyond")
    assert misfit_rows(12, 3103).startswith("12 of 3103 rows")


def test_an_overdetermined_estimate_that_misses_its_readings_says_so(prototype):
    """Three measured tendons, one unknown: readings with t1's and t2's lengths swapped are
    met to 0.77 mm RMS, far beyond their noise: the estimate (a least-squares fit) says so (it
    was 0.068 N for 0.1 N, no word); the true readings and ones off by the length noise have
    no such note."""
    T = {"t1": 2.0, "t2": 0.3, "t3": 0.3}
    y = solve(prototype, T, [(0.25, (0.0, 0.0, -0.1))]).displacements
    words = "the readings disagree beyond their noise"
    for lengths, flagged in (
            (y, False), ({"t1": y["t1"] + 1e-4, "t2": y["t2"] - 1e-4, "t3": y["t3"]}, False),
            ({"t1": y["t2"], "t2": y["t1"], "t3": y["t3"]}, True)):
        r = estimate(prototype, lengths, T, [TIP])
        assert r.converged and (words in r.extra.get("note", "")) == flagged, r.extra


def test_schedule_and_snapshot_slips_name_their_row_and_reason(tmp_path):
    """A tension schedule's time that goes back names its row (was "time must start at >= 0 s
    and increase from row to row"); a mistyped sliding word in a snapshot is not told it is
    "stuck" (was "a stuck tendon's friction is not known"); a schedule that starts after the
    run is said to hold its first row (was "only the start of its first ramp is simulated")."""
    (tmp_path / "back.csv").write_text("time,tension_t1\n0,1\n1,2\n0.5,3\n")
    code, err, _ = refused_before_jax("simulate", PROTOTYPE, "--tensions", "back.csv",
                                      "--duration", "1", "-o", "s.csv", cwd=tmp_path)
    assert code == 1 and "back.csv: row 3: time 0.5 s is not after row 2's 1 s" in err, err
    text = (ROOT / "examples" / "tutorial" / "snapshots.csv").read_text().splitlines()
    (tmp_path / "snaps.csv").write_text("\n".join(
        [text[0] + ",sliding_t1"] + [line + ",paid" for line in text[1:]]) + "\n")
    code, err, _ = refused_before_jax("identify", PROTOTYPE, "--snapshots", "snaps.csv",
                                      cwd=tmp_path)
    assert code == 1 and "'paid' is not in or out (a snapshot's tendon is pulled in or paid " \
        "out)" in err, err
    (tmp_path / "log.csv").write_text("time,tension_t1,displacement_t1,note\n0,1,-0.004,a\n"
                                      "0.01,1.1,-0.0045,\n")  # a recorded log (was refused)
    from tendonsense.readings import read_tension_schedule
    t, T = read_tension_schedule(tmp_path / "log.csv", load_robot(PROTOTYPE))["t1"]
    assert t.tolist() == [0.0, 0.01] and T.tolist() == [1.0, 1.1]
    (tmp_path / "late.csv").write_text("time,tension_t1\n5,1\n6,2\n")
    p = cli("simulate", PROTOTYPE, "--tensions", "late.csv", "--duration", "0.02", "-o",
            "s.csv", cwd=tmp_path)
    assert p.returncode == 0 and "its first row is at 5 s, not before --duration 0.02 s: the " \
        "tensions stay at that row's throughout" in p.stderr, p.stderr


def test_a_log_of_poorly_determined_magnitudes_stays_with_the_single_estimate(prototype,
                                                                             tmp_path):
    """Two forces along z (tip and mid) from three tendons that see one in-plane bending: the
    readings fix a combination of them. A log's first row landed elsewhere on that combination
    (0.168 ± 0.014 N and -1.10 ± 0.13 N for a truth of 0 and 0, where the single estimate of
    the row has 0.018 and -0.088) and later rows slid along it to unstable equilibria with
    tight bands (1.03 and -4.70 N, 67 σ off). Now the first row is the single estimate, file
    and stream, and no row is more than 4 σ from the truth."""
    import io
    from tendonsense.logs import estimate_file, stream_readings
    n = 12
    T1 = np.linspace(1.9, 4.8, n)
    out = solve_batch(prototype, {"t1": T1, "t2": 0 * T1, "t3": 0 * T1})
    rng = np.random.default_rng(7)
    y = {t: out.displacements[t] + rng.normal(0, 1e-4, n) for t in ("t1", "t2", "t3")}
    T1 = T1 * (1 + rng.normal(0, 0.005, n))
    log = tmp_path / "log.csv"
    log.write_text("tension_t1,tension_t2,tension_t3,displacement_t1,displacement_t2,"
                   "displacement_t3\n" + "".join(
                       f"{T1[k]},0,0,{y['t1'][k]},{y['t2'][k]},{y['t3'][k]}\n" for k in range(n)))
    unknowns = [TIP, PointForceUnknown(0.125, (0, 0, -1))]
    noise = Noise(tension=0.005)
    single = estimate(prototype, {t: y[t][0] for t in y}, {"t1": T1[0], "t2": 0, "t3": 0},
                      unknowns, noise=noise)
    estimate_file(prototype, log, tmp_path / "out.csv", unknowns, noise=noise)
    streamed = io.StringIO()
    stream_readings(prototype, io.StringIO(log.read_text()), streamed, unknowns, noise=noise)
    for rows in (list(csv.DictReader(open(tmp_path / "out.csv"))),
                 list(csv.DictReader(io.StringIO(streamed.getvalue())))):
        z = np.array([[float(r[f"magnitude_{i}"]) for i in (1, 2)] for r in rows])
        sigma = np.array([[float(r[f"sigma_{i}"]) for i in (1, 2)] for r in rows])
        np.testing.assert_allclose(z[0], single.magnitudes, rtol=1e-6, atol=1e-9)
        good = [r["converged"] == "true" for r in rows]
        assert sum(good) >= n - 1
        assert np.all(np.abs(z[good]) <= 4 * sigma[good]), (z, sigma)


def test_an_overdetermined_log_that_misses_its_readings_says_so(prototype, tmp_path):
    """The same test on every row of a three-tendon log (file, CLI and stream): t1's and t2's
    length columns swapped, the rows say so and the CLI counts them (the log's rows had no
    word); the true log, with its length noise, has none."""
    import io
    from tendonsense.logs import estimate_file, stream_readings
    n = 12
    T1 = np.linspace(1.5, 3.0, n)  # pulled in only: the friction the log's history says
    F = np.stack([0 * T1, 0 * T1, -np.linspace(0.05, 0.15, n)], axis=1)
    out = solve_batch(prototype, {"t1": T1, "t2": 0.3 + 0 * T1, "t3": 0.3 + 0 * T1},
                      [(0.25, F)])
    rng = np.random.default_rng(3)
    y = {t: out.displacements[t] + rng.normal(0, 1e-4, n) for t in ("t1", "t2", "t3")}
    words = "the readings disagree beyond their noise"
    for swapped in (False, True):
        a, b = ("t2", "t1") if swapped else ("t1", "t2")
        log = tmp_path / f"log_{swapped}.csv"
        log.write_text("tension_t1,tension_t2,tension_t3,displacement_t1,displacement_t2,"
                       "displacement_t3\n" + "".join(
                           f"{T1[k]},0.3,0.3,{y[a][k]},{y[b][k]},{y['t3'][k]}\n"
                           for k in range(n)))
        summary = estimate_file(prototype, log, tmp_path / "out.csv", [TIP])
        notes = [r["note"] for r in csv.DictReader(open(tmp_path / "out.csv"))]
        flagged = sum(words in note for note in notes)
        assert summary.converged == n
        # (swapped: 10 of 12, the two near 2.2 N explained by another force within the noise)
        assert flagged >= n - 3 if swapped else flagged == 0, notes
        assert (f"{flagged} of {n} rows: {words}" in summary.note) == swapped, summary.note
        streamed = io.StringIO()
        stream_readings(prototype, io.StringIO(log.read_text()), streamed, [TIP])
        notes = [r["note"] for r in csv.DictReader(io.StringIO(streamed.getvalue()))]
        assert sum(words in note for note in notes) == flagged, notes
        if swapped:
            p = cli("estimate", PROTOTYPE, "--readings", log, "--unknown", "0.25,0,0,-1",
                    "-o", tmp_path / "cli.csv")
            assert p.returncode == 0 and f"{log}: note: {flagged} of {n} rows: {words}" \
                in p.stderr, p.stderr


@pytest.mark.parametrize("edit, words", [
    (("X = 0.125\n", "X = 0.125\noffset = [0.0, 0.0, 25]\n"), "marker[0] (mid).offset: "
     "[0.0, 0.0, 25.0] is 25 m from the centre line, more than the rod is long"),
    (("", '\n[[mass]]\nname = "g"\nX = 0.1\nmass = 0.004\noffset = [0, 0, 3]\n'),
     "mass[0] (g).offset"),
    (('name = "t1"', 'name = "a=b"'), "tendon[0] (a=b).name: \"a=b\": a name is letters"),
    (('name = "mid"', 'name = "m 1"'), "marker[0] (m 1).name"),
    (("disks = 9", "disks = 100000"), "100000 disks, more than 500"),
    (("disks = 9", "disks = 1000000000"), "1000000000 disks, more than 500"),
    (('name = "t1"', 'name = "-t"'), "not starting with '-'"),
    ((None, None), "not a robot file (TOML is UTF-8 text; byte 0 is not"),
])
def test_a_robot_file_slip_of_a_new_robots_kind_is_refused(tmp_path, edit, words):
    """Offsets in millimetres (a marker 25 m off the rod was accepted, a mass 3 m off moved
    the shape), names that cannot head a column or be given as NAME=value, a disk count that
    ran out of memory (74.5 GiB), a file that is not text (its name was not said)."""
    text, path = PROTOTYPE.read_text(), tmp_path / "robot.toml"
    old, new = edit
    if old is None:
        path.write_bytes(b"\xff\xfe" + text.encode())
    else:
        path.write_text(text.replace(old, new, 1) if old else text + new)
    code, err, jax_loaded = refused_before_jax("solve", path, "--tension", "t2=1")
    assert code == 1 and words in err and str(path) in err and not jax_loaded, err
    assert len(err.splitlines()) == 1


def test_the_python_api_names_a_slip_of_its_arguments(prototype):
    """A path for a robot (was an AttributeError), a bool for a tension (was 1 N), a start of
    the wrong size, a NaN in a batch, a misspelled tendon in a live update (was 'displacement
    t1: missing')."""
    for call in (lambda: solve(str(PROTOTYPE), {"t1": 1.0}),
                 lambda: estimate(str(PROTOTYPE), {"t1": -0.005}, {"t1": 2.1}, [TIP])):
        with pytest.raises(ValueError, match="robot: a Robot, such as tendonsense.load_robot"):
            call()
    with pytest.raises(ValueError, match="tension t1: not a number: True"):
        solve(prototype, {"t1": True})
    with pytest.raises(ValueError, match=r"q0: 3 values .* 15 strain coordinates"):
        solve(prototype, {"t1": 1.0}, q0=[0.0, 0.0, 0.0])  # (was numpy's reshape error)
    with pytest.raises(ValueError, match=r"batch: sample 2: tension t1: not a finite number"):
        solve_batch(prototype, {"t1": [1.0, np.nan]})  # (was no sample, no tendon)
    live = OnlineEstimator(problem(prototype, ["t1"], [TIP]))
    assert "displacement T1: no such tendon" in live.update({"T1": -0.005}, {"t1": 2.1}).note
    assert live.update({"t1": -0.005}, {"t1": 2.1}).converged
    p = subprocess.run([sys.executable, "-m", "tendonsense", "--version"], capture_output=True,
                       text=True, timeout=60)
    assert p.returncode == 0 and p.stdout.startswith("tendonsense ")


def test_a_stream_in_motion_checks_its_stamps_and_a_log_keeps_a_row_without_its_markers(
        tmp_path):
    """--dynamic on a stream: stamps 10 s apart are refused after its first rows (a file's
    rule; was estimated, exit 0), a repeated stamp skips its row and says so (was a note
    without 'skipped'); a row whose marker cells are empty (a frame the camera missed) is
    estimated (was skipped), one with a marker's cell missing is skipped."""
    head = "time,tension_t1,tension_t2,tension_t3,displacement_t1"
    row = ",2.0,0,0,-0.0032"
    args = ("estimate", PROTOTYPE, "--readings", "-", "--unknown", "0.25,0,0,-1", "--dynamic")
    p = cli(*args, stdin="\n".join([head] + [f"{10 * k}{row}" for k in range(12)]) + "\n")
    assert p.returncode == 1 and "(its first 10 rows): rows 10 s apart" in p.stderr
    paused = [0.0] + [2.0 + 0.01 * k for k in range(11)]  # a pause at the start: a motion
    p = cli(*args, stdin="\n".join([head] + [f"{t}{row}" for t in paused]) + "\n")
    assert p.returncode == 0, p.stderr
    p = cli(*args, stdin="\n".join([head] + [f"{t}{row}" for t in (0, 0.01, 0.01, 0.02)])
            + "\n")
    out = list(csv.DictReader(p.stdout.splitlines()))
    assert [r["converged"] for r in out] == ["true", "true", "false", "true"]
    assert out[2]["note"].startswith("skipped: time 0.01 s is the row before's")
    assert "row 3 skipped" in p.stderr
    log = tmp_path / "log.csv"
    log.write_text("\n".join([head + ",marker_tip_x,marker_tip_y,marker_tip_z",
                              f"0{row},0.24,0,-0.047", f"0.01{row},,,", f"0.02{row},0.24,,-0.047"])
                   + "\n")
    p = cli("estimate", PROTOTYPE, "--readings", log, "--unknown", "0.25,0,0,-1")
    out = list(csv.DictReader(p.stdout.splitlines()))
    assert [r["converged"] for r in out] == ["true", "true", "false"]
    assert out[0]["shape_rmse"] and not out[1]["shape_rmse"]
    assert "marker_tip_y: missing value" in out[2]["note"]


def test_a_damping_fit_takes_a_row_without_its_markers(prototype, tmp_path):
    """identify --readings: a row whose marker cells are empty (a frame the camera missed)
    fits the damping to the markers the other rows have (was a KeyError: 'tip')."""
    from tendonsense.identification import identify_damping
    from tendonsense.readings import read_readings
    robot = prototype.with_parameters(damping=1000.0)
    start = solve(robot, {"t1": 1.9})
    log = tmp_path / "step.csv"
    cells = ",".join(map(repr, map(float, start.markers["tip"])))
    log.write_text("time,tension_t1,tension_t2,tension_t3,displacement_t1,marker_tip_x,"
                   "marker_tip_y,marker_tip_z\n" + "".join(
                       f"{0.01 * k},{1.9 + 0.1 * min(k, 2)},0,0,{start.displacements['t1']},"
                       f"{cells if k != 3 else ',,'}\n" for k in range(6)))
    _, samples = read_readings(log, robot)
    assert "tip" not in samples[3].markers and not samples[3].error
    fit = identify_damping(robot, samples)
    assert fit.marker_rmse is not None and np.isfinite(fit.marker_rmse)


def test_a_damping_fit_takes_the_logs_friction_direction(prototype, tmp_path, monkeypatch):
    """identify --readings: a log whose sliding_t1 column says out in every row starts at the
    paid-out equilibrium and is simulated paid out (the column was ignored: the same η as
    pulled in); directions that change along the log are refused."""
    import tendonsense.identification as identification
    from tendonsense.readings import read_readings
    robot = prototype.with_parameters(damping=1000.0)
    start = solve(robot, {"t1": 1.9}, sliding={"t1": "out"})

    def log(directions):
        path = tmp_path / "step.csv"
        path.write_text("time,tension_t1,tension_t2,tension_t3,displacement_t1,sliding_t1\n"
                        + "".join(f"{0.01 * k},{1.9 + 0.1 * min(k, 2)},0,0,"
                                  f"{start.displacements['t1']},{d}\n"
                                  for k, d in enumerate(directions)))
        return read_readings(path, robot)[1]

    class Stop(Exception):
        pass

    seen = []

    def simulated(*args, sliding=None, q0=None, **kwargs):
        seen.append((sliding, q0))
        raise Stop

    monkeypatch.setattr(identification, "simulate", simulated)
    with pytest.raises(Stop):
        identification.identify_damping(robot, log(["out"] * 6))
    assert seen[0][0] == {"t1": "out"}
    np.testing.assert_allclose(seen[0][1], start.q, atol=1e-9)
    with pytest.raises(SnapshotError, match="column sliding_t1 says in and out: the damping"):
        identification.identify_damping(robot, log(["in"] * 3 + ["out"] * 3))


@pytest.mark.parametrize("sep, words", [(";", "this one by ';'"), ("\t", "this one by tabs")])
def test_a_log_not_separated_by_commas_is_named(tmp_path, sep, words):
    """A log written with semicolons or tabs (a spreadsheet's export) is refused naming the
    separator, before JAX (it was one giant column's name)."""
    log = tmp_path / "log.csv"
    log.write_text(sep.join(["time", "tension_t1", "tension_t2", "tension_t3",
                             "displacement_t1"]) + "\n" + sep.join("0 2.1 0 0 -0.005".split())
                   + "\n")
    code, err, jax_loaded = refused_before_jax("estimate", PROTOTYPE, "--readings", log,
                                               "--unknown", "0.25,0,0,-1")
    assert code == 1 and "columns are separated by commas, " + words in err and not jax_loaded


@pytest.mark.parametrize("command, flag, header", [
    ("identify", "--snapshots", "tension_t1;tension_t2;tension_t3;marker_tip_x;marker_tip_y;"
                                "marker_tip_z"),
    ("sweep", None, "tension_t1;young_modulus"),
    ("simulate", "--tensions", "time;tension_t1")])
def test_every_table_not_separated_by_commas_is_named(tmp_path, command, flag, header):
    """A snapshot file, a sweep's sets and a tension schedule written with semicolons get the
    log's message naming the separator, before JAX (they were told of one unknown column)."""
    table = tmp_path / "table.csv"
    table.write_text(header + "\n" + ";".join(["1"] * header.count(";")) + ";2\n")
    args = [command, PROTOTYPE, *([flag] if flag else []), table, "-o", tmp_path / "out.csv"]
    if command == "simulate":
        args += ["--duration", "1"]
    code, err, jax_loaded = refused_before_jax(*args)
    assert code == 1 and "columns are separated by commas, this one by ';'" in err, err
    assert not jax_loaded


def test_a_frictionless_tendon_cannot_be_stuck(tmp_path):
    """``--sliding t1=stuck`` on a tendon without friction was a range "between X and X": it
    is refused, naming the tendon and why, before JAX."""
    robot = tmp_path / "frictionless.toml"
    robot.write_text(PROTOTYPE.read_text().replace("friction = 0.4", "friction = 0.0"))
    code, err, jax_loaded = refused_before_jax(
        "estimate", robot, "--displacement", "t1=-0.005", "--tension", "t1=2.1", "--unknown",
        "0.25,0,0,-1", "--sliding", "t1=stuck")
    assert code == 1 and "t1 has no friction (μ = 0)" in err and not jax_loaded, err


def test_a_fit_of_a_force_no_measured_tendon_sees_is_no_estimate():
    """Two tendons in the x–z plane, both measured, and an unknown force along y: the least-
    squares fit stopped at once (its gradient 0) and said "converged, 0 ± 0 N"; it is no
    estimate, named, its σ unbounded."""
    from conftest import robot_from, uniform_rod
    robot = robot_from(rod=uniform_rod(0.01, 0.25, 1e6), gravity={"acceleration": [0, 0, 0]},
                       tendon=[{"name": n, "offset_base": [0, z], "offset_tip": [0, z],
                                "friction": 0.0, "disks": 9}
                               for n, z in (("a", 0.004), ("b", -0.004))])
    T = {"a": 0.5, "b": 0.2}
    y = solve(robot, T, [(0.25, (0.0, 0.02, 0.0))]).displacements
    r = estimate(robot, y, T, [PointForceUnknown(0.25, (0, 1, 0))])
    assert not r.converged and np.isinf(r.sigma[0])
    assert "measured tendons (a, b) do not change length with unknown 1" in r.extra["note"]


def test_a_modulus_in_kilopascals_says_the_strain_is_large(prototype):
    """E typed in kPa (1000 for 1 MPa, the softest modulus a robot file takes) hangs the
    prototype 94 % longer than it is under its own weight, converged: the note says the strain
    is far beyond what the model's linear elasticity holds and asks for the units; the paper's
    loads (a few per cent) say nothing."""
    res = solve(prototype.with_parameters(young_modulus=1000.0))
    assert res.converged and res.extra["note"].startswith(
        "large strain: the centre line is 94% longer than the rod at rest")
    assert "Young's modulus in Pa" in res.extra["note"]
    for pull in (2.0, 5.0):
        assert "large strain" not in solve(prototype, {"t1": pull}).extra.get("note", "")


def test_a_tension_the_rod_cannot_bear_names_a_modulus_too_soft_for_a_rubber(prototype):
    """E typed in kPa (1000) with a 2 N pull: the tension's message blamed the tension alone;
    it names E too where E is softer than any silicone rubber (and not otherwise)."""
    said = inputs.tension_error(prototype, "t1", 2.0, young_modulus=1000.0)
    assert "tensions are in newtons, and Young's modulus in Pa (E = 1000 Pa here" in said
    assert "Young's modulus" not in inputs.tension_error(prototype, "t1", 204.0)
