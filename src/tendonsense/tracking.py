"""The fast path for sequences of readings: one compiled scan over the samples.

Each sample starts from a first-order prediction (the previous solution plus its sensitivity
times the change of the measurements) and takes quasi-Newton steps with an inverse Jacobian
carried along the scan and kept current by Broyden updates. A step that does not halve the
residual triggers a fresh exact Jacobian at the current point, after which the iteration is
the damped Newton method of :mod:`tendonsense.statics` (Armijo backtracking). Convergence is
tested exactly as there, so the results agree with the plain path to the solver tolerance.
The sensitivity to the measurements, ``dx/dm = −R_x⁻¹ R_m``, uses the carried inverse with two
steps of iterative refinement against the exact ``R_x`` (JVPs).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache
from typing import Mapping, NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from . import linalg, tendons
from .compiled import Program
from .estimation import Noise, Problem, estimate_problem
from .forward import model_for
from .inputs import tendon_vector
from .kinematics import poses, positions
from .model import VALUE_NAMES, Structure, points_at
from .robot import Robot
from .statics import (CACHE_SIZE, Drive, Scaling, Unknowns, admissible, residual,
                      scaling, shape_outputs, solve_system)


class Track(NamedTuple):
    """Per-sample outputs (leading axis: sample, for a series)."""

    x: jax.Array  # (N, nq + n_z) solution [q; z]
    converged: jax.Array  # (N,) converged and admissible
    iterations: jax.Array  # (N,) residual evaluations
    jacobians: jax.Array  # (N,) exact Jacobians computed
    dx_dm: jax.Array  # (N, nq + n_z, n_meas + n_T) sensitivity to [y_meas; T_columns]
    markers: jax.Array  # (N, n_markers, 3)
    lengths: jax.Array  # (N, n_t) tendon length changes, eq. 9
    admissible: jax.Array  # (N,) strain within the model's range (:func:`admissible`)


class Carry(NamedTuple):
    """What a sample hands the next: the last good solution, the inverse Jacobian there, its
    sensitivity to the measurements and those measurements."""

    x: jax.Array
    H: jax.Array
    dx_dm: jax.Array
    measurements: jax.Array
    ok: jax.Array
    count: jax.Array
    scaling: Scaling  # of the residual, for samples that keep the values of the first


#: work budget of one sample on the fast path: residual evaluations and exact Jacobians
MAX_EVALUATIONS, MAX_JACOBIANS = 60, 6


def _sample_fns(structure: Structure, measured: tuple[int, ...], n_z: int,
                tension_columns: tuple[int, ...], refine_every: int, step_tol: float = 1e-8):
    """``init(x0, d0, p0, unknowns, values) -> Carry`` and
    ``step(carry, d, p, unknowns, values) -> (Carry, Track row)`` of the tracker (pure):
    quasi-Newton for a square system, Gauss–Newton SQP for least squares (n_z < n_a)."""
    num = structure.numerics
    nq = structure.nq
    tcols = np.array(tension_columns, int)
    sel = np.array(measured, int)

    def at(values, p, sc=None):  # the values of one sample and their residual scaling
        if p or sc is None:  # (a Cholesky factorisation and inverse: not per sample)
            v = values._replace(**p) if p else values
            return v, scaling(v, measured)
        return values, sc

    def f(x, d, unknowns, vs, with_actuation=False):  # (r, load size[, ∂r/∂T])
        return residual(structure, vs[0], measured, x, d, unknowns, 1.0, vs[1],
                        with_actuation=with_actuation)

    def jac(x, d, unknowns, vs):
        return jax.jacfwd(lambda x: f(x, d, unknowns, vs)[0])(x)

    def merit(r):
        m = 0.5 * jnp.dot(r, r)
        return jnp.where(jnp.isfinite(m), m, jnp.inf)

    def measurements(d):
        return jnp.concatenate([d.targets, d.tensions[tcols]])

    def init(x0, d0, p0, unknowns, values):
        m0 = measurements(d0)
        vs = at(values, p0)
        return Carry(x0, linalg.inv(jac(x0, d0, unknowns, vs)),
                     jnp.zeros((x0.size, m0.size)), m0, jnp.asarray(False), jnp.asarray(0),
                     vs[1])

    def step(carry: Carry, d, p, unknowns, values):
        vs = at(values, p, carry.scaling)
        sc = vs[1]
        floor = vs[0].energy_floor * jnp.sqrt(vs[0].young_modulus)
        # first-order tangent predictor from the previous sample's sensitivity
        guess = carry.x + jnp.where(carry.ok, carry.dx_dm @ (measurements(d) - carry.measurements),
                                    0.0)
        r, s = f(guess, d, unknowns, vs)
        st = dict(x=guess, r=r, s=s, H=carry.H, fresh=jnp.asarray(False),
                  alpha=jnp.asarray(1.0), evals=jnp.asarray(1), jacs=jnp.asarray(0),
                  status=jnp.where(jnp.linalg.norm(r) <= num.tolerance * (s + floor), 1, 0))

        def cond(st):
            return (st["status"] == 0) & (st["evals"] < MAX_EVALUATIONS)

        def body(st):
            dx = -st["H"] @ st["r"]
            xt = st["x"] + st["alpha"] * dx
            rt, ts = f(xt, d, unknowns, vs)
            m0, mt = merit(st["r"]), merit(rt)
            contracts = mt <= 0.25 * m0
            armijo = mt <= (1 - 2e-4 * st["alpha"]) * m0
            accept = contracts | (st["fresh"] & armijo)
            conv = jnp.linalg.norm(rt) <= num.tolerance * (ts + floor)
            refresh = ~accept & ~st["fresh"]
            # good Broyden update of the inverse on an accepted step, exact on refresh
            step, dr = xt - st["x"], rt - st["r"]
            Hy = st["H"] @ dr
            denom = jnp.dot(step, Hy)
            safe = accept & (jnp.abs(denom) > 1e-300)
            broyden = st["H"] + jnp.outer(step - Hy, step @ st["H"]) / jnp.where(
                safe, denom, 1.0)
            H = jax.lax.cond(refresh, lambda: linalg.inv(jac(st["x"], d, unknowns, vs)),
                             lambda: jnp.where(safe, broyden, st["H"]))
            give_up = (~accept & st["fresh"] & (st["alpha"] < 2.0**-30)) | (
                refresh & (st["jacs"] >= MAX_JACOBIANS))
            return dict(
                x=jnp.where(accept, xt, st["x"]), r=jnp.where(accept, rt, st["r"]),
                s=jnp.where(accept, ts, st["s"]), H=H,
                fresh=jnp.where(accept, False, True),
                alpha=jnp.where(accept | refresh, 1.0, st["alpha"] / 2),
                evals=st["evals"] + 1, jacs=st["jacs"] + refresh.astype(int),
                status=jnp.where(accept, jnp.where(conv, 1, 0), jnp.where(give_up, 2, 0)))

        st = jax.lax.while_loop(cond, body, st)
        x = st["x"]
        fine = admissible(vs[0], x[:nq])
        ok = (st["status"] == 1) & fine
        # sensitivity to the measurements [y_meas; T]: R_x dx = −R_m dm
        # ∂r/∂y_meas is −√k on the length rows, ∂r/∂T = −L⁻¹B on the equilibrium rows
        Ry = jnp.zeros((x.size, sel.size)).at[nq + jnp.arange(sel.size),
                                               jnp.arange(sel.size)].set(-sc.root_k)
        rT = f(x, d, unknowns, vs, with_actuation=True)[2]  # once, not in every evaluation
        Rm = jnp.concatenate([Ry, rT[:, tcols]], axis=1)
        Rx = jax.vmap(lambda u: jax.jvp(lambda x: f(x, d, unknowns, vs)[0], (x,), (u,))[1],
                      in_axes=1, out_axes=1)

        def refine(H):
            # the exact products W = R_x v give a block (multi-secant) Broyden update of the
            # inverse, H W = v, then the refined v = −H R_m
            v = -H @ Rm
            W = Rx(v)
            HW = H @ W
            M = v.T @ HW
            ok_m = jnp.abs(jnp.linalg.det(M)) > 1e-300
            Hn = H + (v - HW) @ linalg.solve(jnp.where(ok_m, M, jnp.eye(M.shape[0])),
                                             v.T @ H)
            return jnp.where(ok_m, Hn, H)

        H = jax.lax.cond(carry.count % refine_every == 0, refine, lambda H: H, st["H"])
        return finish(carry, d, values, x, ok, fine, H, -H @ Rm, st["evals"], st["jacs"])

    def finish(carry, d, values, x, ok, fine, H, dx_dm, evals, jacs):
        grid, g = poses(values, x[:nq], points_at(structure, values, values.marker_X))
        markers = positions(g, values.marker_offsets)
        y = tendons.length_changes(structure, values, grid, x[:nq])
        # a failed sample leaves the carry as it was: the next one starts from the last good
        new = Carry(x, H, dx_dm, measurements(d), ok, carry.count + 1, carry.scaling)
        keep = carry._replace(count=carry.count + 1)
        out = jax.tree_util.tree_map(lambda a, b: jnp.where(ok, a, b), new, keep)
        return out, Track(x, ok, evals, jacs, dx_dm, markers, y, fine)

    def linear(x, d, unknowns, vs):  # (J, r, load size, ∂r/∂T), one residual evaluation
        def with_aux(x):
            out = f(x, d, unknowns, vs, with_actuation=True)
            return out[0], out
        J, (r, s, rT) = jax.jacfwd(with_aux, has_aux=True)(x)
        return J, r, s, rT

    def kkt(J):
        """eq. 17 linearised: min ‖r_y + C dx‖² subject to r_E + A dx = 0, J = [A; C], as the
        system [[CᵀC, Aᵀ], [A, 0]] [dx; λ]."""
        A, C = J[:nq], J[nq:]
        return jnp.block([[C.T @ C, A.T], [A, jnp.zeros((nq, nq))]])

    def gauss_newton(J, r):
        C = J[nq:]
        rhs = jnp.concatenate([-C.T @ r[nq:], -r[:nq]])
        return jnp.linalg.solve(kkt(J), rhs)[:nq + n_z]

    def init_ls(x0, d0, p0, unknowns, values):
        m0 = measurements(d0)
        n = nq + n_z
        return Carry(x0, jnp.zeros((n, n)), jnp.zeros((n, m0.size)), m0, jnp.asarray(False),
                     jnp.asarray(0), at(values, p0)[1])

    def step_ls(carry: Carry, d, p, unknowns, values):
        vs = at(values, p, carry.scaling)
        floor = vs[0].energy_floor * jnp.sqrt(vs[0].young_modulus)
        guess = carry.x + jnp.where(carry.ok, carry.dx_dm @ (measurements(d) - carry.measurements),
                                    0.0)

        def merit(r):  # equilibrium weighted above the lengths: the SQP step descends on it
            m = 0.5 * (10.0 * jnp.dot(r[:nq], r[:nq]) + jnp.dot(r[nq:], r[nq:]))
            return jnp.where(jnp.isfinite(m), m, jnp.inf)

        def stationary(x, r, s, dx):
            # equilibrium holds and the Gauss–Newton step in z is below its resolution, or
            # the lengths are met exactly
            small = num.tolerance * (s + floor)
            z = x[nq:]
            return (jnp.linalg.norm(r[:nq]) <= small) & (
                (jnp.linalg.norm(dx[nq:]) <= step_tol * (jnp.linalg.norm(z) + 1e-6))
                | (jnp.linalg.norm(r[nq:]) <= small))

        J, r, s, rT = linear(guess, d, unknowns, vs)
        dx = gauss_newton(J, r)
        st = dict(x=guess, J=J, r=r, s=s, rT=rT, dx=dx, alpha=jnp.asarray(1.0),
                  evals=jnp.asarray(1), jacs=jnp.asarray(1),
                  status=jnp.where(stationary(guess, r, s, dx), 1, 0))

        def cond(st):
            return (st["status"] == 0) & (st["evals"] < MAX_EVALUATIONS) & (
                st["jacs"] < 2 * MAX_JACOBIANS)

        def body(st):
            xt = st["x"] + st["alpha"] * st["dx"]
            Jt, rt, ts, rTt = linear(xt, d, unknowns, vs)
            # Armijo on the merit, or a step that restores equilibrium (where the lengths'
            # misfit is large, e.g. a force tried at the wrong X, the merit alone can refuse
            # the step to the constrained minimum)
            rE, rEt = jnp.linalg.norm(st["r"][:nq]), jnp.linalg.norm(rt[:nq])
            accept = (merit(rt) <= (1 - 1e-4 * st["alpha"]) * merit(st["r"])) | (
                (rEt <= 0.5 * rE) & (rE > num.tolerance * (st["s"] + floor))
                & jnp.isfinite(merit(rt)))
            dxt = gauss_newton(Jt, rt)
            new = dict(x=xt, J=Jt, r=rt, s=ts, rT=rTt, dx=dxt, alpha=jnp.asarray(1.0),
                       status=jnp.where(stationary(xt, rt, ts, dxt), 1, 0))
            old = dict(st, alpha=st["alpha"] / 2,
                       status=jnp.where(st["alpha"] < 2.0**-20, 2, 0))
            out = jax.tree_util.tree_map(lambda a, b: jnp.where(accept, a, b), new,
                                         {k: old[k] for k in new})
            return dict(out, evals=st["evals"] + 1, jacs=st["jacs"] + 1)

        st = jax.lax.while_loop(cond, body, st)
        x = st["x"]
        fine = admissible(vs[0], x[:nq])
        ok = (st["status"] == 1) & fine
        # Gauss–Newton sensitivity to the measurements [y_meas; T] (as the uncertainty of
        # eq. 17 in :mod:`tendonsense.estimation`): the same KKT system, right-hand side R_m
        Ry = jnp.zeros((x.size - n_z + sel.size, sel.size)).at[
            nq + jnp.arange(sel.size), jnp.arange(sel.size)].set(-vs[1].root_k)
        Rm = jnp.concatenate([Ry, st["rT"][:, tcols]], axis=1)
        C = st["J"][nq:]
        rhs = jnp.concatenate([-C.T @ Rm[nq:], -Rm[:nq]])
        dx_dm = linalg.solve(kkt(st["J"]), rhs)[:nq + n_z]
        return finish(carry, d, values, x, ok, fine, carry.H, dx_dm, st["evals"], st["jacs"])

    if len(measured) > n_z:
        return init_ls, step_ls
    return init, step


@lru_cache(maxsize=CACHE_SIZE)
def tracker(structure: Structure, measured: tuple[int, ...], n_z: int,
            tension_columns: tuple[int, ...], refine_every: int = 1, step_tol: float = 1e-8):
    """Compiled ``track(x0, drives, unknowns, values, varied) -> Track`` for a square system
    (``len(measured) == n_z``) or least squares (more measured tendons); ``drives`` is a
    :class:`Drive` and ``varied`` a dict of values by name
    (:data:`~tendonsense.model.VALUE_NAMES`, may be empty), both with a leading sample axis.
    The sensitivity columns are the measured lengths, then the tensions of the tendons
    ``tension_columns``. A least-squares sample is stationary when its Gauss–Newton step in z
    is below ``step_tol`` relative (a coarse value suits a profile that is refined later)."""
    init, step = _sample_fns(structure, measured, n_z, tension_columns, refine_every, step_tol)

    def track(x0, drives, unknowns, values, varied):
        d0, p0 = jax.tree_util.tree_map(lambda a: a[0], (drives, varied))
        carry = init(x0, d0, p0, unknowns, values)
        _, out = jax.lax.scan(lambda c, dp: step(c, *dp, unknowns, values), carry,
                              (drives, varied))
        return out

    return Program(track, "tracker", (structure, measured, n_z, tension_columns, refine_every,
                                       step_tol))


@lru_cache(maxsize=CACHE_SIZE)
def stepper(structure: Structure, measured: tuple[int, ...], n_z: int,
            tension_columns: tuple[int, ...], refine_every: int = 1):
    """The tracker one sample at a time: compiled ``init(x0, d0, p0, unknowns, values)`` and
    ``step(carry, d, p, unknowns, values) -> (carry, row)``, the row packed into one vector
    (one transfer to the host; :func:`unpack_row`)."""
    init, step = _sample_fns(structure, measured, n_z, tension_columns, refine_every)

    def packed(carry, d, p, unknowns, values):
        carry, row = step(carry, d, p, unknowns, values)
        return carry, jnp.concatenate([jnp.ravel(a).astype(float) for a in row])

    key = (structure, measured, n_z, tension_columns, refine_every)
    return Program(init, "stepper_init", key), Program(packed, "stepper_step", key)


def unpack_row(flat: np.ndarray, n_x: int, n_m: int, n_markers: int, n_t: int) -> Track:
    """A :class:`Track` row from the packed vector of :func:`stepper` (numpy)."""
    sizes = (n_x, 1, 1, 1, n_x * n_m, 3 * n_markers, n_t, 1)
    x, conv, its, jacs, dx_dm, markers, y, fine = np.split(flat, np.cumsum(sizes)[:-1])
    return Track(x, bool(conv[0]), int(its[0]), int(jacs[0]), dx_dm.reshape(n_x, n_m),
                 markers.reshape(n_markers, 3), y, bool(fine[0]))


def stacked_drives(prob: Problem, tensions: np.ndarray, targets: np.ndarray) -> Drive:
    """The problem's drive for every row of ``tensions`` (N, n_t) and ``targets`` (N, n_m)."""
    n = tensions.shape[0]
    return Drive(jnp.asarray(tensions, float),
                 jnp.asarray(np.broadcast_to(prob.known_forces, (n, *prob.known_forces.shape))),
                 jnp.asarray(np.broadcast_to(prob.load_X, (n, *prob.load_X.shape))),
                 jnp.asarray(np.broadcast_to(prob.gravity, (n, 3))), jnp.asarray(targets, float))


