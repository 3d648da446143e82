"""The fast path: the compiled per-sample step of the estimation problem, over a series (one
compiled scan, :func:`tracker`) or one sample at a time (:func:`live`).

Each sample starts from a first-order prediction (the previous solution plus its sensitivity
times the change of the measurements) and takes quasi-Newton steps with an inverse Jacobian
carried along the scan and kept current by Broyden updates. A step that does not halve the
residual triggers a fresh exact Jacobian at the current point, after which the iteration is
the damped Newton method of :mod:`tendonsense.statics` (Armijo backtracking). Convergence is
tested exactly as there, so the results agree with the plain path to the solver tolerance.
The sensitivity to the measurements, ``dx/dm = −R_x⁻¹ R_m``, uses the carried inverse; on
every ``exact_every``-th sample (the first included) one more pass forms that inverse exactly
at the solution, with the loop's own Jacobian (one copy of it in the program).
"""

from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

from . import linalg, tendons
from .compiled import Program
from .inputs import EDGE, Noise
from .kinematics import poses, positions
from .model import Structure, points_at
from .problem import Problem, noise_covariance
from .sliding import FIXED_POINT, STATE_TOL, Band, play, pulled, reach
from .stability import UNSTABLE, scaled_ratios
from .statics import CACHE_SIZE, Drive, Scaling, admissible, residual, scaling


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
    # least squares: the measured lengths' sensitivities to the unknowns (N, n_meas, n_z) and
    # to the tensions of the sensitivity's columns (N, n_meas, n_T), the equilibrium
    # eliminated (m per unit, m/N; for the misfit's test), zeros for a square system
    Jz: jax.Array
    JT: jax.Array


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
#: one sample in every ``EXACT_EVERY`` (the first of a scan included) forms the exact inverse
#: Jacobian at its solution; the others carry Broyden's, so that their sensitivity (and 1-σ
#: band) is within a few per cent of the exact one (the speed page gives the figures)
EXACT_EVERY = 4
#: Bates–Watts relative offsets: a least-squares sample is at its minimum below the first; a
#: step onto such a point that lowers the merit by less than Armijo asks is taken below the
#: second (the plain path's :data:`~tendonsense.estimation.RELATIVE_OFFSET`)
OFFSET, RELATIVE_OFFSET = 1e-6, 1e-3


