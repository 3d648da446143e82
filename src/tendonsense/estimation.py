"""Shape and force estimation from tendon length changes and tensions (eq. 17).

Unknowns are magnitudes: a point force of unknown size along a known global direction at a
known X (:class:`PointForceUnknown`), or the scale of the distributed gravity load
(:class:`GravityUnknown`). With as many measured tendons as unknowns the problem is square and
solved by the core Newton solver (equilibrium + tendon lengths); with more tendons it is the
least-squares problem of eq. 17, solved by Levenberg–Marquardt on the magnitudes with the
equilibrium as an exact constraint (implicit differentiation, no finite differences).
"""

from __future__ import annotations

import dataclasses
import itertools
from typing import Mapping, Sequence

import jax
import numpy as np

from .fastpath import tracker
from . import inputs
from .forward import make_result
from .inputs import (GravityUnknown, Noise, PointForceUnknown, Unknown,  # noqa: F401 (API)
                     check_noise)
from .model import Values
from .problem import (Problem, _jacobians_fn, confounded, noise_covariance,  # noqa: F401
                      jacobians, misfit_note, preload_jacobians, problem, reduced_jacobians,
                      unseen, unstable_at)
from .result import Result, joined, warns_if_not_converged
from .robot import Robot, check_robot
from .sliding import band_note, band_range
from .statics import (Drive, NewtonResult, Unknowns, preload_outputs, shape_outputs,
                      solve_system)


#: Bates–Watts relative offset below which a least-squares estimate that no step improves is
#: at its minimum (cost within 1e-6 of it)
RELATIVE_OFFSET = 1e-3

#: Levenberg–Marquardt steps of a least-squares estimate
LM_STEPS = 100