@dataclass(frozen=True, eq=False)
class SampleEstimate:
    """One sample of a series: magnitudes with their 1-σ band, markers (global, m)."""

    magnitudes: np.ndarray
    sigma: np.ndarray
    markers: dict[str, np.ndarray]
    converged: bool
    iterations: int
    x: np.ndarray
    note: str = ""  # why a sample is not converged
    locations: np.ndarray = field(default_factory=lambda: np.zeros(0))  # located forces' X, m
    location_sigma: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @staticmethod
    def failed(prob: Problem, note: str, x=None, iterations: int = 0) -> "SampleEstimate":
        """A sample that has no estimate (not-a-number magnitudes and markers)."""
        nan = np.full(prob.n_magnitudes, np.nan)
        x = np.full(prob.model.nq + prob.n_z, np.nan) if x is None else x
        loc = np.full(len(prob.located), np.nan)
        return SampleEstimate(nan, nan.copy(), {m: np.full(3, np.nan)
                                                for m in prob.robot.marker_names},
                              False, iterations, x, note, loc, loc.copy())


#: evaluations of the solve from the straight rod that a sample the fast path could not
#: converge gets once an earlier sample has converged (the first gets the full budget)
RESCUE_BUDGET = 12


def estimate_series(prob: Problem, displacements: Sequence[Mapping[str, float]],
                    tensions: Sequence[Mapping[str, float]], noise: Noise = Noise(),
                    chunk: int = 100, progress=None,
                    values: Mapping[str, object] | None = None) -> list[SampleEstimate]:
    """Estimate a time series of readings, each sample warm-started from the previous one;
    ``values`` ({name: (N,)}, as for :func:`solve_batch`) gives each sample its own E, ν, ρ
    or μ (e.g. a Monte Carlo over friction).

    The compiled tracker takes them in chunks of ``chunk`` samples (quasi-Newton for square
    problems, Gauss–Newton SQP for least squares); a sample it cannot converge is solved again
    on its own from the straight rod (load continuation, a bounded budget once an earlier
    sample has converged); a bad reading (non-finite, negative tension, a tendon pulled in
    beyond its length) is marked with the reason. ``progress(done, total)`` is called per
    chunk (:func:`series_chunks` hands over each chunk's estimates as it finishes)."""
    n = len(displacements)
    out: list[SampleEstimate | None] = [None] * n
    for first, estimates in series_chunks(prob, displacements, tensions, noise, chunk, values):
        out[first:first + len(estimates)] = estimates
        if progress:
            progress(first + len(estimates), n)
    return out