def _sample_fns(structure: Structure, measured: tuple[int, ...], n_z: int,
                tension_columns: tuple[int, ...], exact_every: int = EXACT_EVERY,
                step_tol: float = 1e-8):
    """``init(x0, d0, p0, unknowns, values) -> Carry`` and
    ``step(carry, d, p, unknowns, values, skip=False) -> (Carry, Track row)`` of the tracker
    (pure; ``skip``: the sample is not attempted, 0 iterations, the carry kept):
    quasi-Newton for a square system, Gauss–Newton SQP for least squares (n_z < n_a)."""
    num = structure.numerics
    nq = structure.nq
    tcols = np.array(tension_columns, int)
    sel = np.array(measured, int)

    def at(values, p, sc=None):  # the values of one sample and their residual scaling
        v = values._replace(**p) if p else values
        # (a Cholesky factorisation and inverse of K: not per sample unless K changes)
        if sc is None or "young_modulus" in p or "poisson_ratio" in p:
            return v, scaling(v, measured)
        return v, sc

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
        # no inverse yet: the first sample's loop forms it (one copy of the Jacobian's
        # program), and again at its solution
        return Carry(x0, jnp.zeros((x0.size, x0.size)), jnp.zeros((x0.size, m0.size)), m0,
                     jnp.asarray(False), jnp.asarray(0), vs[1])

    def step(carry: Carry, d, p, unknowns, values, skip=False):
        vs = at(values, p, carry.scaling)
        sc = vs[1]
        floor = vs[0].energy_floor * jnp.sqrt(vs[0].young_modulus)
        # first-order tangent predictor from the previous sample's sensitivity
        guess = carry.x + jnp.where(carry.ok, carry.dx_dm @ (measurements(d) - carry.measurements),
                                    0.0)
        # the loop's first pass evaluates the guess (r = 0 there: no step; one copy of the
        # residual's program)
        st = dict(x=guess, r=jnp.zeros(guess.size), s=jnp.asarray(0.0), H=carry.H,
                  rT=jnp.zeros((guess.size, d.tensions.size)), fresh=jnp.asarray(False),
                  alpha=jnp.asarray(1.0), evals=jnp.asarray(0), jacs=jnp.asarray(0),
                  status=jnp.asarray(0))

        # every exact_every-th sample (the first included) and while no inverse has been
        # formed: once converged, one more pass forms the exact inverse there
        exact = (carry.count % exact_every == 0) | ~jnp.any(carry.H != 0)

        def cond(st):
            return (((st["status"] == 0) & (st["evals"] < MAX_EVALUATIONS)) | (
                (st["status"] == 1) & exact & ~st["fresh"])) & ~jnp.asarray(skip)

        def body(st):
            dx = -st["H"] @ st["r"]
            xt = st["x"] + st["alpha"] * dx
            again = st["status"] == 1  # converged: the pass that forms the inverse at x

            def converged(r, s):
                return jnp.linalg.norm(r) <= num.tolerance * (s + floor)

            # ∂r/∂T at the solution only (where this pass converges; once a sample)
            rt, ts, rTt = f(xt, d, unknowns, vs, lambda r, s: converged(r, s) & ~again)
            m0, mt = merit(st["r"]), merit(rt)
            contracts = mt <= 0.25 * m0
            armijo = mt <= (1 - 2e-4 * st["alpha"]) * m0
            first = st["evals"] == 0
            accept = first | ((contracts | (st["fresh"] & armijo)) & ~again)
            conv = converged(rt, ts)
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
            give_up = ~again & ((~accept & st["fresh"] & (st["alpha"] < 2.0**-30)) | (
                refresh & (st["jacs"] >= MAX_JACOBIANS)))
            return dict(
                x=jnp.where(accept, xt, st["x"]), r=jnp.where(accept, rt, st["r"]),
                s=jnp.where(accept, ts, st["s"]), rT=jnp.where(accept, rTt, st["rT"]), H=H,
                fresh=jnp.where(accept, False, True),
                alpha=jnp.where(accept | refresh, 1.0, st["alpha"] / 2),
                evals=st["evals"] + 1, jacs=st["jacs"] + refresh.astype(int),
                status=jnp.where(again, 1, jnp.where(accept, jnp.where(conv, 1, 0),
                                                     jnp.where(give_up, 2, 0))))

        st = jax.lax.while_loop(cond, body, st)
        x = st["x"]
        fine = admissible(vs[0], x[:nq])
        ok = (st["status"] == 1) & fine
        # sensitivity to the measurements [y_meas; T]: R_x dx = −R_m dm
        # ∂r/∂y_meas is −√k on the length rows, ∂r/∂T = −L⁻¹B on the equilibrium rows
        Ry = jnp.zeros((x.size, sel.size)).at[nq + jnp.arange(sel.size),
                                               jnp.arange(sel.size)].set(-sc.root_k)
        Rm = jnp.concatenate([Ry, st["rT"][:, tcols]], axis=1)
        return finish(carry, d, values, x, ok, fine, st["H"], -st["H"] @ Rm, st["evals"],
                      st["jacs"], jnp.zeros((sel.size, n_z)),
                      jnp.zeros((sel.size, tcols.size)))

    def finish(carry, d, values, x, ok, fine, H, dx_dm, evals, jacs, Jz, JT):
        grid, g = poses(values, x[:nq], points_at(structure, values, values.marker_X))
        markers = positions(g, values.marker_offsets)
        y = tendons.length_changes(structure, values, grid, x[:nq])
        # a failed sample leaves the carry as it was: the next one starts from the last good
        new = Carry(x, H, dx_dm, measurements(d), ok, carry.count + 1, carry.scaling)
        keep = carry._replace(count=carry.count + 1)
        out = jax.tree_util.tree_map(lambda a, b: jnp.where(ok, a, b), new, keep)
        return out, Track(x, ok, evals, jacs, dx_dm, markers, y, fine, Jz, JT)

    def linear(x, d, unknowns, vs):  # (J, r, load size, ∂r/∂T), one residual evaluation
        def with_aux(x):
            out = f(x, d, unknowns, vs, with_actuation=True)
            return out[0], out
        J, (r, s, rT) = jax.jacfwd(with_aux, has_aux=True)(x)
        return J, r, s, rT

    def eliminated(J, r):
        """The constraint r_E + A dx = 0 of :func:`gauss_newton` eliminated through
        A = [A_q A_z]: ``(a, M, G, h)`` with dx_q = a + M dz and the rest r_y + C dx = h + G dz
        (``r`` (n, k))."""
        A_q, A_z, C_q, C_z = J[:nq, :nq], J[:nq, nq:], J[nq:, :nq], J[nq:, nq:]
        sol = linalg.solve(A_q, jnp.concatenate([r[:nq], A_z], axis=1))
        a, M = -sol[:, :r.shape[1]], -sol[:, r.shape[1]:]
        return a, M, C_q @ M + C_z, r[nq:] + C_q @ a

    def gauss_newton(J, r, parts=None):
        """eq. 17 linearised: ``dx`` of min ‖r_y + C dx‖² subject to r_E + A dx = 0 (J = [A; C],
        r = [r_E; r_y], either (n,) or with columns), the constraint eliminated
        (:func:`eliminated`, or its ``parts`` if known), and dz by least squares on the rest."""
        a, M, G, h = eliminated(J, r.reshape(r.shape[0], -1)) if parts is None else parts
        dz = -linalg.solve(G.T @ G, G.T @ h)
        return jnp.concatenate([a + M @ dz, dz]).reshape((nq + n_z, *r.shape[1:]))

    def init_ls(x0, d0, p0, unknowns, values):
        m0 = measurements(d0)
        n = nq + n_z
        return Carry(x0, jnp.zeros((n, n)), jnp.zeros((n, m0.size)), m0, jnp.asarray(False),
                     jnp.asarray(0), at(values, p0)[1])

    def step_ls(carry: Carry, d, p, unknowns, values, skip=False):
        vs = at(values, p, carry.scaling)
        floor = vs[0].energy_floor * jnp.sqrt(vs[0].young_modulus)
        guess = carry.x + jnp.where(carry.ok, carry.dx_dm @ (measurements(d) - carry.measurements),
                                    0.0)

        def merit(r):  # equilibrium weighted above the lengths: the SQP step descends on it
            m = 0.5 * (10.0 * jnp.dot(r[:nq], r[:nq]) + jnp.dot(r[nq:], r[nq:]))
            return jnp.where(jnp.isfinite(m), m, jnp.inf)

        def stationary(x, J, r, s, dx):
            # equilibrium holds and the Gauss–Newton step in z is below its resolution, or it
            # would explain a negligible share of the lengths' misfit (the Bates–Watts
            # relative offset, as in :mod:`tendonsense.estimation`), or the lengths are met
            small = num.tolerance * (s + floor)
            z, ry = x[nq:], r[nq:]
            return (jnp.linalg.norm(r[:nq]) <= small) & (
                (jnp.linalg.norm(dx[nq:]) <= step_tol * (jnp.linalg.norm(z) + 1e-6))
                | (jnp.linalg.norm(J[nq:] @ dx) <= OFFSET * jnp.linalg.norm(ry))
                | (jnp.linalg.norm(ry) <= small))

        # the loop's first pass evaluates the guess (dx = 0 there; one copy of the
        # linearisation's program)
        n = nq + sel.size
        st = dict(x=guess, J=jnp.zeros((n, guess.size)), r=jnp.zeros(n), s=jnp.asarray(0.0),
                  rT=jnp.zeros((n, d.tensions.size)), dx=jnp.zeros(guess.size),
                  alpha=jnp.asarray(1.0), evals=jnp.asarray(0), jacs=jnp.asarray(0),
                  status=jnp.asarray(0))

        def cond(st):
            return (st["status"] == 0) & (st["evals"] < MAX_EVALUATIONS) & (
                st["jacs"] < 2 * MAX_JACOBIANS) & ~jnp.asarray(skip)

        def body(st):
            xt = st["x"] + st["alpha"] * st["dx"]
            Jt, rt, ts, rTt = linear(xt, d, unknowns, vs)
            # Armijo on the merit, or a step that restores equilibrium (where the lengths'
            # misfit is large, e.g. a force tried at the wrong X, the merit alone can refuse
            # the step to the constrained minimum), or a small step onto a stationary point
            # (near a minimum with a misfit left no step lowers the merit by Armijo's share:
            # a step whose Bates–Watts offset is o moves it by at most (2o + o²))
            rE, rEt = jnp.linalg.norm(st["r"][:nq]), jnp.linalg.norm(rt[:nq])
            dxt = gauss_newton(Jt, rt)
            at_minimum = stationary(xt, Jt, rt, ts, dxt)
            o = st["alpha"] * jnp.linalg.norm(st["J"][nq:] @ st["dx"]) / jnp.maximum(
                jnp.linalg.norm(st["r"][nq:]), 1e-300)
            first = st["evals"] == 0
            accept = first | (merit(rt) <= (1 - 1e-4 * st["alpha"]) * merit(st["r"])) | (
                (rEt <= 0.5 * rE) & (rE > num.tolerance * (st["s"] + floor))
                & jnp.isfinite(merit(rt))) | (
                at_minimum & (o <= RELATIVE_OFFSET)
                & (merit(rt) <= (1 + 2 * o + o * o + 1e-12) * merit(st["r"])))
            new = dict(x=xt, J=Jt, r=rt, s=ts, rT=rTt, dx=dxt, alpha=jnp.asarray(1.0),
                       status=jnp.where(at_minimum, 1, 0))
            old = dict(st, alpha=st["alpha"] / 2,
                       status=jnp.where(st["alpha"] < 2.0**-20, 2, 0))
            out = jax.tree_util.tree_map(lambda a, b: jnp.where(accept, a, b), new,
                                         {k: old[k] for k in new})
            return dict(out, evals=st["evals"] + 1, jacs=st["jacs"] + 1)

        st = jax.lax.while_loop(cond, body, st)
        x = st["x"]
        fine = admissible(vs[0], x[:nq])
        # a stationary point at an unstable equilibrium, reached from the last sample's
        # solution, is no state the robot holds: where the magnitudes are poorly determined
        # the fit can slide to one along the readings' blind direction (the sample is then
        # solved on its own, from the straight rod; a sample started afresh, e.g. from such a
        # solution, is taken as it is); the stiffness ratios of
        # :func:`~tendonsense.stability.unstable`
        ratios = scaled_ratios(st["J"][:nq, :nq], vs[1].L_inv)
        ok = (st["status"] == 1) & fine & (~carry.ok | (jnp.min(ratios) >= -UNSTABLE))
        # Gauss–Newton sensitivity to the measurements [y_meas; T] (as the uncertainty of
        # eq. 17 in :mod:`tendonsense.estimation`): the same elimination, right-hand side R_m
        Ry = jnp.zeros((x.size - n_z + sel.size, sel.size)).at[
            nq + jnp.arange(sel.size), jnp.arange(sel.size)].set(-vs[1].root_k)
        Rm = jnp.concatenate([Ry, st["rT"][:, tcols]], axis=1)
        parts = eliminated(st["J"], Rm)
        dx_dm = gauss_newton(st["J"], Rm, parts)
        # the lengths' rows are √k-scaled: G = √k dy/dz, h = √k dy/dT (the tensions' columns)
        G, h = parts[2:]
        root_k = vs[1].root_k[:, None]
        return finish(carry, d, values, x, ok, fine, carry.H, dx_dm, st["evals"], st["jacs"],
                      G / root_k, h[:, sel.size:] / root_k)

    if len(measured) > n_z:
        return init_ls, step_ls
    return init, step