def _least_squares(prob: Problem, drive: Drive, values: Values, x0, tol: float, budget=None,
                   total_budget=None):
    """min ‖y(q) − y_meas‖² over the magnitudes z, q solving equilibrium (eq. 17), by
    Levenberg–Marquardt; returns (x, converged, iterations, newton result, misfit, why) with
    ``why`` the reason a fit whose equilibrium converged is not at a minimum (else None).
    ``budget`` bounds each equilibrium solve's evaluations, ``total_budget`` theirs together."""
    nq, n_z = prob.model.nq, prob.n_z
    structure = prob.model.structure
    statics_unknowns = Unknowns.none(len(prob.robot.tendons), prob.load_X.size)
    y_meas = np.asarray(drive.targets)
    sel = list(prob.measured)

    def equilibrium(z, q0):
        d = drive._replace(
            forces=drive.forces + np.tensordot(z, prob.unknowns.forces, axes=1),
            gravity=drive.gravity + z @ prob.unknowns.gravity,
            load_X=drive.load_X + np.asarray(z)[prob.n_magnitudes:] @ prob.unknowns.positions,
            targets=np.zeros(0))
        bounds = [b for b in (budget, total_budget and max(total_budget - used[0], 1)) if b]
        res = solve_system(structure, values, (), d, statics_unknowns, q0,
                           min(bounds, default=None))
        used[0] += int(res.evaluations)
        return res, shape_outputs(structure, values, res.x)[2][sel] - y_meas

    def spent() -> bool:
        return total_budget is not None and used[0] >= total_budget

    used = [0]  # evaluations of the equilibrium solves
    z = np.zeros(n_z) if x0 is None else np.asarray(x0[nq:], float)
    res, e = equilibrium(z, None if x0 is None else x0[:nq])
    total, damping = int(res.iterations), 1e-3
    converged, offset, steps = False, np.inf, 0
    for steps in range(1, LM_STEPS + 1):
        if not bool(res.converged) or spent():
            break
        Jz, _ = reduced_jacobians(prob, np.concatenate([np.asarray(res.x), z]), drive, values)
        g = Jz.T @ e
        scale = np.linalg.norm(Jz) * np.linalg.norm(e)
        # stationary: the undamped Gauss–Newton step is below the resolution of z (an exact,
        # consistent sample ends here with a misfit at the equilibrium solves' rounding)
        gauss_newton = np.linalg.lstsq(Jz, -e, rcond=None)[0]
        # Bates–Watts relative offset: the share of the misfit the model can still explain
        offset = np.linalg.norm(Jz @ gauss_newton) / max(np.linalg.norm(e), 1e-300)
        if (np.linalg.norm(e) <= 1e-13 or np.linalg.norm(g) <= tol * scale or offset <= 1e-6
                or np.linalg.norm(gauss_newton) <= 1e-8 * (np.linalg.norm(z) + 1e-6)):
            converged = True
            break
        H = Jz.T @ Jz
        cost = e @ e
        improved = False
        while damping < 1e12 and not spent():
            dz = np.linalg.solve(H + damping * np.diag(np.diag(H)), -g)
            r2, e2 = equilibrium(z + dz, res.x)
            total += int(r2.iterations)
            if bool(r2.converged) and e2 @ e2 < cost:
                # a negligible step that was (nearly) the Gauss–Newton step: at the minimum
                small = (np.linalg.norm(dz) <= 1e-12 * (1 + np.linalg.norm(z))
                         and damping <= 1e-3)
                z, res, e, damping = z + dz, r2, e2, max(damping / 4, 1e-9)
                improved = True
                if small:
                    converged = True
                break
            damping *= 4
        if not improved or converged:
            # no decrease possible (the equilibrium solves' resolution): at a minimum if the
            # gradient or the relative offset is already tiny
            converged = (converged or np.linalg.norm(g) <= 1e-6 * max(scale, 1e-300)
                         or offset <= RELATIVE_OFFSET)
            break
    x = np.concatenate([np.asarray(res.x), z])
    why = None
    if bool(res.converged) and not converged and spent():
        why = f"the least-squares fit used its work budget ({total_budget} evaluations)"
    elif bool(res.converged) and not converged:
        why = (f"the least-squares fit stopped after {steps} steps short of a minimum: no step "
               f"lowers the length misfit, yet the model could still explain a share "
               f"{offset:.1e} of it (relative offset; a minimum is below {RELATIVE_OFFSET:g})"
               if steps < LM_STEPS else
               f"the least-squares fit took its {LM_STEPS} steps without reaching a minimum "
               f"(relative offset {offset:.1e}; a minimum is below {RELATIVE_OFFSET:g})")
    return (x, converged and bool(res.converged), total, res, float(np.linalg.norm(e)), why)