def series_chunks(prob: Problem, displacements: Sequence[Mapping[str, float]],
                  tensions: Sequence[Mapping[str, float]], noise: Noise = Noise(),
                  chunk: int = 100, values: Mapping[str, object] | None = None):
    """:func:`estimate_series` as it goes: yields ``(first, estimates)`` for consecutive
    samples ``first, first + 1, …`` as each chunk is done."""
    robot, model = prob.robot, prob.model
    n = len(displacements)
    if prob.located:  # sample by sample: X searched first, then followed (and after failures)
        if values:
            raise ValueError("values per sample are not available with located forces")
        from .online import OnlineEstimator
        online = OnlineEstimator(prob, noise, rescue_budget=RESCUE_BUDGET)
        for first in range(0, n, chunk):
            yield first, [online.update(d, t) for d, t in
                          zip(displacements[first:first + chunk], tensions[first:first + chunk])]
        return
    for what, readings in (("tension", tensions), ("displacement", displacements)):
        for name in {name for r in readings for name in r}:
            if name not in robot.tendon_names:
                raise ValueError(f"{what} {name}: no such tendon (robot has "
                                 f"{', '.join(robot.tendon_names)})")
    varied = _varied_values(model.values, values, n)
    T, Y = np.zeros((n, len(robot.tendons))), np.zeros((n, len(robot.tendons)))
    out: list[SampleEstimate | None] = [None] * n
    for k in range(n):
        try:
            T[k], Y[k] = prob.readings(displacements[k], tensions[k])
        except ValueError as exc:
            out[k] = SampleEstimate.failed(prob, f"bad value: {exc}")
    tcols = tuple(sorted(set(prob.measured) | set(np.flatnonzero(np.any(T != 0, axis=0)))))
    track = tracker(model.structure, prob.measured, prob.n_z, tcols, 4)
    meas = list(prob.measured)
    valid = [k for k in range(n) if out[k] is None]
    x0, seen_good, done = None, False, 0
    for start in range(0, len(valid), chunk):
        idx = valid[start:start + chunk]
        if x0 is None:  # the first sample solved from the straight rod (square problems)
            x0 = _first_solution(prob, T[idx[0]], Y[idx[0], meas], model.values._replace(
                **{name: v[idx[0]] for name, v in varied.items()}))
        # a fixed scan length (padded with the last sample) keeps one compiled tracker
        rows = list(idx) + [idx[-1]] * (chunk - len(idx))
        drives = stacked_drives(prob, T[rows], Y[rows][:, meas])
        tr = jax.device_get(track(jnp.asarray(x0), drives, prob.unknowns, model.values,
                                  {name: jnp.asarray(v[rows]) for name, v in varied.items()}))
        for j, k in enumerate(idx):
            if tr.converged[j]:
                sigma = band(tr.dx_dm[j, model.nq:, :], len(meas), T[k, list(tcols)], noise)
                out[k] = SampleEstimate(
                    tr.x[j, model.nq:], sigma, dict(zip(robot.marker_names, tr.markers[j])),
                    True, int(tr.iterations[j]), tr.x[j])
            else:
                out[k] = _from_result(estimate_problem(
                    prob, displacements[k], tensions[k], noise,
                    values=model.values._replace(**{name: v[k] for name, v in varied.items()}),
                    budget=RESCUE_BUDGET if seen_good else None))
            seen_good = seen_good or out[k].converged
        good = [out[k].x for k in idx if out[k].converged]
        x0 = good[-1] if good else x0
        end = idx[-1] + 1 if start + chunk < len(valid) else n
        yield done, out[done:end]
        done = end
    if done < n:  # every sample bad
        yield done, out[done:]