def _until_failure(sample, carry, xs, count, failing):
    """The outputs of ``lax.scan`` of ``sample(carry, x, skip) -> (carry, ys)`` (``ys[0]`` a
    :class:`Track` row) over the first ``count`` samples (the rest padding), stopped at a
    failure after a converged sample (``failing``: the sample before the first failed): each
    sample after it, and the padding, is skipped (not attempted: its track row not converged,
    0 iterations, the carry kept). The caller solves such a failure its own way and scans again
    after it; failures in a row (no solution over a stretch) are scanned through."""

    def body(c, xs):
        carry, stop, failed, k = c
        carry, ys = sample(carry, xs, stop | (k >= count))
        fails = ~ys[0].converged
        return (carry, stop | (fails & ~failed), fails, k + 1), ys

    return jax.lax.scan(body, (carry, jnp.asarray(False), jnp.asarray(failing), 0), xs)[1]


@lru_cache(maxsize=CACHE_SIZE)
def tracker(structure: Structure, measured: tuple[int, ...], n_z: int,
            tension_columns: tuple[int, ...], exact_every: int = EXACT_EVERY,
            step_tol: float = 1e-8, until_failure: bool = False):
    """Compiled ``track(x0, drives, unknowns, values, varied) -> Track`` for a square system
    (``len(measured) == n_z``) or least squares (more measured tendons); ``drives`` is a
    :class:`Drive` and ``varied`` a dict of values by name
    (:data:`~tendonsense.model.VALUE_NAMES`, may be empty), both with a leading sample axis.
    The sensitivity columns are the measured lengths, then the tensions of the tendons
    ``tension_columns``. A least-squares sample is stationary when its Gauss–Newton step in z
    is below ``step_tol`` relative (a coarse value suits a profile that is refined later).
    ``until_failure``: ``track`` takes two more arguments, ``count`` and ``failing``, and
    stops early (0 iterations from there): after the first ``count`` samples (the rest
    padding) and after a failure that follows a converged sample (``failing``: the sample
    before the first failed)."""
    init, step = _sample_fns(structure, measured, n_z, tension_columns, exact_every, step_tol)

    def track(x0, drives, unknowns, values, varied, *count_failing):
        d0, p0 = jax.tree_util.tree_map(lambda a: a[0], (drives, varied))
        carry = init(x0, d0, p0, unknowns, values)

        def one(c, dp, skip=False):
            c, row = step(c, *dp, unknowns, values, skip)
            return c, (row,)

        if until_failure:
            return _until_failure(one, carry, (drives, varied), *count_failing)[0]
        return jax.lax.scan(one, carry, (drives, varied))[1][0]

    return Program(track, "tracker", (structure, measured, n_z, tension_columns, exact_every,
                                       step_tol, until_failure))