@warns_if_not_converged
def estimate(robot: Robot, displacements: Mapping[str, float], tensions: Mapping[str, float],
             unknowns: Sequence[Unknown], point_forces=(), noise: Noise = Noise(),
             x0=None, sliding: Mapping[str, str] | None = None) -> Result:
    """Estimate the shape and the magnitudes of ``unknowns`` from measured tendon
    ``displacements`` (m) and ``tensions`` (N), by tendon name (eq. 17).

    ``sliding`` ({tendon: 'in' | 'out' | 'stuck'}, default in) is the direction each tendon
    slides, which sets the sense of its friction. A stuck tendon's tension profile
    is anywhere between the two: the result is the estimate at the middle of that band
    (no friction in it) with :attr:`~tendonsense.result.Result.magnitude_range`
    ``[[low, high], …]``, the estimates at its ends (±inf on the side of an end without an
    equilibrium, said in its ``note``): the magnitudes' 1-σ band is the noise's at the
    middle, the range is what the friction leaves open.

    ``x0`` (a previous result's ``extra['x']``) warm-starts the solve. The result carries
    ``magnitudes`` (N for point forces, a scale for gravity), their 1-σ band ``sigma`` for
    the sensor ``noise`` and ``sensitivity``: ∂magnitudes/∂measurement per measurement. A
    result that did not converge is the solver's last iterate, no estimate: said by a
    :class:`~tendonsense.result.NotConvergedWarning`.
    """
    inputs.tendon_vector(check_robot(robot), displacements, "displacement")  # the robot's names
    prob = problem(robot, list(displacements), unknowns, point_forces)
    inputs.check_stuck(robot, sliding, tensions, bool(prob.located))
    if not sliding:
        return estimate_problem(prob, displacements, tensions, noise, x0)
    stuck = [robot.tendon_names.index(n) for n, d in inputs.sliding(robot, sliding).items()
             if d == "stuck"]
    values, signs = prob.model.values, inputs.friction_signs(robot, sliding)  # stuck: 0
    mid = estimate_problem(prob, displacements, tensions, noise, x0,
                           values._replace(friction=values.friction * signs))
    if (signs < 0).any() and x0 is None and not prob.located:
        mid = _other_equilibrium(prob, displacements, tensions, noise,
                                 values._replace(friction=values.friction * signs), mid)
    if not stuck:
        return mid
    ends, open_ends = [], []
    for combo in itertools.product((1.0, -1.0), repeat=len(stuck)):  # the band's corners
        signs[stuck] = combo
        end = estimate_problem(prob, displacements, tensions, noise, mid.extra["x"],
                               values._replace(friction=values.friction * signs))
        ends.append(end.magnitudes if end.converged else np.full(prob.n_magnitudes, np.nan))
        if not end.converged:
            open_ends.append(", ".join(f"{robot.tendon_names[k]} {'in' if c > 0 else 'out'}"
                                       for k, c in zip(stuck, combo)))
    extra = {**mid.extra, "magnitude_range": band_range(mid.magnitudes, ends)}
    if open_ends and mid.converged:
        extra["note"] = joined(extra.get("note"), (
            f"no equilibrium at the friction band's end ({' / '.join(open_ends)}): the range "
            "is open on that side"))
    if mid.converged and (note := band_note(mid.magnitudes, ends)):
        extra["note"] = joined(extra.get("note"), note)
    return dataclasses.replace(mid, extra=extra)


#: markers further apart than this (m), or magnitudes further apart than this (relative),
#: are two equilibria, not one solved twice
SAME_EQUILIBRIUM, SAME_MAGNITUDE = 1e-6, 1e-6


def _other_equilibrium(prob: Problem, displacements, tensions, noise: Noise, values: Values,
                       found: Result) -> Result:
    """``found`` (estimated from the straight rod with a tendon paid out), and where a second
    equilibrium explains the same readings, said so. Paid out, a tendon's tension grows toward
    its anchor and one reading can have two (the prototype at 2.4 N: 0.3 N down on the tip,
    or the rod curled up with 1.8 N pushing up). The readings are estimated again from the
    shape their tensions give without the unknown loads (forward statics: its last iterate,
    a start, whether or not it converged); if that converges elsewhere,
    ``extra['other_estimate']`` holds its magnitudes, 1-σ band and markers and the note says
    the reading is ambiguous. Only a second start: an equilibrium neither start reaches goes
    unseen."""
    if not found.converged:
        return found
    T, y = prob.readings(displacements, tensions)
    drive = prob.drive(T, y[list(prob.measured)])
    unloaded = solve_system(prob.model.structure, values, (), drive,
                            Unknowns.none(len(T), drive.load_X.shape[0]))
    start = np.concatenate([np.asarray(unloaded.x), np.zeros(prob.n_z)])
    if not np.isfinite(start).all():
        return found
    other = estimate_problem(prob, displacements, tensions, noise, start, values)
    apart = max((float(np.linalg.norm(np.subtract(p, other.markers[m])))
                 for m, p in found.markers.items()), default=0.0)
    moved = np.abs(np.subtract(other.magnitudes, found.magnitudes)) > SAME_MAGNITUDE * (
        1.0 + np.abs(found.magnitudes))
    if not other.converged or not (apart > SAME_EQUILIBRIUM or moved.any()):
        return found
    note = (f"ambiguous: another equilibrium explains these readings too, with magnitudes "
            f"{', '.join(f'{m:.4g}' for m in other.magnitudes)} (markers up to "
            f"{apart * 1e3:.1f} mm away; found from the shape without the unknown loads); a "
            f"paid-out tendon's reading alone cannot tell them apart")
    return dataclasses.replace(found, extra={
        **found.extra, "note": joined(found.extra.get("note"), note),
        "other_estimate": {"magnitudes": other.magnitudes, "sigma": other.sigma,
                           "markers": other.markers}})


