"""Estimation (eq. 17): round trips, refusal, logs, uncertainty (issue 3)."""

import csv
import json
import subprocess
import sys

import numpy as np
import pytest

from conftest import PROTOTYPE, ROOT
from tendonsense.estimation import GravityUnknown, Noise, PointForceUnknown, estimate, problem
from tendonsense.estimation import estimate_problem
from tendonsense.forward import solve

ALL = {"t1": 2.0, "t2": 1.0, "t3": 1.5}
UX, UY, UZ = ((1, 0, 0), (0, 1, 0), (0, 0, 1))


def round_trip(robot, tensions, loads, unknowns, truth, measured=None):
    fwd = solve(robot, tensions, loads)
    assert fwd.converged
    measured = measured or list(tensions)
    est = estimate(robot, {n: fwd.displacements[n] for n in measured}, tensions, unknowns)
    assert est.converged
    np.testing.assert_allclose(est.magnitudes, truth, rtol=1e-6)
    for m, p in fwd.markers.items():
        np.testing.assert_allclose(est.markers[m], p, atol=1e-8)
    return est


def test_tip_force_with_t1(prototype):
    round_trip(prototype, {"t1": 2.0}, [(0.25, (0, 0, -0.3))],
               [PointForceUnknown(0.25, (0, 0, -1))], [0.3])


def test_mid_force_with_t3_out_of_plane(prototype):
    round_trip(prototype, {"t3": 2.5}, [(0.125, (0, 0, -0.6))],
               [PointForceUnknown(0.125, (0, 0, -1))], [0.6])


def test_3d_tip_force_with_three_tendons(prototype):
    F = (0.1, 0.2, -0.3)
    round_trip(prototype, ALL, [(0.25, F)],
               [PointForceUnknown(0.25, UX), PointForceUnknown(0.25, UY),
                PointForceUnknown(0.25, UZ)], F)


def test_gravity_scale(prototype):
    heavier = prototype.replace(gravity=(0.0, 0.0, -9.81 * 1.3))
    fwd = solve(heavier, {"t1": 2.0})
    est = estimate(prototype, {"t1": fwd.displacements["t1"]}, {"t1": 2.0}, [GravityUnknown()])
    assert est.converged
    assert est.magnitudes[0] == pytest.approx(1.3, rel=1e-6)


def test_two_forces_with_three_tendons_least_squares(prototype):
    est = round_trip(prototype, ALL, [(0.125, (0, 0, -0.5)), (0.25, (0, 0.2, 0))],
                     [PointForceUnknown(0.125, (0, 0, -1)), PointForceUnknown(0.25, UY)],
                     [0.5, 0.2])
    assert est.extra["length_misfit"] < 1e-10


def test_least_squares_with_inconsistent_readings_reaches_the_minimum(prototype):
    """Noisy readings: the estimate is the stationary point of ‖y(q) − y_meas‖²."""
    fwd = solve(prototype, ALL, [(0.25, (0, 0, -0.3))])
    y = {n: v + d for (n, v), d in zip(fwd.displacements.items(), (2e-4, -1e-4, 1.5e-4))}
    unknowns = [PointForceUnknown(0.25, UZ), PointForceUnknown(0.25, UY)]
    est = estimate(prototype, y, ALL, unknowns)
    assert est.converged and est.extra["length_misfit"] > 1e-5
    for k in range(2):  # nudging either magnitude must not lower the misfit
        for h in (-1e-4, 1e-4):
            loads = [(0.25, (0, 0, est.magnitudes[0])), (0.25, (0, est.magnitudes[1], 0))]
            loads[k] = (0.25, tuple(np.array(loads[k][1]) + h * np.array([UZ, UY][k])))
            other = solve(prototype, ALL, loads)
            misfit = np.linalg.norm([other.displacements[n] - y[n] for n in y])
            assert misfit >= est.extra["length_misfit"] - 1e-12


def test_refuses_fewer_tendons_than_unknowns(prototype):
    with pytest.raises(ValueError, match="at least 3 tendons"):
        estimate(prototype, {"t1": -0.01}, {"t1": 2.0},
                 [PointForceUnknown(0.25, d) for d in (UX, UY, UZ)])


def test_impossible_reading_is_not_reported_converged(prototype):
    # pulled in by more than the tendon is long: no shape can do that (refused, with why)
    with pytest.raises(ValueError, match="pulls in more than the tendon's whole length"):
        estimate(prototype, {"t1": -0.3}, {"t1": 2.0}, [PointForceUnknown(0.25, UZ)])


@pytest.mark.parametrize("case", ["1-D tip force, t1", "3-D tip force, three tendons"])
def test_uncertainty_band_matches_monte_carlo(prototype, case):
    if case.startswith("1-D"):
        T, loads, unknowns = {"t1": 2.0}, [(0.25, (0, 0, -0.3))], [PointForceUnknown(0.25, UZ)]
    else:
        T, loads = ALL, [(0.25, (0.1, 0.2, -0.3))]
        unknowns = [PointForceUnknown(0.25, d) for d in (UX, UY, UZ)]
    fwd = solve(prototype, T, loads)
    prob = problem(prototype, list(T), unknowns)
    y = {n: fwd.displacements[n] for n in T}
    nominal = estimate_problem(prob, y, T)
    rng = np.random.default_rng(42)
    noise = Noise()
    draws = []
    for _ in range(300):
        yn = {n: v + rng.normal(scale=noise.length) for n, v in y.items()}
        Tn = {n: v * (1 + rng.normal(scale=noise.tension)) for n, v in T.items()}
        r = estimate_problem(prob, yn, Tn, x0=nominal.extra["x"])
        assert r.converged
        draws.append(r.magnitudes)
    spread = np.std(draws, axis=0, ddof=1)
    np.testing.assert_allclose(spread, nominal.sigma, rtol=0.2)


