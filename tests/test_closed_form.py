"""Closed-form beam results (issue 2, tests 1, 2, 7)."""

import numpy as np
import pytest

from conftest import robot_from, uniform_rod
from tendonsense.forward import solve


def test_cantilever_tip_load_matches_euler_bernoulli():
    r, L, E, F = 0.01, 0.25, 1e6, 1e-3
    robot = robot_from(rod=uniform_rod(r, L, E), gravity={"acceleration": [0, 0, 0]},
                       marker=[{"name": "tip", "X": L}])
    res = solve(robot, point_forces=[(L, (0.0, 0.0, -F))])
    assert res.converged
    I = np.pi * r**4 / 4
    expected = F * L**3 / (3 * E * I)
    deflection = -res.markers["tip"][2]
    assert deflection == pytest.approx(expected, rel=1e-4)  # -7.2e-6 (2026-12-05)


def test_constant_offset_tendon_bends_rod_into_arc():
    r, L, E, d, T = 0.01, 0.25, 1e6, 0.008, 0.5
    robot = robot_from(rod=uniform_rod(r, L, E), gravity={"acceleration": [0, 0, 0]},
                       tendon=[{"name": "t", "offset_base": [0, d], "offset_tip": [0, d],
                                "friction": 0.0, "disks": 41}],
                       solver={"intervals": 40})
    res = solve(robot, {"t": T})
    assert res.converged
    pts = res.backbone[:, [0, 2]]
    # algebraic circle fit in the x-z plane
    A = np.c_[2 * pts, np.ones(len(pts))]
    (cx, cz, c), *_ = np.linalg.lstsq(A, (pts**2).sum(1), rcond=None)
    radius = np.sqrt(c + cx**2 + cz**2)
    off_circle = np.abs(np.hypot(pts[:, 0] - cx, pts[:, 1] - cz) - radius).max()
    kappa = T * d / (E * np.pi * r**4 / 4)
    # 0.18 %: the tension shortens the rod by T / (E A) = 0.16 %, which the arc's formula
    # leaves out (2026-12-05)
    assert 1 / radius == pytest.approx(kappa, rel=3e-3)
    assert off_circle < 1e-8 * radius  # 8e-11 (2026-12-05)
    assert res.markers == {}


def test_prototype_t1_088N_keeps_tendon_length(prototype):
    res = solve(prototype, {"t1": 0.88})
    assert res.converged
    assert abs(res.displacements["t1"]) < 1e-3


@pytest.mark.parametrize("ratio", [0.97, 1.03, 1.5])
def test_a_column_past_eulers_load_is_said_to_be_unstable(ratio):
    """A straight cantilever column under an end load P along its axis is in equilibrium at
    any P, stable below Euler's P_cr = π² EI / 4L² and unstable above: a solve past it says
    so, with the stiffness ratio 1 − P/P_cr of its first mode (it was a straight rod without
    a word); an estimate that lands there likewise; below P_cr no such note."""
    from tendonsense.estimation import PointForceUnknown, estimate
    r, L, E = 0.005, 0.25, 1e6
    robot = robot_from(rod=uniform_rod(r, L, E), gravity={"acceleration": [0, 0, 0]},
                       tendon=[{"name": "t", "offset_base": [0, 0.004],
                                "offset_tip": [0, 0.004], "friction": 0.0, "disks": 9}])
    P = ratio * np.pi**2 * E * (np.pi * r**4 / 4) / (4 * L**2)
    res = solve(robot, point_forces=[(L, (-P, 0.0, 0.0))])
    assert np.abs(res.backbone[:, 1:]).max() < 1e-12  # the straight rod, by symmetry
    if ratio < 1:
        assert res.converged and "note" not in res.extra
        return
    note = res.extra["note"]
    assert res.converged and note.startswith("unstable equilibrium")
    lam = float(note.split("stiffness ratio ")[1].split(";")[0])
    assert lam == pytest.approx(1 - ratio, abs=2e-3 * ratio)  # GVS's P_cr a little above
    est = estimate(robot, {"t": res.displacements["t"]}, {"t": 0.0},
                   [PointForceUnknown(L, (-1.0, 0.0, 0.0))])
    assert est.converged and est.extra["note"].startswith("unstable equilibrium")


def test_a_batch_marks_the_columns_past_eulers_load():
    """``solve_batch(..., stability=True)`` makes :func:`solve`'s check on every sample: the
    column above at P/P_cr from 0.5 to 1.5 in one batch, unstable above 1 with the ratio
    1 − P/P_cr in its note (a sweep reported them converged without a word); unchecked by
    default."""
    from tendonsense.tracking import solve_batch
    r, L, E = 0.005, 0.25, 1e6
    robot = robot_from(rod=uniform_rod(r, L, E), gravity={"acceleration": [0, 0, 0]},
                       tendon=[{"name": "t", "offset_base": [0, 0.004],
                                "offset_tip": [0, 0.004], "friction": 0.0, "disks": 9}])
    ratio = np.array([0.5, 0.97, 1.03, 1.2, 1.5])
    P = ratio * np.pi**2 * E * (np.pi * r**4 / 4) / (4 * L**2)
    loads = [(L, np.stack([-P, 0 * P, 0 * P], 1))]
    out = solve_batch(robot, {"t": np.zeros(5)}, loads, stability=True)
    assert out.converged.all() and list(out.unstable) == [False, False, True, True, True]
    assert list(out.notes[:2]) == ["", ""]
    for k in (2, 3, 4):
        assert out.notes[k].startswith("unstable equilibrium")
        lam = float(out.notes[k].split("stiffness ratio ")[1].split(";")[0])
        assert lam == pytest.approx(1 - ratio[k], abs=2e-3 * ratio[k])
    plain = solve_batch(robot, {"t": np.zeros(5)}, loads)
    assert plain.unstable is None and set(plain.notes) == {""}