#: the band's ends followed from sample to sample, at most 2**ENDS_KEPT (the first of them
#: when more tendons are stuck; the others start from the sample's own solution)
ENDS_KEPT = 6


class Ends(NamedTuple):
    """The ends of the stuck tendons' friction band, each followed from sample to sample
    (:func:`live`): slot j holds the carry of the j-th sign pattern of the stuck tendons (as
    ``itertools.product((-1, 1), ...)``: the first stuck tendon the most significant bit)."""

    carry: Carry  # leading axis: slots; without its scaling (the sample's)
    ok: jax.Array  # (slots,) the slot holds a converged carry
    stuck: jax.Array  # (n_t,) bool: the stuck tendons the slots are for


class Followed(NamedTuple):
    """What :func:`_followed` returns for one sample."""

    carry: Carry  # for the next sample (as it was if this one failed)
    row: Track  # the sample's own solution
    state: jax.Array  # (n_t, turns) the friction state it was solved with, at every turn
    band: Band  # the history after it (as it was if it failed)
    code: jax.Array | None = None  # (n_t,) each tendon's direction: +1 in, −1 out, 0 stuck
    ends: Ends | None = None  # the band's ends for the next sample
    z: jax.Array | None = None  # (2**n_t, n_z) the unknowns at each end (NaN: none)