def _first_solution(prob: Problem, T, targets, values) -> np.ndarray:
    """A start for a series: its first sample solved from the straight rod with load
    continuation (square problems; the straight rod itself for least squares, or if that
    solve fails: the series' own fallback then takes over)."""
    x0 = np.zeros(prob.model.nq + prob.n_z)
    if len(prob.measured) != prob.n_z:
        return x0
    res = solve_system(prob.model.structure, values, prob.measured, prob.drive(T, targets),
                       prob.unknowns, None)
    return np.asarray(res.x) if bool(res.converged) else x0


def band(dz_dm: np.ndarray, n_lengths: int, tensions: np.ndarray, noise: Noise) -> np.ndarray:
    """1-σ band of the magnitudes from their sensitivity ``dz_dm`` to [lengths; tensions]
    (first-order propagation of the sensor noise, as in :mod:`tendonsense.estimation`)."""
    scale = np.concatenate([np.full(n_lengths, noise.length),
                            noise.tension * np.abs(tensions)])
    return np.sqrt(((dz_dm * scale) ** 2).sum(axis=1))


def _from_result(r) -> SampleEstimate:
    note = "" if r.converged else r.extra.get("note", "did not converge")
    located = [k for k, v in enumerate(r.extra.get("locations", [])) if v is not None]
    return SampleEstimate(np.asarray(r.magnitudes), np.asarray(r.sigma), dict(r.markers),
                          bool(r.converged), int(r.iterations), np.asarray(r.extra["x"]), note,
                          np.array([r.extra["locations"][k] for k in located]),
                          np.array([r.extra["location_sigma"][k] for k in located]))