def test_a_column_past_eulers_load_settles_in_the_elastica():
    """Past Euler's load the straight column is unstable and ``solve(..., settle=True)``
    gives the buckled one: the cantilever elastica under an end load P along its axis, tip
    angle α with k = sin(α/2) from K(k) = λL, λ = √(P/EI): tip deflection 2k/λ and axial
    position (2E(k) − K(k))/λ (Timoshenko & Gere, §2.7; complete elliptic integrals)."""
    from scipy.optimize import brentq
    from scipy.special import ellipe, ellipk
    r, L, E, ratio = 0.005, 0.25, 1e6, 1.5
    robot = robot_from(rod=uniform_rod(r, L, E), gravity={"acceleration": [0, 0, 0]},
                       tendon=[{"name": "t", "offset_base": [0, 0.004],
                                "offset_tip": [0, 0.004], "friction": 0.0, "disks": 9}],
                       marker=[{"name": "tip", "X": L}])
    EI = E * np.pi * r**4 / 4
    P = ratio * np.pi**2 * EI / (4 * L**2)
    lam = np.sqrt(P / EI)
    m = brentq(lambda m: ellipk(m) - lam * L, 1e-12, 1 - 1e-12)  # m = k²
    k = np.sqrt(m)
    res = solve(robot, point_forces=[(L, (-P, 0.0, 0.0))], settle=True)
    assert res.converged and "unstable equilibrium" not in res.extra["note"]
    assert res.extra["note"].startswith("settled: the equilibrium solved for was unstable")
    tip = res.markers["tip"]
    assert np.hypot(tip[1], tip[2]) == pytest.approx(2 * k / lam, rel=1e-3)  # 1.1e-4
    assert tip[0] == pytest.approx((2 * ellipe(m) - ellipk(m)) / lam, rel=1e-3)  # 1.3e-4
    again = solve(robot, point_forces=[(L, (-P, 0.0, 0.0))], q0=res.q)
    assert again.converged and "note" not in again.extra  # stable: no note


@pytest.mark.parametrize("turn, tube, touches", [(1.0, 0.01, False), (1.9, 0.01, True),
                                                 (1.9, 0.007, False), (2.2, 0.001, True)])
def test_a_ring_of_the_rod_passes_through_itself_where_its_ends_meet(turn, tube, touches):
    """A centre line bent into an arc of radius ρ turning ``turn`` half-turns: its ends are
    2ρ sin(θ/2) apart, and past a half-turn the rod passes through itself where that is less
    than its diameter; a straight rod never does."""
    from tendonsense.rod import overlap
    rho = 0.05
    X = np.linspace(0.0, rho * turn * np.pi, 201)
    th = X / rho
    P = np.stack([rho * np.sin(th), 0 * th, rho * (1 - np.cos(th))], axis=1)
    found = overlap(P, X, np.full(X.size, tube))
    assert (found is not None) == touches
    if touches and turn < 2:  # the deepest at the ends, exactly
        assert (found.X, found.X_other) == (0.0, X[-1])
        assert found.distance == pytest.approx(2 * rho * np.sin(turn * np.pi / 2), rel=1e-12)
        assert found.reach == pytest.approx(2 * tube)
    assert overlap(np.stack([X, 0 * X, 0 * X], axis=1), X, np.full(X.size, 0.1)) is None


@pytest.mark.parametrize("pitch", [0.015, 0.025])
def test_a_coil_passes_through_itself_where_its_turns_are_closer_than_its_diameter(pitch):
    """A helical centre line of pitch p: each turn lies p from the next, so a rod of radius
    r = 0.01 passes through itself when p < 2r, there about p apart, and not otherwise."""
    from tendonsense.rod import overlap
    R, r = 0.03, 0.01
    th = np.linspace(0.0, 3 * 2 * np.pi, 601)
    X = th * np.hypot(R, pitch / (2 * np.pi))
    P = np.stack([R * np.cos(th), R * np.sin(th), pitch * th / (2 * np.pi)], axis=1)
    found = overlap(P, X, np.full(X.size, r))
    if pitch > 2 * r:
        assert found is None
    else:
        assert 0.98 * pitch <= found.distance <= pitch and found.reach == pytest.approx(2 * r)
        assert found.X_other - found.X == pytest.approx(2 * np.pi * np.hypot(
            R, pitch / (2 * np.pi)), rel=0.02)


def test_a_centre_line_too_short_or_with_a_gap_is_read_as_it_can_be():
    """Fewer than three points: nothing to compare (None); a non-finite point is left out,
    the ring's ends still found."""
    from tendonsense.rod import overlap
    rho = 0.05
    X = np.linspace(0.0, rho * 1.9 * np.pi, 201)
    th = X / rho
    P = np.stack([rho * np.sin(th), 0 * th, rho * (1 - np.cos(th))], axis=1)
    P[150] = np.nan
    found = overlap(P, X, np.full(X.size, 0.01))
    assert found is not None and (found.X, found.X_other) == (0.0, X[-1])
    assert overlap(P[:2], X[:2], np.full(2, 0.01)) is None
    assert overlap(np.zeros((0, 3)), np.zeros(0), np.zeros(0)) is None