def _followed(structure: Structure, step, carry, band, d, given, unknowns, values, skip,
              ends: Ends | None = None, stuck_given=None, tension_noise=None):
    """One sample whose friction follows its history (:func:`follower`): ``(carry, row,
    state, band after)``; a failed or skipped sample keeps the history. One solve per pass of
    one loop (one copy of ``step`` in the program).

    With ``ends``, the same loop then solves every end of the stuck tendons' band (each stuck
    tendon pulled in or paid out: eq. 10's exponent at ∓μφ; the others at their state), each
    from its slot (or the sample's own carry: the slots are for one set of stuck tendons),
    and also returns each tendon's direction (+1 in, −1 out, 0 stuck: a state farther from
    ±1 than the tension noise reaches, as :func:`~tendonsense.sliding.labels`, or
    ``stuck_given``), the ends after the sample (as they were if none was solved) and the
    unknowns z at each end (NaN where not converged or not an end)."""
    nq = structure.nq
    mu = values.friction
    keeps, after_pull = pulled(band, d.tensions, given)
    ones = jnp.ones_like(band.phi)

    def solve(c, s):
        return step(c, d, {"friction": s * mu[:, None]}, unknowns, values)

    blank = jax.tree_util.tree_map(lambda a: jnp.zeros(a.shape, a.dtype),
                                   jax.eval_shape(solve, carry, ones)[1])
    zero = jnp.asarray(0)
    st = dict(k=zero, new=carry, tr=blank, s=ones, band=band, last=band.phi,
              settled=jnp.asarray(False), done=jnp.asarray(skip))
    if ends is not None:
        st.update(j=zero, n_ends=zero, stuck=jnp.zeros(mu.shape, bool), code=jnp.ones_like(mu),
                  ends=ends,
                  z=jnp.full((2 ** mu.shape[0], carry.x.size - nq), jnp.nan))

    def again(st):
        # one solve a pass: the sample's own, the first at the state of the last sample's
        # shape, then at its own until it settles; then the band's ends
        k, tr, s = st["k"], st["tr"], st["s"]
        # the turning of the shape (one copy in the program; not needed pulled in, nor for
        # the band's ends): the first pass's is the last sample's shape's
        phi = jax.lax.cond(keeps | st["settled"], lambda: jnp.zeros_like(band.phi),
                           lambda: tendons.depths(structure, values,
                                                  jnp.where(k == 0, carry.x, tr.x)[:nq]))
        last = jnp.where(k == 0, phi, st["last"])
        s_own, after_own = jax.lax.cond(
            keeps, lambda: (ones, after_pull),
            lambda: play(band._replace(phi=last), mu, d.tensions, phi, given))
        failed = (k > 0) & ~tr.converged
        settles = ~st["settled"] & (k > 0) & (
            failed | keeps | (jnp.max(jnp.abs(s_own - s)) <= STATE_TOL) | (k >= FIXED_POINT))
        settled = st["settled"] | settles
        out = dict(st, settled=settled, s=jnp.where(settled, s, s_own), last=last,
                   band=_where(settles, _where(failed, band, after_own), st["band"]))
        go, c_in, s_in = ~settled, st["new"], s_own
        if ends is not None:
            out, end, c_end, s_end = _next_end(out, settles, phi, stuck_given, tension_noise,
                                               mu)
            go, c_in = go | end, _where(settled, c_end, c_in)
            s_in = jnp.where(settled, s_end, s_in)
        c_out, row = jax.lax.cond(go, lambda: solve(c_in, s_in), lambda: (c_in, blank))
        out.update(k=k + ~settled, new=_where(settled, out["new"], c_out),
                   tr=_where(settled, tr, row), done=~go)
        if ends is not None:  # the end solved, in its slot (an index past the end: none)
            j, e = out["j"], out["ends"]
            at = jnp.where(end, j, out["z"].shape[0])

            def put(a, b):
                return a.at[at].set(b, mode="drop")

            out.update(j=j + end, z=put(out["z"], jnp.where(row.converged, row.x[nq:], jnp.nan)),
                       ends=Ends(jax.tree_util.tree_map(put, e.carry, c_out._replace(
                           scaling=None)), put(e.ok, row.converged), e.stuck))
        return out

    st = jax.lax.while_loop(lambda st: ~st["done"], again, st)
    if ends is None:
        return Followed(st["new"], st["tr"], st["s"], st["band"])
    # the ends kept for the next stuck sample: as they were when none was solved (the
    # sample failed, or nothing is stuck)
    kept = _where(st["n_ends"] > 0, st["ends"]._replace(stuck=st["stuck"]), ends)
    return Followed(st["new"], st["tr"], st["s"], st["band"], st["code"], kept, st["z"])