def _principal_order(m: np.ndarray) -> np.ndarray:
    """Rows of ``m`` ordered along their first principal direction (standardised columns), so
    that neighbours warm-start each other."""
    if m.shape[0] < 2:
        return np.arange(m.shape[0])
    z = (m - m.mean(0)) / np.maximum(m.std(0), 1e-300)
    return np.argsort(z @ np.linalg.svd(z, full_matrices=False)[2][0])


def estimate_batch(prob: Problem, displacements: Sequence[Mapping[str, float]],
                   tensions: Sequence[Mapping[str, float]], noise: Noise = Noise(),
                   workers: int = 2, progress=None,
                   values: Mapping[str, object] | None = None) -> list[SampleEstimate]:
    """Estimate independent readings, returned in the input order; ``values`` gives each
    its own E, ν, ρ or μ ({name: (N,)}, as for :func:`solve_batch`).

    The readings are ordered along their first principal direction so that neighbours
    warm-start each other, cut into ``workers`` runs, and the runs are solved concurrently
    (one thread each; the compiled tracker releases the GIL, so each takes a core).
    """
    from concurrent.futures import ThreadPoolExecutor
    robot = prob.robot
    n = len(displacements)
    varied = _varied_values(prob.model.values, values, n)
    m = np.array([np.concatenate([tendon_vector(robot, y, "displacement"),
                                  tendon_vector(robot, t, "tension")])
                  for y, t in zip(displacements, tensions)]).reshape(n, -1)
    m = np.concatenate([m, *(v.reshape(n, -1) for v in varied.values())], axis=1)
    runs = [r for r in np.array_split(_principal_order(m), max(1, workers)) if r.size]
    done = [0] * len(runs)

    def solve_run(i):
        def tick(d, _):
            done[i] = d
            if progress:
                progress(sum(done), n)
        return estimate_series(prob, [displacements[k] for k in runs[i]],
                               [tensions[k] for k in runs[i]], noise, progress=tick,
                               values={name: v[runs[i]] for name, v in varied.items()})

    with ThreadPoolExecutor(len(runs)) as pool:
        solved = list(pool.map(solve_run, range(len(runs))))
    out: list = [None] * n
    for run, res in zip(runs, solved):
        for k, r in zip(run, res):
            out[k] = r
    return out