# ----------------------------------------------------------------------------- logs and CLI

def cli(*args):
    return subprocess.run([sys.executable, "-m", "tendonsense.cli", *map(str, args)],
                          capture_output=True, text=True, timeout=600)


def make_log(prototype, path, forces, bad_row=None):
    header = ["time", "tension_t1", "tension_t2", "tension_t3", "displacement_t1",
              "marker_tip_x", "marker_tip_y", "marker_tip_z"]
    rows = []
    for i, f in enumerate(forces):
        r = solve(prototype, {"t1": 2.0}, [(0.25, (0, 0, -f))])
        rows.append([0.1 * i, 2.0, 0, 0, r.displacements["t1"], *r.markers["tip"]])
    if bad_row is not None:
        rows[bad_row][4] = ""
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows(rows)
    return rows


def test_readings_log_with_a_bad_row(prototype, tmp_path):
    forces = [0.1, 0.15, 0.2, 0.25]
    make_log(prototype, tmp_path / "in.csv", forces, bad_row=2)
    out = tmp_path / "out.csv"
    p = cli("estimate", PROTOTYPE, "--readings", tmp_path / "in.csv", "--unknown", "0.25,0,0,-1",
            "-o", out, "--quiet")
    assert p.returncode == 3  # not every sample could be estimated
    assert "row 3" in p.stderr and "displacement_t1" in p.stderr
    rows = list(csv.DictReader(open(out)))
    assert len(rows) == 4
    assert [r["converged"] for r in rows] == ["true", "true", "false", "true"]
    for r, f in zip(rows, forces):
        if r["converged"] == "true":
            assert float(r["magnitude_1"]) == pytest.approx(f, rel=1e-6)
            assert float(r["shape_rmse"]) < 1e-8
            assert float(r["sigma_1"]) > 0
    assert rows[2]["magnitude_1"] == ""


def test_readings_bad_header_writes_nothing(tmp_path):
    (tmp_path / "in.csv").write_text("time,tension_t9,displacement_t9\n0,1,0\n")
    out = tmp_path / "out.csv"
    p = cli("estimate", PROTOTYPE, "--readings", tmp_path / "in.csv", "--unknown", "gravity",
            "-o", out)
    assert p.returncode == 1 and "tension_t9" in p.stderr
    assert len(p.stderr.strip().splitlines()) == 1
    assert not out.exists() and list(tmp_path.iterdir()) == [tmp_path / "in.csv"]


def test_cli_single_reading_json(prototype):
    fwd = solve(prototype, {"t1": 2.1}, [(0.25, (0, 0, -0.2))])
    p = cli("estimate", PROTOTYPE, "--displacement", f"t1={fwd.displacements['t1']!r}",
            "--tension", "t1=2.1", "--unknown", "0.25,0,0,-1", "--json")
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    assert {"magnitudes", "q", "markers", "backbone", "converged", "iterations",
            "residual", "sigma"} <= set(out)
    assert out["magnitudes"][0] == pytest.approx(0.2, rel=1e-6)


def test_cli_refuses_too_few_tendons():
    p = cli("estimate", PROTOTYPE, "--displacement", "t1=-0.01", "--tension", "t1=2",
            "--unknown", "0.25,1,0,0", "--unknown", "0.25,0,1,0", "--json")
    assert p.returncode == 1 and p.stdout == ""
    assert "at least 2 tendons" in p.stderr


def test_paper_experiments_all_converge():
    p = cli("experiments", ROOT / "examples" / "paper_experiments.csv", "--robot", PROTOTYPE,
            "--json")
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    assert out["rows"] == 23 and out["converged"] == 23
    assert len(out["cases"]) == 23 and all(c["estimate"] is not None for c in out["cases"])


def test_a_least_squares_fit_keeps_to_its_total_budget(prototype):
    """``total_budget`` bounds a least-squares fit's equilibrium solves together (the live
    estimator's rescue within its time limit): a reading that takes many solves stops at the
    budget and says so; without it the same fit converges."""
    prob = problem(prototype, ["t1", "t2", "t3"], [PointForceUnknown(0.25, (0, 0, -1))])
    readings = ({"t1": -0.05, "t2": 0.0005, "t3": 0.0005}, {"t1": 2.0, "t2": 0.0, "t3": 0.0})
    free = estimate_problem(prob, *readings)
    assert free.converged and free.iterations > 40
    bounded = estimate_problem(prob, *readings, budget=12, total_budget=12)
    assert not bounded.converged and "used its work budget (12 evaluations)" in \
        bounded.extra["note"]