def estimate_problem(prob: Problem, displacements, tensions, noise: Noise = Noise(),
                     x0=None, values: Values | None = None, budget: int | None = None,
                     total_budget: int | None = None) -> Result:
    """:func:`estimate` on a prepared :func:`problem`; ``values`` overrides the robot file's
    values (e.g. a friction error, :meth:`Model.with_values`) without recompiling; ``budget``
    bounds the evaluations of each equilibrium solve (:func:`~tendonsense.statics.solve_system`),
    ``total_budget`` those of a least-squares fit's solves together.
    With located unknowns ``x0`` is not used: their X is searched over its whole range."""
    check_noise(noise, prob.robot)
    model = prob.model
    T, y_all = prob.readings(displacements, tensions,
                             None if values is None else float(values.young_modulus))
    drive = prob.drive(T, y_all[list(prob.measured)])
    values = model.values if values is None else values
    if prob.located:
        return _locate(prob, drive, values, T, noise, budget)
    _preload(prob, drive, values)
    x, converged, iterations, res, misfit, why = _solve(prob, drive, values, x0, budget,
                                                        total_budget)
    return _result(prob, x, drive, values, T, noise, converged, iterations, res, misfit,
                   why=why)


def _preload(prob: Problem, drive: Drive, values: Values) -> None:
    """The programs an estimate runs after its solve (its Jacobians, the shape's outputs),
    loaded from disk on another thread while the solve's own loads and runs."""
    preload_jacobians(prob, drive, values)
    preload_outputs(prob.model.structure, prob.model.values)  # (as :func:`make_result`)


def _solve(prob: Problem, drive: Drive, values: Values, x0, budget, total_budget=None):
    """(x, converged, iterations, Newton result, length misfit, why not converged or None)
    of a square or least-squares problem."""
    model = prob.model
    if len(prob.measured) == prob.n_z:
        res = solve_system(model.structure, values, prob.measured, drive, prob.unknowns, x0,
                           budget)
        return np.asarray(res.x), bool(res.converged), int(res.iterations), res, 0.0, None
    return _least_squares(prob, drive, values, x0, prob.robot.numerics.tolerance, budget,
                          total_budget)


def _result(prob: Problem, x, drive, values, T, noise, converged, iterations, res, misfit,
            why=None, **extra) -> Result:
    n = prob.n_magnitudes
    if converged and (over := prob.overloaded(x, float(values.young_modulus))[0]):
        converged, why = False, over
    parts = jacobians(prob, x, drive, values)  # one call for σ and both checks
    sens, sigma, cov, (Jz, JT) = _uncertainty(prob, x, drive, values, T, noise, parts)
    # a load the measured tendons cannot see: no estimate, whether the solver stuck where it
    # started or a fit stopped at once (its gradient 0: "converged", σ 0 from the pseudo-inverse)
    blind, blind_why = unseen(prob, x, drive, values, parts)
    sigma[list(blind)] = np.inf
    if blind and (converged or why is None):
        converged, why = False, blind_why
    z = x[prob.model.nq:]
    if converged and len(prob.measured) > prob.n_z:  # a least-squares fit: is it one?
        y = shape_outputs(prob.model.structure, values, x[:prob.model.nq])[2]
        columns = np.flatnonzero(np.asarray(T, float) != 0)
        extra["note"] = joined(extra.get("note", ""), misfit_note(
            Jz, JT[:, columns], y[list(prob.measured)] - np.asarray(drive.targets),
            np.asarray(T, float)[columns], noise))
    note = joined(extra.pop("note", ""), converged and confounded(cov, n),
                  converged and unstable_at(prob, x, drive, values, parts))
    return make_result(prob.model, x, T, NewtonResult(x, converged, iterations, res.residual, 0,
                                                   level=res.level),
                       why=why,
                       magnitudes=z[:n], sigma=sigma[:n],
                       sensitivity={k: v[:n] for k, v in sens.items()},
                       extra={"x": x, "length_misfit": misfit, **_located(prob, x, sigma),
                              **extra, **({"note": note} if note else {})})


