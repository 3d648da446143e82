"""The command line contract of SPEC §4 for solve and fk (issue 2, test 8)."""

import json
import subprocess
import sys

import pytest

from conftest import PROTOTYPE

KEYS = {"q", "tensions", "displacements", "markers", "backbone", "converged", "iterations",
        "residual"}


def run(*args):
    return subprocess.run([sys.executable, "-m", "tendonsense.cli", *map(str, args)],
                          capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("args", [
    ("solve", PROTOTYPE, "--tension", "t1=2.0", "--point-force", "0.25,0,0,-0.2"),
    ("fk", PROTOTYPE, "--displacement", "t1=-0.01"),
])
def test_json_has_spec_keys(args):
    p = run(*args, "--json")
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    assert KEYS <= set(out)
    assert out["converged"] is True
    assert set(out["markers"]) == {"mid", "three_quarter", "tip"}
    assert len(out["backbone"]) >= 50 and all(len(p) == 3 for p in out["backbone"])
    assert len(out["q"]) == 15
    if args[0] == "fk":
        assert out["displacements"]["t1"] == pytest.approx(-0.01, abs=1e-9)
        assert out["tensions"]["t1"] > 0


def test_bad_robot_file(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(PROTOTYPE.read_text().replace("length = 0.25", "length = -0.25"))
    p = run("solve", bad, "--tension", "t1=1", "--json")
    assert p.returncode != 0
    assert p.stdout == ""
    assert len(p.stderr.strip().splitlines()) == 1
    assert "rod.length" in p.stderr and "> 0" in p.stderr


@pytest.mark.parametrize("flag", [("--tension", "t1"), ("--tension", "t9=1"),
                                  ("--point-force", "0.1,0,0"), ("--bogus",)])
def test_bad_flag(flag):
    p = run("solve", PROTOTYPE, *flag, "--json")
    assert p.returncode != 0
    assert p.stdout == ""
    assert len(p.stderr.strip().splitlines()) == 1, p.stderr


def test_solve_settle_finds_the_state_beyond_the_planar_branch(tmp_path):
    """The paper's simulated robot without friction, t1 at 6.5 N and 1.2 N hanging at its
    tip: the planar shape a solve from the straight rod keeps by symmetry ends before this
    load (not converged, exit 3), but the rod has a stable state out of that plane;
    ``--settle`` finds it (converged, said so, its stability checked again: a solve from it
    says nothing), a figure drawn."""
    from tendonsense import load_robot
    from tendonsense.forward import solve
    robot = tmp_path / "sim.toml"
    robot.write_text(PROTOTYPE.with_name("paper_simulation.toml").read_text()
                     .replace("friction = 0.3", "friction = 0.0"))
    args = ("solve", robot, "--tension", "t1=6.5", "--point-force", "0.25,0,0,-1.2", "--json")
    plain = run(*args)
    assert plain.returncode == 3 and json.loads(plain.stdout)["converged"] is False
    fig = tmp_path / "settled.png"
    p = run(*args, "--settle", "--plot", fig)
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    assert out["converged"] is True and out["note"].startswith(
        "settled: the equilibrium solved for was not found")
    assert abs(out["markers"]["tip"][1]) > 0.03  # out of the plane of its loads (49 mm)
    again = solve(load_robot(robot), {"t1": 6.5}, [(0.25, (0, 0, -1.2))], q0=out["q"])
    assert again.converged and "note" not in again.extra
    assert again.markers["tip"] == pytest.approx(out["markers"]["tip"], abs=1e-9)
    assert fig.stat().st_size > 10_000


def test_a_figures_given_line_says_each_known_forces_direction():
    """"given: … 0.2 N known force at X = 0.25 m along (0, 0, -1)": the direction, not the
    size alone (a force up and one down read the same before)."""
    from types import SimpleNamespace

    from tendonsense.cli import _given
    args = SimpleNamespace(displacement={}, tension={"t1": 2.0}, sliding={},
                           point_force=[(0.25, 0.0, 0.0, -0.2), (0.1, 0.0, 0.3, 0.4)])
    assert _given(args) == ("given: t1 tension 2 N, 0.2 N known force at X = 0.25 m along "
                            "(0, 0, -1), 0.5 N known force at X = 0.1 m along (0, 0.6, 0.8)")
