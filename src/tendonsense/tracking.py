"""Estimation over many readings: a time series on the compiled scan of
:mod:`tendonsense.fastpath` (each sample warm-started from the last), independent readings
and forward solves in batches over two threads.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Mapping, Sequence

import jax
import numpy as np

from .estimation import estimate_problem
from .fastpath import (MAX_EVALUATIONS, MAX_JACOBIANS, Carry, Track,  # noqa: F401 (API)
                       follower, stacked_drives, tracker)
from .forward import model_for, settled, sliding_values, why_not
from .inputs import (Noise, check_noise, first_force_error, force_pairs, friction_signs,
                     max_tension, outside_rod, per_sample, tendon_vector, tension_error)
from .model import VALUE_NAMES
from .online import RESCUE_BUDGET, OnlineEstimator
from .problem import Problem, band, confounded, covariance, misfit_notes  # noqa: F401 (API)
from .result import SampleEstimate, compact_repr, fields_json, joined
from .robot import Robot, value_error
from .sliding import Band, FrictionHistory, fallen, labels, turning_program
from .stability import (is_unstable, preload_stiffness_ratios, stiffness_ratio,
                        stiffness_ratios, tangent, unstable_note)
from .statics import Drive, Unknowns, shape_outputs, solve_system
from .tendons import turns


def estimate_series(prob: Problem, displacements: Sequence[Mapping[str, float]],
                    tensions: Sequence[Mapping[str, float]], noise: Noise = Noise(),
                    chunk: int = 100, progress=None,
                    values: Mapping[str, object] | None = None) -> list[SampleEstimate]:
    """Estimate a time series of readings, each sample warm-started from the previous one,
    every tendon pulled in (eq. 10 as written; :func:`tendonsense.logs.estimate_readings`
    follows each tendon's friction history); ``values`` ({name: (N,)}, as for
    :func:`solve_batch`) gives each sample its own E, ν, ρ or μ (e.g. a Monte Carlo over
    friction).

    The compiled tracker takes them in chunks of ``chunk`` samples (quasi-Newton for square
    problems, Gauss–Newton SQP for least squares); a sample it cannot converge is solved again
    on its own from the straight rod (load continuation, a bounded budget once an earlier
    sample has converged) and the scan goes on again after it, from that solution; a bad
    reading (:mod:`tendonsense.inputs`' rules: non-finite, a negative tension or one that
    would crush the rod, a tendon pulled in beyond its length) is marked with the reason. A
    square problem's 1-σ band is exact on the first sample of every
    :data:`~tendonsense.fastpath.EXACT_EVERY` and within a few per cent between (the
    quasi-Newton inverse). ``progress(done, total)`` is called per
    chunk (:func:`series_chunks` hands over each chunk's estimates as it finishes).

    ``displacements`` and ``tensions``: one ``{tendon: value}`` a sample, or ``{tendon: (N,)
    values}``. A converged sample where a tendon with friction has fallen from its highest
    tension more than the noise explains is noted (:func:`~tendonsense.sliding.fallen`): if it
    is released there, this series' law misreads it."""
    displacements = per_sample(displacements, "displacement")
    tensions = per_sample(tensions, "tension")
    out = _series(prob, displacements, tensions, noise, chunk, progress, values)
    T = np.array([[_number(t.get(name, 0.0)) for name in prob.robot.tendon_names]
                  for t in tensions], float).reshape(len(tensions), len(prob.robot.tendons))
    mu = varied_values(prob.model.values, values, len(out)).get("friction", np.broadcast_to(
        np.asarray(prob.model.values.friction, float), T.shape))
    falls = fallen(T, mu, prob.robot.tendon_names, noise.tension)
    return [replace(e, note=joined(e.note, falls[k])) if e.converged and falls[k] else e
            for k, e in enumerate(out)]


def _series(prob: Problem, displacements, tensions, noise: Noise, chunk: int, progress,
            values) -> list[SampleEstimate]:
    """:func:`estimate_series`' estimates, without its notes on fallen tensions (the runs of
    :func:`estimate_batch` are in no time order)."""
    n = len(displacements)
    out: list[SampleEstimate | None] = [None] * n
    for first, estimates in series_chunks(prob, displacements, tensions, noise, chunk, values):
        out[first:first + len(estimates)] = estimates
        if progress:
            progress(first + len(estimates), n)
    return out


def _number(v) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return np.nan


def series_chunks(prob: Problem, displacements: Sequence[Mapping[str, float]],
                  tensions: Sequence[Mapping[str, float]], noise: Noise = Noise(),
                  chunk: int = 100, values: Mapping[str, object] | None = None,
                  start: np.ndarray | None = None, history: FrictionHistory | None = None,
                  given: np.ndarray | None = None, persistent: bool = True,
                  stuck: np.ndarray | None = None):
    """:func:`estimate_series` as it goes: yields ``(first, estimates)`` for consecutive
    samples ``first, first + 1, …`` as each chunk is done. ``start``: the solution ``x`` of a
    reading near the first (e.g. the same row's earlier estimate) to warm-start from, instead
    of solving the first sample from the straight rod.

    ``history``: every tendon's friction follows it along the series (compiled
    :func:`~tendonsense.fastpath.follower`; it is left as it stands after the last sample) and
    each estimate carries its ``friction_state`` and each tendon's direction
    (:func:`~tendonsense.sliding.labels`, at the turning of its own shape);
    ``given`` (N, n_t) states the log sets (+1 in, −1 out), NaN where the history decides;
    ``stuck`` (N, n_t) where the log says a tendon is stuck.

    A sample the compiled scan fails is solved on its own (a rescue; with a history, each
    tendon's friction at its anchor's state at every turn: solved at the state of each turn,
    such a rescue did not converge on a slow rod's log); with ``persistent``
    False, only if the sample before it converged (a series that may have no solution over a
    stretch, e.g. a friction band's far end, is not solved row by row in vain).

    Where every sample of a chunk converged on the scan, the next chunk's scan is started
    (from its last solution and friction band) before the chunk is handed over, and runs while
    the caller takes it: ``history``, ``given`` and ``stuck`` are read at the start, not
    changed between chunks."""
    check_noise(noise, prob.robot)
    robot, model = prob.robot, prob.model
    n = len(displacements)
    if (prob.located or values) and history is not None:
        raise ValueError("a friction history is followed with the model's own values and "
                         "known points only")
    if history is not None and history.turns != turns(model.values):
        raise ValueError(f"a friction history of this robot has a state at each of its "
                         f"{turns(model.values)} turns (FrictionHistory(..., turns=...))")
    # each sample's tension bound with its own E
    varied = varied_values(model.values, values, n)
    T, Y, errors = prob.many_readings(displacements, tensions, varied.get("young_modulus"))
    if prob.located:  # sample by sample: X searched first, then followed (and after failures)
        if values:
            raise ValueError("values per sample are not available with located forces")
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
    out: list[SampleEstimate | None] = [None] * n
    for k, error in errors.items():
        out[k] = SampleEstimate.failed(prob, f"bad value: {error}")
    # every tendon's tension a column (a slack one's adds nothing to the band): one program
    # whichever tendons a log pulls
    tcols = tuple(range(len(robot.tendons)))
    if history is None:
        track = tracker(model.structure, prob.measured, prob.n_z, tcols, until_failure=True)
    else:
        follow = follower(model.structure, prob.measured, prob.n_z, tcols)
        given = np.full((n, len(robot.tendons)), np.nan) if given is None else given
        stuck = np.zeros((n, len(robot.tendons)), bool) if stuck is None else stuck
        mu = np.asarray(model.values.friction, float)
    meas = list(prob.measured)
    valid = [k for k in range(n) if out[k] is None]
    # the first sample from the straight rod on the scan itself (its exact Jacobian and line
    # search), the solver with load continuation only if that fails (a rescue)
    x0 = np.zeros(model.nq + prob.n_z) if start is None else start
    if start is None and valid and len(meas) > prob.n_z:
        # a least-squares fit's first sample as a single estimate (Levenberg–Marquardt from
        # the straight rod): where the readings leave the magnitudes poorly determined, the
        # scan's undamped first step would land elsewhere on their blind direction
        k = valid[0]
        first = estimate_problem(prob, displacements[k], tensions[k], noise,
                                 values=model.values._replace(
                                     **{name: a[k] for name, a in varied.items()}))
        x0 = np.asarray(first.extra["x"], float) if first.converged else x0

    def scan(run, x0, failing, before):  # dispatched, not awaited (JAX runs it meanwhile)
        # a fixed scan length (padded with the last sample, not solved) keeps one program
        rows = list(run) + [run[-1]] * (chunk - len(run))
        drives = stacked_drives(prob, T[rows], Y[rows][:, meas])
        if history is None:
            return rows, track(np.asarray(x0, float), drives, prob.unknowns, model.values,
                               {name: np.asarray(v[rows], float) for name, v in varied.items()},
                               len(run), failing)
        return rows, follow(np.asarray(x0, float), drives, prob.unknowns, model.values,
                            np.asarray(given[rows], float), before, len(run), failing)

    seen_good, last_failed, done = False, False, 0
    ahead = None  # the next chunk's scan, started where this one ends if it converges throughout
    for at in range(0, len(valid), chunk):
        idx = valid[at:at + chunk]
        pos = 0
        while pos < len(idx):
            run = idx[pos:]
            rows, got = ahead if ahead is not None and pos == 0 else scan(
                run, x0, last_failed, None if history is None else Band.of(history))
            ahead = None
            if history is None:
                tr = jax.device_get(got)
            else:
                tr, states, bands = jax.device_get(got)
            if pos == 0 and at + chunk < len(valid) and tr.converged[:len(run)].all():
                # each sample converged on the scan: the next chunk starts from the last (as
                # the loop below would start it), while this one's rows are made
                ahead = scan(valid[at + chunk:at + 2 * chunk], tr.x[len(run) - 1], False,
                             None if history is None else
                             Band(*(a[len(run) - 1] for a in bands)))
            sigma = band(tr.dx_dm[:, model.nq:, :], len(meas), T[rows][:, list(tcols)], noise)
            cov = covariance(tr.dx_dm[:, model.nq:, :], len(meas), T[rows][:, list(tcols)],
                             noise) if prob.n_magnitudes > 1 else None
            if history is not None:  # a tendon's state and direction are its anchor's
                states = states[:, :, -1]
                said = labels(states[:len(run)], mu, bands.phi[:len(run), :, -1], noise.tension,
                              stuck[run])
            over = prob.overloaded(tr.x[:len(run)], varied["young_modulus"][run]
                                   if "young_modulus" in varied else None)
            misfit = [""] * len(run) if len(meas) == prob.n_z else misfit_notes(
                tr.Jz[:len(run)], tr.JT[:len(run)],  # (a failed row's are not finite: none)
                tr.lengths[:len(run)][:, meas] - Y[run][:, meas], T[run][:, list(tcols)], noise)
            solved_x = None  # the last solution of the equations (the next scan starts there)
            for j, k in enumerate(run):
                friction = {} if history is None else dict(friction_state=states[j],
                                                           sliding=said[j])
                if tr.converged[j]:  # (a solution whose force the model cannot hold: not)
                    out[k] = SampleEstimate(
                        tr.x[j, model.nq:], sigma[j],
                        dict(zip(robot.marker_names, tr.markers[j])), not over[j],
                        int(tr.iterations[j]), tr.x[j], over[j] or joined(
                            misfit[j], "" if cov is None else confounded(cov[j],
                                                                          prob.n_magnitudes)),
                        **friction)
                elif not persistent and last_failed:
                    out[k] = replace(SampleEstimate.failed(
                        prob, "not estimated: the sample before did not converge either",
                        tr.x[j]), **friction)
                else:
                    v = model.values._replace(**{name: a[k] for name, a in varied.items()})
                    out[k] = replace(SampleEstimate.of(estimate_problem(
                        prob, displacements[k], tensions[k], noise,
                        values=v if history is None else v._replace(friction=states[j] * mu),
                        budget=RESCUE_BUDGET if seen_good else None)), **friction)
                    if history is not None and out[k].converged:  # labelled at its own turning
                        phi = np.asarray(turning_program(model.structure)(
                            out[k].x[None, :model.nq], model.values))[0]
                        out[k] = replace(out[k], sliding=labels(states[j], mu, phi,
                                                                noise.tension, stuck[k]))
                solved = out[k].converged or bool(tr.converged[j] and over[j])
                solved_x = out[k].x if solved else solved_x
                last_failed = not solved
                seen_good = seen_good or solved
                if j + 1 < len(run) and (tr.iterations[j + 1] == 0 or (
                        not tr.converged[j] and out[k].converged and not tr.converged[j + 1])):
                    break  # the scan stopped here, or failed on after a rescue: again after it
            if history is not None:  # as it stands after the last sample taken
                Band(*(a[j] for a in bands)).into(history)
            pos += j + 1
            x0 = x0 if solved_x is None else solved_x
        end = idx[-1] + 1 if at + chunk < len(valid) else n
        yield done, out[done:end]
        done = end
    if done < n:  # every sample bad
        yield done, out[done:]


def principal_order(m: np.ndarray) -> np.ndarray:
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
    """Estimate independent readings, returned in the input order (as
    :func:`estimate_series`'s: one ``{tendon: value}`` a sample, or ``{tendon: (N,)
    values}``), each with every tendon pulled in; ``values`` gives each its own E, ν, ρ or μ
    ({name: (N,)}, as for :func:`solve_batch`).

    The readings are ordered along their first principal direction so that neighbours
    warm-start each other, cut into ``workers`` runs, and the runs are solved concurrently
    (one thread each; the compiled tracker releases the GIL, so each takes a core).
    """
    check_noise(noise, prob.robot)
    from concurrent.futures import ThreadPoolExecutor
    robot = prob.robot
    displacements = per_sample(displacements, "displacement")
    tensions = per_sample(tensions, "tension")
    n = len(displacements)
    varied = varied_values(prob.model.values, values, n)
    m = np.array([np.concatenate([tendon_vector(robot, y, "displacement"),
                                  tendon_vector(robot, t, "tension")])
                  for y, t in zip(displacements, tensions)]).reshape(n, -1)
    m = np.concatenate([m, *(v.reshape(n, -1) for v in varied.values())], axis=1)
    runs = [r for r in np.array_split(principal_order(m), max(1, workers)) if r.size]
    done = [0] * len(runs)

    def solve_run(i):
        def tick(d, _):
            done[i] = d
            if progress:
                progress(sum(done), n)
        return _series(prob, [displacements[k] for k in runs[i]],
                       [tensions[k] for k in runs[i]], noise, 100, tick,
                       {name: v[runs[i]] for name, v in varied.items()})

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
    notes: np.ndarray  # (N,) str: why a sample is no solution, or is at an unstable equilibrium
    #: (N,) bool: at an unstable equilibrium (its note says so; checked with ``stability``)
    unstable: np.ndarray | None = None

    __repr__ = compact_repr
    to_json = fields_json


def solve_batch(robot: Robot, tensions, point_forces: Sequence = (),
                values: Mapping[str, object] | None = None, chunk: int = 100,
                workers: int = 2, sliding: Mapping[str, str] | None = None,
                stability: bool = False, settle: bool = False) -> BatchResult:
    """Forward statics over a batch of tensions, point loads and values, for sweeps and Monte
    Carlo: one compiled program per robot structure, whatever the numbers.

    ``tensions``: (N, n_t) array (tendons in file order), {tendon: (N,) array}, or one
    {tendon: value} a sample (as :func:`estimate_batch` takes readings); tendons not named
    are slack.
    ``point_forces``: [(X, f), ...] where X may be (N,) and f (N, 3). ``values``: {name: (N,)}
    for ``young_modulus``, ``poisson_ratio``, ``density``, ``friction`` ((N,) one μ for every
    tendon, or (N, n_t)), each under the robot file's rules (``ValueError`` naming the value
    otherwise). ``sliding`` ({tendon: 'in' | 'out'}, default in) as for
    :func:`~tendonsense.forward.solve`, in every sample. The samples are ordered along their
    first principal direction and
    solved by the compiled tracker, each warm-started from its neighbour, on ``workers``
    threads; a sample it cannot converge is solved again on its own from the straight rod
    with load continuation.

    ``stability``: each converged sample's equilibrium is checked as
    :func:`~tendonsense.forward.solve` checks its own (an exact Jacobian and an eigenvalue
    problem a sample, about as long again as its solve); one the tracker reached at an
    unstable equilibrium is solved again on its own from the straight rod, as ``solve``
    (warm-started from a neighbour, the tracker may reach another equilibrium), and that
    solution kept where it converges. ``unstable`` marks the shapes the rod would leave for
    another, and their notes say so (:func:`~tendonsense.stability.unstable`).

    ``settle`` (with ``stability``): such a sample, or one not solved, is instead the stable
    state the rod comes to rest in from it, as ``solve(..., settle=True)`` gives (its note
    says so; ~0.01–0.5 s a sample); it warm-starts no other.

    >>> E = np.linspace(0.8e6, 1.2e6, 1000)
    >>> out = solve_batch(robot, {"t1": np.full(1000, 2.0)}, values={"young_modulus": E})
    >>> out.markers["tip"].shape, bool(out.converged.all())
    ((1000, 3), True)
    """
    from concurrent.futures import ThreadPoolExecutor
    model = model_for(robot)
    structure, base = model.structure, model.values
    T, X, F, varied = batch_inputs(robot, base, tensions, point_forces, values)
    n, n_t = T.shape
    if n == 0:
        raise ValueError("batch: no samples")
    if settle and not stability:
        raise ValueError("batch: settle needs the stability check (stability=True)")
    varied = signed_friction(robot, base, varied, n, sliding)
    g = np.broadcast_to(np.asarray(robot.gravity, float), (n, 3))
    unknowns = Unknowns.none(n_t, X.shape[1])
    track = tracker(structure, (), 0, tuple(range(n_t)))  # (as series_chunks)
    features = np.concatenate([T, X, F.reshape(n, -1), *(v.reshape(n, -1)
                                                          for v in varied.values())], axis=1)
    runs = [r for r in np.array_split(principal_order(features), max(1, workers)) if r.size]
    q, mk = np.zeros((n, structure.nq)), np.zeros((n, len(robot.markers), 3))
    y, conv, its = np.zeros((n, n_t)), np.zeros(n, bool), np.zeros(n, int)
    notes, ratio, rested = np.full(n, "", object), np.full(n, np.nan), np.zeros(n, bool)

    def drive(rows):
        return Drive(T[rows], F[rows], X[rows], g[rows], np.zeros((len(rows), 0)))

    def params(rows):
        return {k: np.asarray(v[rows]) for k, v in varied.items()}

    def ratio_args(rows, count):  # the chunk's first ``count`` rows, where converged
        return (structure, base, params(rows), drive(rows), unknowns,
                np.where(conv[rows, None], q[rows], 0.0), conv[rows] & (np.arange(chunk) < count))

    def one(k):  # sample k's values and drive
        return (base._replace(**{name: np.asarray(a[k]) for name, a in varied.items()}),
                jax.tree_util.tree_map(lambda a: a[0], drive([k])))

    stopped = {}  # where the solver of a sample that failed stopped (settled from there)

    def alone(k):  # sample k solved on its own from the straight rod, as :func:`solve`
        v, d = one(k)
        res = solve_system(structure, v, (), d, unknowns)
        markers, _, lengths, fine = shape_outputs(structure, v, res.x)
        return v, res, markers, lengths, bool(res.converged) and bool(fine), bool(fine)

    def solve_run(run):
        x0 = np.zeros(structure.nq)
        for start in range(0, run.size, chunk):
            idx = run[start:start + chunk]
            rows = np.concatenate([idx, np.full(chunk - idx.size, idx[-1])])
            tr = jax.device_get(track(x0, drive(rows), unknowns, base,
                                      params(rows)))
            for j, k in enumerate(idx):
                if tr.converged[j]:
                    q[k], mk[k], y[k], conv[k], its[k] = (tr.x[j], tr.markers[j], tr.lengths[j],
                                                          True, tr.iterations[j])
                    continue
                _, res, mk[k], y[k], conv[k], fine = alone(k)
                q[k], its[k], stopped[k] = np.asarray(res.x), int(res.evaluations), res.stopped
                if not conv[k]:
                    notes[k] = why_not(res, fine, robot.numerics.tolerance)
            if stability:
                ratio[idx] = stiffness_ratios(*ratio_args(rows, idx.size))[:idx.size]
                # warm-started from its neighbour, the tracker may reach another equilibrium
                # than a solve from the straight rod: where it is unstable, the sample is
                # solved on its own, and that solution kept where it converges
                for j in np.flatnonzero(tr.converged[:idx.size] & is_unstable(ratio[idx])):
                    k = idx[j]
                    v, res, markers, lengths, ok, _ = alone(k)
                    if ok:
                        q[k], mk[k], y[k], its[k] = np.asarray(res.x), markers, lengths, (
                            its[k] + int(res.evaluations))
                        ratio[k] = stiffness_ratio(v, tangent(v, res, structure.nq))
            for k in idx[(~conv[idx] | is_unstable(ratio[idx])) if settle else []]:
                came = settled(model, *one(k), unknowns, stopped.get(k, q[k]), its[k],
                               ratio[k])
                q[k], conv[k], its[k], ratio[k] = came.q, came.converged, came.iterations, np.nan
                mk[k] = [came.markers[m] for m in robot.marker_names]
                y[k] = [came.displacements[t] for t in robot.tendon_names]
                notes[k], rested[k] = came.note, True
            good = np.flatnonzero(conv[idx] & ~rested[idx])  # a settled state starts no other
            if good.size:
                x0 = q[idx[good[-1]]]

    if stability:
        preload_stiffness_ratios(*ratio_args(np.zeros(chunk, int), 0))
    with ThreadPoolExecutor(len(runs)) as pool:
        list(pool.map(solve_run, runs))
    shaky = None
    if stability:
        shaky = conv & is_unstable(ratio)
        notes[shaky] = [unstable_note(r) for r in ratio[shaky]]
    return BatchResult(q, {m: mk[:, i] for i, m in enumerate(robot.marker_names)},
                       {t: y[:, j] for j, t in enumerate(robot.tendon_names)}, conv, its,
                       notes, shaky)


def batch_inputs(robot: Robot, base, tensions, point_forces, values):
    """Validated batch arrays: T (N, n_t), X (N, n_p), F (N, n_p, 3) and the varied values."""
    names = robot.tendon_names
    if isinstance(tensions, Sequence) and tensions and all(
            isinstance(t, Mapping) for t in tensions):  # one {tendon: value} a sample
        for k, t in enumerate(tensions):
            try:
                tendon_vector(robot, t, "tension")  # (the names, finite)
            except ValueError as exc:
                raise ValueError(f"batch: sample {k + 1}: {exc}") from None
        tensions = {name: [t.get(name, 0.0) for t in tensions] for name in names}
    if isinstance(tensions, Mapping):
        cols = {k: np.atleast_1d(np.asarray(v, float)) for k, v in tensions.items()}
        for k, c in cols.items():
            if k not in names:
                raise ValueError(f"tension {k}: no such tendon (robot has {', '.join(names)})")
            if c.ndim > 1:
                raise ValueError(f"batch: tension {k}: one value or (N,) values (one a "
                                 f"sample), not an array of shape {c.shape}")
        n = max((c.size for c in cols.values()), default=1)
        if odd := [f"{k} ({c.size})" for k, c in cols.items() if c.size not in (1, n)]:
            raise ValueError(f"batch: every tendon's tensions are one value or {n} (one a "
                             f"sample), got {', '.join(odd)}")
        T = np.stack([np.broadcast_to(cols.get(k, np.zeros(1)), (n,)) for k in names], axis=1)
    else:
        try:
            T = np.asarray(tensions, float)
        except (TypeError, ValueError):
            T = np.zeros(np.shape(tensions) if np.ndim(tensions) < 2 else (0,))
        if T.ndim == 1 and (len(names) == 1 or T.size == 0):  # one column, or none at all
            T = T.reshape(-1, len(names))
        if T.ndim != 2 or T.shape[1] != len(names):
            raise ValueError(f"batch: tensions as an array are (N, {len(names)}), a column per "
                             f"tendon ({', '.join(names)}), not of shape {T.shape} (or give "
                             f"{{tendon: (N,) values}}, or one {{tendon: value}} a sample)")
    n = T.shape[0]
    point_forces = force_pairs(point_forces)
    X = np.stack([np.broadcast_to(np.asarray(x, float), (n,)) for x, _ in point_forces], axis=1) \
        if point_forces else np.zeros((n, 0))
    F = np.stack([np.broadcast_to(np.asarray(f, float), (n, 3)) for _, f in point_forces],
                 axis=1) if point_forces else np.zeros((n, 0, 3))
    for what, a in (("tension", T), ("point force", X), ("point force", F)):
        if not np.all(np.isfinite(a)):
            k, j = np.argwhere(~np.isfinite(a))[0][:2]
            name = names[j] if what == "tension" else str(j + 1)
            raise ValueError(f"batch: sample {k + 1}: {what} {name}: not a finite number "
                             f"({a[k, j]})")
    varied = varied_values(base, values, n)
    E = np.broadcast_to(varied.get("young_modulus", robot.rod.young_modulus), (n,))
    for j, name in enumerate(names):  # each sample's tensions by the rule, with its own E
        bad = (T[:, j] < 0) | (T[:, j] > max_tension(robot, name, E))
        if bad.any():
            k = int(np.argmax(bad))
            raise ValueError(f"batch: sample {k + 1}: "
                             f"{tension_error(robot, name, float(T[k, j]), float(E[k]))}")
    if np.any(off := (X < 0) | (X > robot.rod.length)):
        k, j = np.argwhere(off)[0]
        raise ValueError(f"batch: sample {k + 1}: point force {j + 1}: "
                         f"{outside_rod('X', float(X[k, j]), robot.rod.length)}")
    for j in range(X.shape[1]):  # each sample's loads by the rule, with its own E
        if bad := first_force_error(robot, f"point force {j + 1}", X[:, j], F[:, j], E):
            raise ValueError(f"batch: sample {bad[0] + 1}: {bad[1]}")
    return T, X, F, varied


def signed_friction(robot: Robot, base, varied: dict, n: int, sliding) -> dict:
    """``varied`` with every sample's μ signed by its tendon's ``sliding`` direction, in or
    out (:func:`~tendonsense.forward.sliding_values`; a stuck one is a ValueError)."""
    if not sliding:
        return varied
    sliding_values(robot, base, sliding)  # its rules
    mu = varied.get("friction", np.broadcast_to(np.asarray(base.friction, float),
                                                (n, len(robot.tendons))))
    return {**varied, "friction": mu * friction_signs(robot, sliding)}


def varied_values(base, values, n: int) -> dict[str, np.ndarray]:
    """Per-sample values {name: (n, ...)}, validated: a name of :data:`VALUE_NAMES`, finite;
    ``friction`` (n,) is one μ for every tendon, (n, n_t) one per tendon."""
    varied = {}
    for k, val in (values or {}).items():
        if k not in VALUE_NAMES:
            raise ValueError(f"{k}: not a value that can be varied (one of "
                             f"{', '.join(VALUE_NAMES)}; each tendon's own μ: friction as "
                             f"(N, n_tendons), a column per tendon in the robot's order)")
        a = np.asarray(val, float)
        if k == "friction" and a.ndim <= 1:  # one μ for every tendon
            a = a.reshape(-1, 1)
        try:
            varied[k] = np.broadcast_to(a, (n, *np.shape(getattr(base, k))))
        except ValueError:
            raise ValueError(f"batch: {k} has shape {np.shape(val)}, not one value per "
                             f"sample ({n})" + (f" nor (N, n_tendons) = ({n}, "
                                                f"{np.size(base.friction)}), one μ per tendon"
                                                if k == "friction" else "")) from None
        if not np.all(np.isfinite(varied[k])):
            raise ValueError(f"batch: {k} must be finite")
        for v in np.unique(varied[k]):
            if why := value_error(k, float(v)):
                i = int(np.argmax((varied[k] == v).reshape(n, -1).any(axis=1)))
                raise ValueError(f"batch: sample {i + 1}: {k}: {why}")
    return varied