# ----------------------------------------------------------------------------- forward batches

@dataclass(frozen=True, eq=False)
class BatchResult:
    """Forward-statics solutions of a batch (leading axis: sample, input order); m, global."""

    q: np.ndarray  # (N, nq)
    markers: dict[str, np.ndarray]  # name -> (N, 3)
    displacements: dict[str, np.ndarray]  # tendon -> (N,), eq. 9
    converged: np.ndarray  # (N,) bool
    iterations: np.ndarray  # (N,) residual evaluations


def solve_batch(robot: Robot, tensions, point_forces: Sequence = (),
                values: Mapping[str, object] | None = None, chunk: int = 100,
                workers: int = 2) -> BatchResult:
    """Forward statics over a batch of tensions, point loads and values, for sweeps and Monte
    Carlo: one compiled program per robot structure, whatever the numbers.

    ``tensions``: (N, n_t) array (tendons in file order) or {tendon: (N,) array}.
    ``point_forces``: [(X, f), ...] where X may be (N,) and f (N, 3). ``values``: {name: (N,)}
    for ``young_modulus``, ``poisson_ratio``, ``density``, ``friction`` ((N,) one μ for every
    tendon, or (N, n_t)). The samples are ordered along their first principal direction and
    solved by the compiled tracker, each warm-started from its neighbour, on ``workers``
    threads; a sample it cannot converge is solved again on its own from the straight rod
    with load continuation.

    >>> E = np.linspace(0.8e6, 1.2e6, 1000)
    >>> out = solve_batch(robot, {"t1": np.full(1000, 2.0)}, values={"young_modulus": E})
    >>> out.markers["tip"].shape, bool(out.converged.all())
    ((1000, 3), True)
    """
    from concurrent.futures import ThreadPoolExecutor
    model = model_for(robot)
    structure, base = model.structure, model.values
    T, X, F, varied = _batch_inputs(robot, base, tensions, point_forces, values)
    n, n_t = T.shape
    if n == 0:
        raise ValueError("batch: no samples")
    g = np.broadcast_to(np.asarray(robot.gravity, float), (n, 3))
    unknowns = Unknowns.none(n_t, X.shape[1])
    tcols = tuple(int(j) for j in np.flatnonzero(np.any(T != 0, axis=0)))
    track = tracker(structure, (), 0, tcols, 4)
    features = np.concatenate([T, X, F.reshape(n, -1), *(v.reshape(n, -1)
                                                          for v in varied.values())], axis=1)
    runs = [r for r in np.array_split(_principal_order(features), max(1, workers)) if r.size]
    q, mk = np.zeros((n, structure.nq)), np.zeros((n, len(robot.markers), 3))
    y, conv, its = np.zeros((n, n_t)), np.zeros(n, bool), np.zeros(n, int)

    def drive(rows):
        return Drive(jnp.asarray(T[rows]), jnp.asarray(F[rows]), jnp.asarray(X[rows]),
                     jnp.asarray(g[rows]), jnp.zeros((len(rows), 0)))

    def solve_run(run):
        x0 = np.zeros(structure.nq)
        for start in range(0, run.size, chunk):
            idx = run[start:start + chunk]
            rows = np.concatenate([idx, np.full(chunk - idx.size, idx[-1])])
            tr = jax.device_get(track(jnp.asarray(x0), drive(rows), unknowns, base,
                                      {k: jnp.asarray(v[rows]) for k, v in varied.items()}))
            for j, k in enumerate(idx):
                if tr.converged[j]:
                    q[k], mk[k], y[k], conv[k], its[k] = (tr.x[j], tr.markers[j], tr.lengths[j],
                                                          True, tr.iterations[j])
                    continue
                v = base._replace(**{name: jnp.asarray(a[k]) for name, a in varied.items()})
                res = solve_system(structure, v, (), jax.tree_util.tree_map(
                    lambda a: a[0], drive([k])), unknowns)
                markers, _, lengths, fine = shape_outputs(structure, v, res.x)
                q[k], mk[k], y[k] = np.asarray(res.x), markers, lengths
                conv[k], its[k] = bool(res.converged) and bool(fine), int(res.evaluations)
            good = np.flatnonzero(conv[idx])
            if good.size:
                x0 = q[idx[good[-1]]]

    with ThreadPoolExecutor(len(runs)) as pool:
        list(pool.map(solve_run, runs))
    return BatchResult(q, {m: mk[:, i] for i, m in enumerate(robot.marker_names)},
                       {t: y[:, j] for j, t in enumerate(robot.tendon_names)}, conv, its)


