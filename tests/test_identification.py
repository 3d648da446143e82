"""Identification (eq. 19) of E, ρ, μ from marker snapshots (issue 4)."""

import csv
import json
import subprocess
import sys

import numpy as np
import pytest

from conftest import ROOT
from tendonsense.forward import solve
from tendonsense.identification import Snapshot, SnapshotError, identify, read_snapshots
from tendonsense.robot import load_robot

CASES = [({}, (0.25, (0, 0, -0.2))), ({}, (0.25, (0, 0, -0.4))), ({"t1": 2.0}, None),
         ({"t1": 3.5}, None), ({"t3": 2.5}, None), ({"t2": 1.5, "t1": 1.0}, (0.25, (0, 0, -0.1))),
         ({"t1": 1.0}, (0.125, (0, 0, -0.6))), ({"t2": 3.0}, None)]
ALL = ("young_modulus", "density", "friction")


@pytest.fixture(scope="module")
def truth(prototype):
    return prototype.with_parameters(young_modulus=1.0e6, density=1340.0, friction=0.4)


def snapshots(truth, noise=0.0, seed=0):
    rng = np.random.default_rng(seed)
    out = []
    for T, load in CASES:
        res = solve(truth, T, [load] if load else [])
        markers = {m: p + rng.normal(scale=noise, size=3) if noise else p
                   for m, p in res.markers.items()}
        out.append(Snapshot({n: T.get(n, 0.0) for n in truth.tendon_names}, markers, load))
    return out


def start(robot):
    return robot.with_parameters(young_modulus=1.5e6, density=1100.0, friction=0.2)


def test_fits_back_exactly_without_noise(truth):
    fit = identify(start(truth), snapshots(truth), ALL)
    assert fit.converged
    for k, v in {"young_modulus": 1e6, "density": 1340.0, "friction": 0.4}.items():
        assert fit.parameters[k] == pytest.approx(v, rel=1e-4)
    assert fit.marker_rmse < 1e-6 < fit.initial_marker_rmse


def test_fits_within_3_percent_with_half_millimetre_noise(truth):
    fit = identify(start(truth), snapshots(truth, noise=5e-4), ALL)
    assert fit.converged
    for k, v in {"young_modulus": 1e6, "density": 1340.0, "friction": 0.4}.items():
        assert fit.parameters[k] == pytest.approx(v, rel=0.03), k
    assert 2e-4 < fit.marker_rmse < 1.5e-3


def test_friction_needs_a_tensioned_snapshot(truth):
    snaps = [s for s, (T, _) in zip(snapshots(truth), CASES) if not T]
    with pytest.raises(SnapshotError, match="no snapshot has a tendon under tension"):
        identify(truth, snaps, ["friction"])


def test_gravity_only_cannot_separate_stiffness_and_density(truth):
    snaps = [Snapshot({}, {"tip": np.array([0.23, 0, -0.09])})]
    with pytest.raises(SnapshotError, match="only density / young_modulus"):
        identify(truth, snaps, ["young_modulus", "density"])


def write_snapshots(path, robot, snaps, drop=None):
    header = [f"tension_{n}" for n in robot.tendon_names] + ["load_X", "load_fx", "load_fy",
                                                             "load_fz"]
    header += [f"marker_{m}_{a}" for m in robot.marker_names for a in "xyz"]
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        for s in snaps:
            load = [s.load[0], *s.load[1]] if s.load else ["", "", "", ""]
            row = [s.tensions[n] for n in robot.tendon_names] + load
            row += [v for m in robot.marker_names for v in s.markers[m]]
            w.writerow(row)
    if drop:
        lines = path.read_text().splitlines()
        cells = lines[2].split(",")
        cells[header.index(drop)] = ""
        lines[2] = ",".join(cells)
        path.write_text("\n".join(lines) + "\n")


def test_missing_marker_value_is_named(truth, tmp_path):
    write_snapshots(tmp_path / "s.csv", truth, snapshots(truth), drop="marker_tip_y")
    with pytest.raises(SnapshotError, match="row 2: column marker_tip_y is missing"):
        read_snapshots(tmp_path / "s.csv", truth)


def test_cli_identify_writes_fitted_robot(truth, tmp_path):
    write_snapshots(tmp_path / "s.csv", truth, snapshots(truth))
    robot_file = tmp_path / "start.toml"
    from tendonsense.robot import robot_to_toml
    robot_file.write_text(robot_to_toml(start(truth)))
    out = tmp_path / "fitted.toml"
    p = subprocess.run([sys.executable, "-m", "tendonsense.cli", "identify", str(robot_file),
                        "--snapshots", str(tmp_path / "s.csv"), "--param", "young_modulus",
                        "--param", "density", "--param", "friction", "-o", str(out), "--json"],
                       capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr
    res = json.loads(p.stdout)
    assert {"young_modulus", "density", "friction", "marker_rmse", "converged"} <= set(res)
    assert res["converged"] is True
    assert res["young_modulus"] == pytest.approx(1e6, rel=1e-4)
    fitted = load_robot(out)
    assert fitted.rod.young_modulus == pytest.approx(res["young_modulus"])
    assert fitted.rod.density == pytest.approx(res["density"])
    assert all(t.friction == pytest.approx(res["friction"]) for t in fitted.tendons)


def test_soromox_tentacle_first_session():
    """The second robot: 8 real poses (the source's identification set)."""
    robot = load_robot(ROOT / "examples" / "soromox_tentacle.toml")
    snaps = read_snapshots(ROOT / "examples" / "soromox_snapshots.csv", robot)[:8]
    fit = identify(robot.with_parameters(young_modulus=5.05e5, density=1500.0), snaps)
    assert fit.converged
    assert fit.marker_rmse < 0.02 < fit.initial_marker_rmse
    assert 2e5 < fit.parameters["young_modulus"] < 6e5