def _next_end(st, settles, phi, stuck_given, tension_noise, mu):
    """:func:`_followed`'s band ends: on the pass where the sample settles (``phi`` the
    turning of its shape), its directions, stuck tendons and number of ends (2**stuck, none
    if it failed or none is stuck); on each pass from there, whether an end is left to solve,
    the carry it starts from and its state. An end starts from its own last carry or from
    the sample's; its sensitivity is not needed (no exact pass: the carry's inverse Jacobian
    is refreshed where it fails)."""
    s, tr = st["s"], st["tr"]
    anchor = s[:, -1]  # a tendon's direction is its anchor's
    edge = jnp.maximum(EDGE, reach(mu, phi[:, -1], tension_noise, jnp))
    sliding = (anchor >= 1 - edge) | (anchor <= -1 + edge)
    stuck = tr.converged & (jnp.asarray(stuck_given, bool) | ~sliding)
    n = jnp.sum(stuck)
    st = dict(st, stuck=jnp.where(settles, stuck, st["stuck"]),
              code=jnp.where(settles, jnp.where(stuck, 0.0,
                                                jnp.where(anchor >= 1 - edge, 1.0, -1.0)),
                             st["code"]),
              n_ends=jnp.where(settles, jnp.where(n > 0, jnp.left_shift(1, n), 0),
                               st["n_ends"]))
    stuck, j, e = st["stuck"], st["j"], st["ends"]
    # the j-th sign pattern of the stuck tendons, the first the most significant bit
    shift = jnp.where(stuck, jnp.sum(stuck) - jnp.cumsum(stuck), 0)
    signs = jnp.where(stuck[:, None],
                      jnp.where(jnp.right_shift(j, shift) & 1, 1.0, -1.0)[:, None], s)
    # the same ends as the last sample's (ends past the slots start afresh)
    follows = (j < e.ok.size) & e.ok[j] & jnp.all(e.stuck == stuck)
    slot = jax.tree_util.tree_map(lambda a: a[j], e.carry)._replace(scaling=st["new"].scaling)
    start = _where(follows, slot, st["new"])._replace(count=jnp.ones_like(st["new"].count))
    return st, st["settled"] & (j < st["n_ends"]), start, signs


def _where(c, a, b):
    """``a`` where ``c`` else ``b``, leaf by leaf of two trees of one structure."""
    return jax.tree_util.tree_map(lambda a, b: jnp.where(c, a, b), a, b)


@lru_cache(maxsize=CACHE_SIZE)
def follower(structure: Structure, measured: tuple[int, ...], n_z: int,
             tension_columns: tuple[int, ...], exact_every: int = EXACT_EVERY):
    """Compiled ``follow(x0, drives, unknowns, values, given, band, count, failing) -> (Track,
    states, bands)``, stopping early as :func:`tracker`'s ``until_failure``:
    :func:`tracker` with every tendon's friction following its history
    (:mod:`tendonsense.sliding`). A sample that keeps every tendon pulled in is solved with
    friction μ; any other with friction s_j μ past each turn j, its state s (n_t, turns)
    settled at its own shape by up to :data:`~tendonsense.sliding.FIXED_POINT` solves, each
    from the last (the first with the turning of the last sample's shape). ``given`` (N, n_t):
    states set by the log, NaN where the history decides; ``band``
    (:class:`~tendonsense.sliding.Band`, per turn) the history before the first sample,
    ``bands`` after each; ``states`` (N, n_t, turns). A failed or skipped sample leaves the
    history as it was."""
    init, step = _sample_fns(structure, measured, n_z, tension_columns, exact_every)

    def follow(x0, drives, unknowns, values, given, band, count, failing):
        def sample(c, dg, skip):
            out = _followed(structure, step, c[0], c[1], *dg, unknowns, values, skip)
            return (out.carry, out.band), (out.row, out.state, out.band)

        carry = init(x0, jax.tree_util.tree_map(lambda a: a[0], drives),
                     {"friction": values.friction}, unknowns, values)
        return _until_failure(sample, (carry, band), (drives, given), count, failing)

    return Program(follow, "follower", (structure, measured, n_z, tension_columns,
                                         exact_every))