def _batch_inputs(robot: Robot, base, tensions, point_forces, values):
    """Validated batch arrays: T (N, n_t), X (N, n_p), F (N, n_p, 3) and the varied values."""
    names = robot.tendon_names
    if isinstance(tensions, Mapping):
        cols = {k: np.atleast_1d(np.asarray(v, float)) for k, v in tensions.items()}
        for k in cols:
            if k not in names:
                raise ValueError(f"tension {k}: no such tendon (robot has {', '.join(names)})")
        n = max((c.size for c in cols.values()), default=1)
        T = np.stack([np.broadcast_to(cols.get(k, np.zeros(1)), (n,)) for k in names], axis=1)
    else:
        T = np.asarray(tensions, float).reshape(-1, len(names))
    n = T.shape[0]
    X = np.stack([np.broadcast_to(np.asarray(x, float), (n,)) for x, _ in point_forces], axis=1) \
        if point_forces else np.zeros((n, 0))
    F = np.stack([np.broadcast_to(np.asarray(f, float), (n, 3)) for _, f in point_forces],
                 axis=1) if point_forces else np.zeros((n, 0, 3))
    if not (np.all(np.isfinite(T)) and np.all(np.isfinite(X)) and np.all(np.isfinite(F))):
        raise ValueError("batch: tensions and point forces must be finite")
    if np.any(T < 0):
        raise ValueError("batch: a tension is negative (a tendon cannot push)")
    if np.any((X < 0) | (X > robot.rod.length)):
        raise ValueError(f"batch: a point force X is outside the rod [0, {robot.rod.length:g}]")
    return T, X, F, _varied_values(base, values, n)


def _varied_values(base, values, n: int) -> dict[str, np.ndarray]:
    """Per-sample values {name: (n, ...)}, validated: a name of :data:`VALUE_NAMES`, finite;
    ``friction`` (n,) is one μ for every tendon, (n, n_t) one per tendon."""
    varied = {}
    for k, val in (values or {}).items():
        if k not in VALUE_NAMES:
            raise ValueError(f"{k}: not a value that can be varied (one of "
                             f"{', '.join(VALUE_NAMES)})")
        a = np.asarray(val, float)
        if k == "friction" and a.ndim <= 1:  # one μ for every tendon
            a = a.reshape(-1, 1)
        try:
            varied[k] = np.broadcast_to(a, (n, *np.shape(getattr(base, k))))
        except ValueError:
            raise ValueError(f"batch: {k} has shape {np.shape(val)}, not one value per "
                             f"sample ({n})") from None
        if not np.all(np.isfinite(varied[k])):
            raise ValueError(f"batch: {k} must be finite")
    return varied