#: points of the misfit profile over X for one located force (per located force for two)
PROFILE_POINTS = (21, 9)

#: relative Gauss–Newton step at which a profile point's magnitudes count as found
PROFILE_STEP = 1e-3

#: a location whose 1-σ band exceeds this fraction of the rod length is poorly determined
POOR_LOCATION = 0.1


def _locate(prob: Problem, drive: Drive, values: Values, T, noise: Noise, budget) -> Result:
    """Located unknowns: a profile of the least-squares length misfit over X (each point a
    warm-started Gauss–Newton solve of the magnitudes on the compiled tracker), then Newton /
    Gauss–Newton on (q, magnitudes, X) from the best point. A minimum at the end of a range is
    reported there, the magnitudes solved with X held at that end."""
    model, n_loc = prob.model, len(prob.located)
    if n_loc > len(PROFILE_POINTS):
        raise ValueError(f"at most {len(PROFILE_POINTS)} forces of unknown location, "
                         f"got {n_loc}")
    # from the tip end down: a force at the base moves nothing, its magnitude undetermined
    axes = [np.linspace(b, a, PROFILE_POINTS[n_loc - 1]) for _, (a, b) in prob.located]
    grid = np.stack([g.ravel() for g in np.meshgrid(*axes, indexing="ij")], axis=1)
    if n_loc == 2:  # a serpentine path: neighbours warm-start each other
        m = len(axes[1])
        grid = grid.reshape(-1, m, 2)
        grid[1::2] = grid[1::2, ::-1]
        grid = grid.reshape(-1, 2)
    fixed = prob.fixed()
    drives = [prob.at(X).drive(drive.tensions, drive.targets) for X in grid]
    stacked = jax.tree_util.tree_map(lambda *a: np.stack([np.asarray(v, float) for v in a]),
                                     *drives)
    first, converged, *_ = _solve(prob.at(grid[0]).fixed(), drives[0], values, None, budget)
    track = tracker(model.structure, prob.measured, fixed.n_z, tuple(range(model.n_tendons)),
                    step_tol=PROFILE_STEP)
    tr = jax.device_get(track(np.asarray(first, float), stacked, fixed.unknowns, values, {}))
    sel = list(prob.measured)
    misfit = np.where(tr.converged, np.sqrt(np.mean(
        (tr.lengths[:, sel] - np.asarray(drive.targets)) ** 2, axis=1)), np.nan)
    profile = {"X": grid[:, 0] if n_loc == 1 else grid, "misfit": misfit}
    if not np.isfinite(misfit).any():
        x = np.concatenate([first, np.zeros(n_loc)])
        return _result(prob.at(grid[0]), x, drives[0], values, T, noise, False, 0,
                       NewtonResult(x, False, 0, np.inf, 0), np.inf,
                       note="no point of the location profile converged",
                       location_profile=profile)
    best = int(np.nanargmin(misfit))
    here = prob.at(grid[best])
    d_here = here.drive(drive.tensions, drive.targets)
    x0 = np.concatenate([tr.x[best], np.zeros(n_loc)])
    x, converged, iterations, res, length_misfit, why = _solve(here, d_here, values, x0,
                                                               budget)
    X = here.locations(x)
    lo, hi = np.array([r for _, r in prob.located]).T
    span = hi - lo
    inside = np.all((X >= lo - 1e-9 * span) & (X <= hi + 1e-9 * span))
    notes = []
    if converged and inside:  # the same state, referred to the estimated X
        here = prob.at(X)
        d_here = here.drive(drive.tensions, drive.targets)
        x = np.concatenate([x[:-n_loc], np.zeros(n_loc)])
    else:
        # the minimum lies at an end of a range (or the refinement failed): hold X there
        unrefined = not converged
        if unrefined:  # the reason the result is not converged
            X = grid[best]
            unrefined = (f"the location refinement did not converge: X held at the profile's "
                         f"best point ({', '.join(f'{x_:g} m' for x_ in X)})")
        X = np.clip(X, lo, hi)
        at_end = [f"{x_:g} m" for x_, a, b in zip(X, lo, hi) if x_ in (a, b)]
        if at_end:
            notes.append(f"location at the end of its range ({', '.join(at_end)}): the "
                         f"misfit keeps falling beyond it")
        here = prob.at(X)
        d_here = here.drive(drive.tensions, drive.targets)
        xf, converged, iterations, res, length_misfit, why = _solve(
            here.fixed(), d_here, values, tr.x[best], budget)
        x = np.concatenate([xf, np.zeros(n_loc)])
        converged = converged and not unrefined
        why = why or unrefined or None
    result = _result(here, x, d_here, values, T, noise, converged, iterations, res,
                     length_misfit, why, location_profile=profile)
    poor = [f"{s:.3g} m" for s in result.extra["location_sigma"] if s is not None
            and not s <= POOR_LOCATION * prob.robot.rod.length]
    if poor:
        notes.append(f"location poorly determined: 1-σ band {', '.join(poor)} is more than "
                     f"{POOR_LOCATION:.0%} of the rod length")
    if notes:
        result.extra["note"] = joined(result.extra.get("note"), *notes)
    return result