class LiveRow(NamedTuple):
    """One sample's outputs of :meth:`Live.sample` (numpy; :meth:`Live.unpack`)."""

    x: np.ndarray  # (n_x,) the solution [q; z]
    converged: bool  # and admissible
    iterations: int  # residual evaluations
    admissible: bool  # strain within the model's range
    markers: np.ndarray  # (n_markers, 3)
    sigma: np.ndarray  # (n_z,) 1-σ band of z
    covariance: np.ndarray  # (n_z, n_z) of z, whose diagonal's root is ``sigma``
    state: np.ndarray  # (n_t, turns) the friction state it was solved with, at every turn
    code: np.ndarray  # (n_t,) each tendon's direction: +1 in, −1 out, 0 stuck
    lengths: np.ndarray  # (n_t,) tendon length changes, eq. 9
    Jz: np.ndarray  # (n_meas, n_z) least squares: :class:`Track`'s (zeros if square)
    JT: np.ndarray  # (n_meas, n_T)
    z: np.ndarray  # (2**n_t, n_z) the unknowns at each end of the band (NaN: none)


class Live:
    """The follower one sample at a time, each sample one call
    (:class:`~tendonsense.online.OnlineEstimator`): :func:`follower`'s sample and the ends of
    its stuck tendons' band (:func:`_followed`), with the state it carries from sample to
    sample (the carry, the friction history and the ends) as one vector and the reading as
    another (a call's cost grows with the number of its arrays):

    - ``start(x0, reading, loads, unknowns, values) -> state``: a carry at ``x0``, no
      history, no ends;
    - ``sample(state, reading, loads, unknowns, values) -> (state, packed)``, the outputs
      packed into one vector (:meth:`unpack`);
    - ``put(state, x0, reading, loads, unknowns, values, slot) -> (state, admissible)``: a
      carry at ``x0`` (e.g. a rescue's solution at a band's end) into the end's slot.

    ``reading`` (:meth:`reading`) holds the tensions, the targets, the states the reading
    sets (NaN: the history decides; all +1: every tendon pulled in, friction μ), where it
    says a tendon is stuck, the noise, and a restart: from ``x`` (e.g. a rescue's solution)
    instead of the state's carry, the history and the ends kept. ``loads``: the drive's
    point forces (n_p, 3), their X (n_p,) and gravity (3,). The sensitivity columns (for the
    1-σ band) are the measured lengths and the tensions of ``tension_columns``. ``follows``:
    whether friction follows a history (else the state keeps no ends); ``turns``: the
    friction states of a tendon (:func:`~tendonsense.tendons.turns` of the values)."""

    def __init__(self, structure: Structure, measured: tuple[int, ...], n_z: int,
                 tension_columns: tuple[int, ...], follows: bool, turns: int,
                 exact_every: int = EXACT_EVERY):
        init, step = _sample_fns(structure, measured, n_z, tension_columns, exact_every)
        nq, n_t, n_m = structure.nq, structure.n_tendons, len(measured)
        self.turns = turns
        n_x = nq + n_z
        self.sizes = (n_t, n_m, n_t, n_t, 1, 1, 1, n_x)
        self.n_x, self.n_t, self.nq, self.n_m = n_x, n_t, nq, n_m
        self.n_T = len(tension_columns)
        slots = 2 ** min(n_t, ENDS_KEPT) if follows else 1
        tcols = np.array(tension_columns, int)

        def parts(reading, loads):
            T, targets, given, stuck, length, tension, restart, x0 = jnp.split(
                reading, np.cumsum(self.sizes)[:-1])
            return (Drive(T, *loads, targets), given, stuck > 0, length[0], tension[0],
                    restart[0] > 0, x0)

        def carry_at(x0, d, unknowns, values):
            return init(x0, d, {"friction": values.friction}, unknowns, values)

        def fresh(x0, d, unknowns, values):
            carry = carry_at(x0, d, unknowns, values)
            kept = jax.tree_util.tree_map(lambda a: jnp.broadcast_to(a, (slots, *a.shape)),
                                          carry._replace(scaling=None))
            return carry, Band(jnp.full((n_t, turns), jnp.nan), jnp.zeros(n_t),
                               jnp.zeros((n_t, turns))), Ends(
                kept, jnp.zeros(slots, bool), jnp.zeros(n_t, bool))

        def unravel(state, x0, d, unknowns, values):
            shapes = jax.eval_shape(fresh, x0, d, unknowns, values)
            return ravel_pytree(jax.tree_util.tree_map(
                lambda a: jnp.zeros(a.shape, a.dtype), shapes))[1](state)

        def start(x0, reading, loads, unknowns, values):
            return ravel_pytree(fresh(x0, parts(reading, loads)[0], unknowns, values))[0]

        def sample(state, reading, loads, unknowns, values):
            d, given, stuck, length, tension, restart, x0 = parts(reading, loads)
            carry, band, ends = unravel(state, x0, d, unknowns, values)
            carry = jax.lax.cond(restart, lambda: carry_at(x0, d, unknowns, values),
                                 lambda: carry)
            out = _followed(structure, step, carry, band, d, given, unknowns, values, False,
                            ends, stuck, tension)
            row = out.row
            cov = noise_covariance(jnp, row.dx_dm[nq:], n_m, d.tensions[tcols], length,
                                   tension)
            return ravel_pytree((out.carry, out.band, out.ends))[0], jnp.concatenate(
                [jnp.ravel(a).astype(float) for a in (
                    row.x, row.converged, row.iterations, row.admissible, row.markers, cov,
                    out.state, out.code, row.lengths, row.Jz, row.JT, out.z)])

        def put(state, x0, reading, loads, unknowns, values, slot):
            d = parts(reading, loads)[0]
            carry, band, ends = unravel(state, x0, d, unknowns, values)
            fine = admissible(values, x0[:nq])
            new = carry_at(x0, d, unknowns, values)._replace(scaling=None)
            ends = ends._replace(
                carry=jax.tree_util.tree_map(lambda a, b: a.at[slot].set(b), ends.carry, new),
                ok=ends.ok.at[slot].set(fine))
            return ravel_pytree((carry, band, ends))[0], fine

        key = (structure, measured, n_z, tension_columns, follows, turns, exact_every)
        self.start = Program(start, "live_start", key)
        self.sample = Program(sample, "live_sample", key)
        self.put = Program(put, "live_put", key)
        self.slots = slots

    def reading(self, tensions, targets, given, stuck, noise: Noise, restart=None
                ) -> np.ndarray:
        """The reading vector of :meth:`sample`; ``restart``: the solution to start from."""
        x0 = np.zeros(self.n_x) if restart is None else restart
        return np.concatenate([tensions, targets, given, stuck, (noise.length, noise.tension,
                                                                  restart is not None), x0])

    def unpack(self, flat: np.ndarray, n_markers: int) -> LiveRow:
        """:meth:`sample`'s packed vector (numpy), in the order it is packed."""
        n_x, n_t, n_z, n_m = self.n_x, self.n_t, self.n_x - self.nq, self.n_m
        ends = np.cumsum((n_x, 1, 1, 1, 3 * n_markers, n_z * n_z, n_t * self.turns, n_t, n_t,
                          n_m * n_z, n_m * self.n_T)).tolist()
        x, conv, its, fine, markers, cov, state, code, lengths, Jz, JT = (
            flat[a:b] for a, b in zip([0] + ends, ends))
        cov = cov.reshape(n_z, n_z)
        with np.errstate(invalid="ignore"):  # a failed sample's may not be finite
            sigma = np.sqrt(np.diag(cov))
        return LiveRow(x, bool(conv[0]), int(its[0]), bool(fine[0]), markers.reshape(-1, 3),
                       sigma, cov, state.reshape(n_t, self.turns), code, lengths,
                       Jz.reshape(n_m, n_z), JT.reshape(n_m, self.n_T),
                       flat[ends[-1]:].reshape(2 ** n_t, n_z))


@lru_cache(maxsize=CACHE_SIZE)
def live(structure: Structure, measured: tuple[int, ...], n_z: int,
         tension_columns: tuple[int, ...], follows: bool, turns: int,
         exact_every: int = EXACT_EVERY) -> Live:
    """The :class:`Live` programs of a problem (one per robot structure and problem shape)."""
    return Live(structure, measured, n_z, tension_columns, follows, turns, exact_every)


def stacked_drives(prob: Problem, tensions: np.ndarray, targets: np.ndarray) -> Drive:
    """The problem's drive for every row of ``tensions`` (N, n_t) and ``targets`` (N, n_m), as
    NumPy arrays (a compiled program takes them as they are; JAX arrays made here would each
    run an operation of their own)."""
    n = tensions.shape[0]
    return Drive(np.asarray(tensions, float),
                 np.broadcast_to(prob.known_forces, (n, *prob.known_forces.shape)).astype(float),
                 np.broadcast_to(prob.load_X, (n, *prob.load_X.shape)).astype(float),
                 np.broadcast_to(prob.gravity, (n, 3)).astype(float), np.asarray(targets, float))
