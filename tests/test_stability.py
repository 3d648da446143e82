"""Where the rod settles from an unstable or unfound equilibrium (``solve(..., settle=True)``,
:mod:`tendonsense.stability`): what a settled result and a failed settling say. The checks
against the elastica and the damped motion are in test_closed_form.py and test_dynamics.py."""

import numpy as np

from tendonsense.forward import THROUGH_ITSELF, solve
from tendonsense.stability import UNSTABLE_NOTE


def _stable_there(robot, tensions, forces, result, sliding=None):
    again = solve(robot, tensions, forces, q0=result.q, sliding=sliding)
    return again.converged and UNSTABLE_NOTE not in again.extra.get("note", "") and np.allclose(
        again.q, result.q, rtol=0, atol=1e-8)


def test_a_step_that_leaves_the_motion_is_taken_again_shorter(prototype):
    """t1 = 20 N paid out with 2 N at the tip: no equilibrium solved for; the pseudo-time
    steps, grown into Newton's near a stable state, threw it away and cycled every 440 steps
    (reported NOT CONVERGED at a point whose own re-solve is stable); a step from a stable
    shape after which the residual grows more than fourfold is now taken again shorter, and
    the result is judged at Newton's point: converged, stable there, and its note says no
    nudge was made; the coil it settles in passes through itself (the model has no
    contact), and the note says so too. (Rejecting such steps while leaving the unstable shape too made the path
    end elsewhere on another machine's rounding: the outcome is checked here for inputs
    1e-9 to 1e-5 apart.)"""
    forces, out = [(0.25, (0.0, 0.0, -2.0))], {"t1": "out"}
    for eps in (0.0, 1e-9, -1e-7, 1e-5):
        tensions = {"t1": 20.0 * (1 + eps)}
        assert not solve(prototype, tensions, forces, sliding=out).converged
        res = solve(prototype, tensions, forces, sliding=out, settle=True)
        assert res.converged and res.extra["note"].startswith(
            "settled: the equilibrium solved for was not found")
        assert "nudged" not in res.extra["note"]
        assert _stable_there(prototype, tensions, forces, res, out)
        # a coil the model finds, which the robot cannot take: said
        assert THROUGH_ITSELF in res.extra["note"]


def test_a_rod_that_does_not_come_to_rest_is_not_converged(prototype):
    """t1 = 10 N paid out with 0.5 N at the tip: neither the solve nor the damped rod finds
    a stable equilibrium: its motion runs to where the model's equations have no value (it
    took 1000 ever shorter pseudo-time steps there before); the result says so (not
    converged, the note says settling was tried and why it failed)."""
    from tendonsense.stability import LEFT_THE_MODEL, SETTLE_STEPS
    res = solve(prototype, {"t1": 10.0}, [(0.25, (0.0, 0.0, -0.5))], sliding={"t1": "out"},
                settle=True)
    assert not res.converged
    assert "the rod did not come to rest" in res.extra["note"]
    assert res.extra["note"].endswith(LEFT_THE_MODEL)
    assert f"{SETTLE_STEPS} pseudo-time steps" not in res.extra["note"]


def test_an_estimate_at_an_unstable_shape_suggests_the_forces_direction(prototype):
    """Readings of the rod settled out of the plane of its loads (t1 = 10 N, 1.2 N hanging at
    the tip): a force estimated along the given direction from t1 alone lands on the planar,
    unstable shape and misreads it (0.84 N); its note says so and suggests three unknowns
    along x, y, z with three tendons' readings, which recover the force from the same
    readings."""
    from tendonsense.estimation import PointForceUnknown, estimate
    rest = solve(prototype, {"t1": 10.0}, [(0.25, (0.0, 0.0, -1.2))], settle=True)
    assert rest.converged
    one = estimate(prototype, {"t1": rest.displacements["t1"]}, {"t1": 10.0},
                   [PointForceUnknown(0.25, (0.0, 0.0, -1.0))])
    assert one.converged and abs(one.magnitudes[0] - 1.2) > 0.2
    assert UNSTABLE_NOTE in one.extra["note"] and "--unknown X,0,1,0" in one.extra["note"]
    three = estimate(prototype, rest.displacements, rest.tensions,
                     [PointForceUnknown(0.25, d) for d in np.eye(3)])
    assert three.converged and UNSTABLE_NOTE not in three.extra.get("note", "")
    assert np.allclose(three.magnitudes, [0.0, 0.0, -1.2], atol=1e-6)