def _located(prob: Problem, x, sigma) -> dict:
    """``locations`` and ``location_sigma``: one entry per unknown, None where X is known."""
    X, s = prob.locations(x), np.asarray(sigma)[prob.n_magnitudes:]
    rows = np.asarray(prob.unknowns.forces)[:prob.n_magnitudes].any(axis=2)  # (n_z, n_loads)
    index = {i: k for k, (i, _) in enumerate(prob.located)}
    out = {"locations": [], "location_sigma": []}
    for row in rows:
        k = next((index[i] for i in np.flatnonzero(row) if i in index), None)
        out["locations"].append(None if k is None else float(X[k]))
        out["location_sigma"].append(None if k is None else float(s[k]))
    return out


def _uncertainty(prob: Problem, x, drive, values, T, noise: Noise, parts=None):
    """First-order sensitivity of the magnitudes to every measurement, the 1-σ band and the
    covariance: ``dz/dm = −(∂e/∂z)⁺ ∂e/∂m`` with ``e = y(q(z, T)) − y_meas`` (exact for
    square problems, Gauss–Newton for least squares)."""
    names = prob.robot.tendon_names
    Jz, JT = reduced_jacobians(prob, x, drive, values, parts)
    pinv = np.linalg.pinv(Jz)
    dz_dT = -pinv @ JT  # ∂e/∂y_meas = −I: dz/dy_meas = pinv
    columns = [j for j in range(len(names)) if T[j] != 0 or j in prob.measured]
    sens = {f"displacement_{names[j]}": pinv[:, k] for k, j in enumerate(prob.measured)}
    sens.update({f"tension_{names[j]}": dz_dT[:, j] for j in columns})
    cov = noise_covariance(np, np.concatenate([pinv, dz_dT[:, columns]], axis=1),
                           len(prob.measured), np.asarray(T, float)[columns], noise.length,
                           noise.tension)
    return sens, np.sqrt(np.diag(cov)), cov, (Jz, JT)
