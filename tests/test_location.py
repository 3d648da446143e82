"""Issue 10: estimating where a force acts as well as how hard (beyond the paper)."""

import csv
import json
import subprocess
import sys

import numpy as np
import pytest

from tendonsense.estimation import Noise, PointForceUnknown, estimate, problem
from tendonsense.forward import solve
from tendonsense.tracking import estimate_series

from conftest import PROTOTYPE

TAUT = {"t1": 1.5, "t2": 0.3, "t3": 0.3}


def readings(robot, T, X, f):
    return solve(robot, T, [(X, f)]).displacements


@pytest.mark.parametrize("T, X, f", [
    (TAUT, 0.15, (0.0, 0.0, -0.3)),  # vertical, t1 pulled, the others taut
    ({"t1": 0.3, "t2": 0.3, "t3": 1.5}, 0.2, (0.0, 0.25, 0.0)),  # out of plane, t3 pulled
])
def test_round_trip_recovers_location_and_magnitude(prototype, T, X, f):
    f = np.array(f)
    y = readings(prototype, T, X, tuple(f))
    est = estimate(prototype, y, T, [PointForceUnknown(None, tuple(f))])
    assert est.converged
    assert abs(est.extra["locations"][0] - X) < 1e-4
    assert abs(est.magnitudes[0] / np.linalg.norm(f) - 1) < 1e-6
    assert est.extra["location_sigma"][0] > 0
    # the force held at a wrong X cannot meet the same readings
    prof = est.extra["location_profile"]
    far = np.abs(prof["X"] - X) > 0.03
    assert np.nanmin(prof["misfit"][far]) > 100 * max(est.extra["length_misfit"], 1e-9)


def test_minimum_at_the_end_of_a_range_is_reported_there(prototype):
    y = readings(prototype, TAUT, 0.15, (0.0, 0.0, -0.3))
    est = estimate(prototype, y, TAUT, [PointForceUnknown((0.17, 0.25), (0, 0, -1))])
    assert est.extra["locations"][0] == pytest.approx(0.17)
    assert "end of its range" in est.extra["note"]


def test_location_needs_one_more_tendon(prototype):
    with pytest.raises(ValueError, match="need at least 2 tendons"):
        problem(prototype, ["t1"], [PointForceUnknown(None, (0, 0, -1))])
    with pytest.raises(ValueError, match="outside the rod"):
        problem(prototype, ["t1", "t2"], [PointForceUnknown((0.1, 0.3), (0, 0, -1))])
    with pytest.raises(ValueError, match="must increase"):
        PointForceUnknown((0.2, 0.1), (0, 0, -1))


def test_location_band_matches_monte_carlo(prototype):
    """First-order σ_X and σ of the magnitude against the spread of estimates from noisy
    readings (small noise: the linear regime), within 25 %."""
    noise = Noise(length=2e-6, tension=2e-4)
    X, f = 0.15, (0.0, 0.0, -0.3)
    y = readings(prototype, TAUT, X, f)
    est = estimate(prototype, y, TAUT, [PointForceUnknown(None, (0, 0, -1))], noise=noise)
    rng = np.random.default_rng(3)
    n = 300
    disp = [{k: v + rng.normal(scale=noise.length) for k, v in y.items()} for _ in range(n)]
    ten = [{k: v * (1 + rng.normal(scale=noise.tension)) for k, v in TAUT.items()}
           for _ in range(n)]
    prob = problem(prototype, list(y), [PointForceUnknown(None, (0, 0, -1))])
    out = estimate_series(prob, disp, ten, noise)
    assert all(e.converged for e in out)
    Xs = np.array([e.locations[0] for e in out])
    mags = np.array([e.magnitudes[0] for e in out])
    assert np.std(Xs) == pytest.approx(est.extra["location_sigma"][0], rel=0.25)
    assert np.std(mags) == pytest.approx(est.sigma[0], rel=0.25)
    # the log's fast path reports the single estimate's band for the same readings
    clean = estimate_series(prob, [y] * 3, [TAUT] * 3, noise)
    for e in clean:
        assert e.location_sigma[0] == pytest.approx(est.extra["location_sigma"][0], rel=1e-3)
        assert e.sigma[0] == pytest.approx(est.sigma[0], rel=1e-3)


def test_located_force_in_a_log_is_followed(prototype):
    n = 40
    t = np.linspace(0.0, 1.0, n)
    F = 0.3 + 0.1 * np.sin(2 * np.pi * t)
    X = 0.15 + 0.02 * t  # the contact slides along the rod
    prob = problem(prototype, list(TAUT), [PointForceUnknown(None, (0, 0, -1))])
    disp = [readings(prototype, TAUT, X[k], (0.0, 0.0, -F[k])) for k in range(n)]
    out = estimate_series(prob, disp, [TAUT] * n)
    assert all(e.converged for e in out)
    np.testing.assert_allclose([e.locations[0] for e in out], X, atol=1e-6)
    np.testing.assert_allclose([e.magnitudes[0] for e in out], F, rtol=1e-6)


def test_cli_location(tmp_path):
    from tendonsense import load_robot
    robot = load_robot(PROTOTYPE)
    y = readings(robot, TAUT, 0.15, (0.0, 0.0, -0.3))
    args = [a for k in TAUT for a in ("--tension", f"{k}={TAUT[k]}", "--displacement",
                                      f"{k}={y[k]!r}")]
    cmd = [sys.executable, "-m", "tendonsense.cli", "estimate", str(PROTOTYPE), *args,
           "--unknown", "?,0,0,-1", "--json"]
    out = json.loads(subprocess.run(cmd, capture_output=True, text=True, check=True).stdout)
    assert out["locations"][0] == pytest.approx(0.15, abs=1e-4)
    assert out["location_sigma"][0] > 0 and out["magnitudes"][0] == pytest.approx(0.3)
    # a log: location columns, each row warm-started
    path = tmp_path / "in.csv"
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["time"] + [f"{c}_{k}" for k in TAUT for c in ("tension", "displacement")])
        for i in range(3):
            w.writerow([i] + [v for k in TAUT for v in (TAUT[k], y[k])])
    res = subprocess.run([sys.executable, "-m", "tendonsense.cli", "estimate", str(PROTOTYPE),
                          "--readings", str(path), "--unknown", "?,0,0,-1", "--unknown",
                          "0.25,0,1,0", "-o", str(tmp_path / "out.csv")],
                         capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    rows = list(csv.DictReader(open(tmp_path / "out.csv")))
    assert "location_1" in rows[0] and "location_2" not in rows[0]
    assert all(float(r["location_1"]) == pytest.approx(0.15, abs=1e-4) for r in rows)
    assert all(abs(float(r["magnitude_2"])) < 1e-6 for r in rows)
    bad = subprocess.run([sys.executable, "-m", "tendonsense.cli", "estimate", str(PROTOTYPE),
                          "--tension", "t1=1", "--displacement", "t1=0.001", "--unknown",
                          "?,0,0,-1"], capture_output=True, text=True)
    assert bad.returncode != 0 and "need at least 2 tendons" in bad.stderr
    assert bad.stdout == ""
