"""Friction that follows the tendon (issue 27, part 1): a tendon pulled in (its tension fades
toward the anchor, eq. 10), paid out (it grows: ``T_{i+1} = T_i exp(+μφ_i)``) or stuck
(anywhere between). Checked against the independent Cosserat BVP with the tension growing
toward the anchor, the identities at ``in`` and at μ = 0, and a stuck profile that is not
either end of the band."""

import dataclasses
import json
import subprocess
import sys

import numpy as np
import pytest

from conftest import PROTOTYPE
from cosserat_bvp import CosseratBVP
from tendonsense.estimation import PointForceUnknown, estimate
from tendonsense.forward import forward_kinematics, solve

RICH = (("torsion", 4), ("bending_y", 8), ("bending_z", 8), ("elongation", 6),
        ("shear_y", 6), ("shear_z", 6))


def test_in_is_todays_law_bit_for_bit(prototype):
    T = {"t1": 2.5, "t2": 0.7}
    a, b = solve(prototype, T), solve(prototype, T, sliding={"t1": "in", "t2": "in"})
    assert np.array_equal(a.q, b.q)
    y = {"t1": a.displacements["t1"]}
    c = forward_kinematics(prototype, y, {"t2": 0.7}, sliding={"t1": "in"})
    assert np.array_equal(c.q, forward_kinematics(prototype, y, {"t2": 0.7}).q)


def test_without_friction_the_direction_does_not_matter(prototype):
    robot = prototype.with_parameters(friction=0.0)
    T = {"t1": 2.5, "t3": 1.0}
    a, b = solve(robot, T), solve(robot, T, sliding={"t1": "out", "t3": "out"})
    np.testing.assert_allclose(a.q, b.q, rtol=0, atol=1e-12)


def _paid_out(robot, names):
    """The reference's robot with the Capstan exponent's sign flipped for ``names``."""
    return robot.replace(tendons=tuple(
        dataclasses.replace(t, friction=-t.friction) if t.name in names else t
        for t in robot.tendons))


@pytest.mark.parametrize("T, out", [((1.5, 0.0, 0.0), ("t1",)),
                                    ((1.0, 0.5, 0.8), ("t1", "t3"))])
def test_paid_out_against_cosserat_bvp(prototype, T, out):
    """Markers within 1 mm of the BVP, as for ``in`` (tests/test_cosserat_reference.py).
    The tendon length changes agree less well paid out than pulled in: 0.58 mm on 13.7 mm
    against 0.05 mm on 4.9 mm at 1.5 N on t1 (GVS converged in basis and grid to 0.01 mm;
    not explained yet), so they are held to 1 mm and 0.1 mm."""
    tensions = dict(zip(prototype.tendon_names, T))
    rich = prototype.replace(strain=RICH)
    errors, shortening = {}, {}
    for direction in ("in", "out"):
        ref = CosseratBVP(_paid_out(prototype, out) if direction == "out" else prototype,
                          T).solve()
        gvs = solve(rich, tensions, sliding=dict.fromkeys(out, direction))
        assert gvs.converged
        for name, p in ref.markers().items():
            assert np.linalg.norm(gvs.markers[name] - p) < 1e-3, (direction, name)
        y = ref.tendon_length_changes()
        errors[direction] = max(abs(gvs.displacements[n] - y[n])
                                for n in prototype.tendon_names if tensions[n])
        shortening[direction] = gvs.displacements[out[0]]
    assert errors["in"] < 1e-4 and errors["out"] < 1e-3, errors
    assert abs(shortening["out"] - shortening["in"]) > 1e-3  # the direction matters here


def test_stuck_gives_a_range_that_holds_the_truth(prototype):
    """A stuck tendon whose profile is inside the band (a third of the way from ``in``):
    the range of the estimate holds the true force; ``in`` alone misses it."""
    mu = prototype.tendons[0].friction
    truth_robot = prototype.with_parameters(friction={"t1": mu / 3})
    force = 0.3
    seen = solve(truth_robot, {"t1": 2.5}, [(0.25, (0.0, 0.0, -force))])
    y, T = {"t1": seen.displacements["t1"]}, {"t1": 2.5}
    unknown = [PointForceUnknown(0.25, (0, 0, -1))]
    stuck = estimate(prototype, y, T, unknown, sliding={"t1": "stuck"})
    low, high = stuck.extra["magnitude_range"][0]
    assert stuck.converged and low < force < high
    pulled = estimate(prototype, y, T, unknown)
    assert pulled.magnitudes[0] == pytest.approx(low)  # `in` is one end of the band
    assert abs(pulled.magnitudes[0] - force) > 0.05 * force


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "tendonsense.cli", *map(str, args)],
                          capture_output=True, text=True)


def test_cli(tmp_path):
    r = _cli("estimate", PROTOTYPE, "--displacement", "t1=-0.005", "--tension", "t1=2.1",
             "--unknown", "0.25,0,0,-1", "--sliding", "t1=stuck", "--json")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    (low, high), = out["magnitude_range"]
    assert low < out["magnitudes"][0] < high
    for args, words in ((("solve", "--tension", "t1=2", "--sliding", "t1=stuck"), "stuck"),
                        (("solve", "--tension", "t1=2", "--sliding", "t1=up"), "in, out"),
                        (("solve", "--tension", "t1=2", "--sliding", "t1=out",
                          "--sliding", "t1=in"), "twice"),
                        (("fk", "--displacement", "t1=-0.003", "--sliding", "t9=out"),
                         "no such tendon")):
        plot = tmp_path / "shape.png"
        r = _cli(args[0], PROTOTYPE, *args[1:], "--plot", plot)
        assert r.returncode != 0 and words in r.stderr, (args, r.stderr)
        assert len(r.stderr.strip().splitlines()) == 1 and not plot.exists()
