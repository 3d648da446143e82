"""Live estimation: readings arrive one at a time and each is answered within a bounded amount
of work, warm-started from the last good sample (eq. 17 on the fast path of
:mod:`tendonsense.fastpath`)."""

from __future__ import annotations

import itertools
from dataclasses import replace
from time import perf_counter as _clock
from typing import Mapping

import jax
import numpy as np

from .estimation import estimate_problem
from .fastpath import live
from .filtering import MotionFilter
from .forward import INADMISSIBLE
from .inputs import WALK, Noise, check_noise, check_stuck, sliding as check_sliding
from .problem import Problem, confounded, misfit_note, unseen
from .result import SampleEstimate, joined
from .sliding import DIRECTION, GIVEN, band_note, band_range, labels, turning_program
from .statics import solve_system
from .tendons import turns

#: evaluations of the solve from the straight rod that a sample the fast path could not
#: converge gets once an earlier sample has converged (the first gets the full budget)
RESCUE_BUDGET = 12


class OnlineEstimator:
    """Estimate shape and load magnitudes sample by sample, e.g. inside a data-acquisition
    loop::

        online = OnlineEstimator(problem(robot, ["t1"], [PointForceUnknown(0.25, (0, 0, -1))]))
        for y, T in readings:
            est = online.update({"t1": y}, {"t1": T})
            est.magnitudes, est.sigma, est.converged, est.note

    Every call ends within a work budget: at most ``MAX_EVALUATIONS`` residual evaluations
    and ``MAX_JACOBIANS`` exact Jacobians of the warm-started quasi-Newton step
    (:mod:`tendonsense.fastpath`), then, if that fails and time is left of ``time_limit``
    (s), one solve from the straight rod with as many evaluations as fit in the time left (or
    a fixed ``rescue_budget`` of evaluations, for results that must not depend on the clock).
    The first sample, with no earlier state to start from, may take a full solve with load
    continuation.
    A bad reading (:mod:`tendonsense.inputs`' rules: non-finite, a negative tension or one
    that would crush the rod, a tendon pulled in by more than its length) is answered at
    once, not converged, with the reason in ``note``; a sample that fails leaves the state as
    it was, so the next one starts from the last good sample.
    Overdetermined problems (more measured tendons than unknowns) take Gauss–Newton SQP
    steps on the same fast path; their rescue is the least-squares solver of
    :mod:`tendonsense.estimation` with the same evaluation budget per equilibrium solve.
    A force of unknown location is searched over its range on the first sample, then followed
    sample to sample; a sample that loses it (no convergence, or X outside its range) gets a
    new search when the time left allows one, or after five failures in a row.

    Friction follows each tendon's history (the play operator of :mod:`tendonsense.sliding`,
    at the turning angles of the sample's own estimated shape, as a file log's; forces at
    known points): a tendon whose tension falls sticks, then is paid out; a stuck sample also
    gets the range of its magnitudes over the friction band (``magnitude_range``), each end
    followed from its last estimate like the sample itself, all in one compiled call
    (:class:`~tendonsense.fastpath.Live`). Each estimate carries every tendon's
    ``friction_state`` and direction (``sliding``). ``update(..., sliding={"t1": "out"})``
    overrides it.

    With ``dynamic=True`` each sample needs its ``time`` (s) and is estimated with the damped
    model (:class:`~tendonsense.filtering.MotionFilter`, ``walk`` its unknowns' random walk per
    √s; ``inertia``: the mass of the modes that ring, or none): right
    while the robot moves, at a fixed amount of work per sample after the first (a static
    estimate, taken at rest); friction follows the history there too, without the range of a
    stuck sample.
    """

    def __init__(self, prob: Problem, noise: Noise = Noise(), time_limit: float = 0.02,
                 rescue_budget: int | None = None, dynamic: bool = False, walk: float = WALK,
                 inertia: bool = True):
        self.problem, self.noise, self.time_limit = prob, check_noise(noise, prob.robot), time_limit
        self.rescue_budget = rescue_budget
        self._filter = MotionFilter(prob, noise, walk, inertia) if dynamic else None
        model = prob.model
        n_t = model.n_tendons
        self._square = len(prob.measured) == prob.n_z
        self._follows = bool(np.any(np.asarray(model.values.friction) > 0)) and not (
            dynamic or prob.located)
        self._live = live(model.structure, prob.measured, prob.n_z, tuple(range(n_t)),
                          self._follows, turns(model.values))
        # on the device once: a numpy leaf would be copied in at every call
        self._values, self._unknowns = jax.device_put((model.values, prob.unknowns))
        self._state = None  # the carry, the friction history and the band's ends (Live)
        self._x = None  # last good [q; z]
        self._eval_cost = None  # s per evaluation with a Jacobian, measured
        self._search_cost = None  # s per search over X, measured
        self._failures = 0  # samples failed in a row
        self._refer(prob)
        self._pulled_in = np.ones(n_t)  # without a history, every tendon pulled in
        self._unstuck = np.zeros(n_t)

    def _refer(self, prob: Problem):
        """Located forces: refer the solution to the problem ``prob`` at the estimated X."""
        d = prob.drive(np.zeros(prob.model.n_tendons), np.zeros(len(prob.measured)))
        self._ref, self._loads = prob, jax.device_put((d.forces, d.load_X, d.gravity))

    def prepare(self):
        """Build (or load from the disk cache) every program a sample may need, with a
        reading of slack tendons at their rest lengths, then forget it: the first real
        reading is answered at full speed."""
        names = self.problem.robot.tendon_names
        if self._filter is not None:
            self._filter.prepare()
        self.update({names[j]: 0.0 for j in self.problem.measured}, dict.fromkeys(names, 0.0),
                    0.0)
        self.reset()

    def reset(self):
        """Forget the last good sample: the next one starts from the straight rod (with
        ``dynamic``: at rest)."""
        self._state, self._x, self._failures = None, None, 0
        self._refer(self.problem)
        if self._filter is not None:
            self._filter.reset()

    def update(self, displacements: Mapping[str, float], tensions: Mapping[str, float],
               time: float | None = None, sliding: Mapping[str, str] | None = None
               ) -> SampleEstimate:
        """Estimate one sample of readings: tendon length changes (m) and tensions (N) by
        tendon name, taken at ``time`` (s; needed with ``dynamic``); ``sliding`` {tendon:
        in|out|stuck} where the direction is known."""
        if self._filter is not None:
            return self._filter.update(displacements, tensions, time, sliding)
        start = _clock()
        prob = self.problem
        given, stuck = self._pulled_in, self._unstuck
        try:
            T, y = prob.readings(displacements, tensions)
            said = check_sliding(prob.robot, sliding, default="").values() if sliding else ()
            check_stuck(prob.robot, sliding, tensions, bool(prob.located))
            if self._follows:  # the history decides (NaN) where the reading does not say
                given = np.array([GIVEN[d] for d in said]) if said else np.full(T.size, np.nan)
                if said:
                    stuck = np.array([d == "stuck" for d in said], float)
        except ValueError as exc:
            return self._failed(f"bad value: {exc}")
        return self._sample(start, T, y[list(prob.measured)], displacements, tensions,
                            (given, stuck))

    def _sample(self, start, T, targets, displacements, tensions, said) -> SampleEstimate:
        """One sample on the fast path, rescued if it fails (``said``: the states the reading
        sets and where it says a tendon is stuck)."""
        prob = self.problem
        if prob.located and self._x is None:  # no X yet: search its whole range
            return self._after_rescue(T, targets, displacements, tensions, None, 0,
                                      "no estimate of the location", None, said)
        if self._x is None and len(prob.measured) > prob.n_z:
            # a least-squares fit's first sample as a single estimate (as a file log's: the
            # fast path's undamped first step may land elsewhere on a poorly determined
            # combination of the magnitudes)
            return self._after_rescue(T, targets, displacements, tensions, None, 0,
                                      "did not converge", None, said)
        if self._state is None:
            x0 = np.zeros(prob.model.nq + prob.n_z)
            self._state = self._live.start(x0, self._reading(T, targets, said), self._loads,
                                           self._unknowns, self._values)
            if self._eval_cost is None:
                self._eval_cost = self._time_evaluation(self._ref.drive(T, targets),
                                                        displacements, tensions, self._values)
        est, row = self._solve(T, targets, said, (displacements, tensions))
        if est is not None:
            return est
        iterations = row.iterations
        note = (INADMISSIBLE if not row.admissible else self._outside(row.x) if row.converged
                else "did not converge within the work budget")
        self._failures += 1
        left = self.time_limit - (_clock() - start)
        if prob.located:
            # a search over X when it fits in the time left, or after five failures in a row
            if (self.rescue_budget is None and self._search_cost is not None
                    and left < self._search_cost and self._failures < 5):
                return self._failed(note, row)
            return self._after_rescue(T, targets, displacements, tensions, self.rescue_budget,
                                      iterations, note, row, said)
        # evaluations that fit in the time left, less three for the step that follows a rescue
        budget = (None if self._x is None else self.rescue_budget if self.rescue_budget
                  else int(left / max(self._eval_cost, 1e-6)) - 3)
        if budget is not None and budget < 3:
            return self._failed(note, row)
        return self._after_rescue(T, targets, displacements, tensions, budget, iterations,
                                  note, row, said)

    def _reading(self, T, targets, said, restart=None) -> np.ndarray:
        return self._live.reading(T, targets, *said, self.noise, restart)

    def _after_rescue(self, T, targets, displacements, tensions, budget, iterations, note,
                      row, said):
        """A rescue solve (friction signed by the failed sample's state, if any), then the
        sample again from its solution in one call (which also gives the sensitivities and
        the band's ends): the estimate, or a failed sample."""
        prob = self.problem
        values = self._signed(None if row is None else row.state[:, -1])  # a start only
        t0 = _clock()
        drive = self._ref.drive(T, targets)
        x, converged, evaluations = self._rescue(drive, displacements, tensions, budget,
                                                 values)
        if prob.located:
            self._search_cost = _clock() - t0
        if not converged:  # before any sample converged (no time limit yet): an unseen load?
            why = "" if prob.located or self._x is not None else unseen(prob, x, drive,
                                                                          values)[1]
            return self._failed(why or note, row)
        drive = self._ref.drive(T, targets)  # (located: at the X found)
        restart = x
        if self._state is None:  # a state whose carry is at x already
            self._state = self._live.start(x, self._reading(T, targets, said), self._loads,
                                           self._unknowns, self._values)
            restart = None
        if self._eval_cost is None and not prob.located:  # (located: timed by its search)
            self._eval_cost = self._time_evaluation(drive, displacements, tensions, values)
        est, row2 = self._solve(T, targets, said, (displacements, tensions), restart,
                                iterations + evaluations)
        if est is None and not prob.located:
            # the rescue's solution, where the follower fails the reading from it too (as a
            # file log keeps it): the state and the history as they were
            est = self._rescued(x, values, None if row is None else row.state[:, -1],
                                displacements, tensions, said[1], iterations + evaluations)
        if est is None:
            return self._failed(INADMISSIBLE if not row2.admissible else note, row2)
        return est

    def _rescued(self, x, values, state, displacements, tensions, stuck, iterations):
        """The estimate at a rescue's solution ``x`` (solved with ``values``: its friction
        signed by the failed sample's ``state`` at each tendon's anchor, None: pulled in)
        with its 1-σ band, each tendon labelled at its turning there; None if it is none. A
        stuck tendon's range is not searched (the note says so)."""
        prob = self.problem
        r = estimate_problem(prob, displacements, tensions, self.noise, x, values)
        if not r.converged:
            return None
        est = replace(SampleEstimate.of(r), iterations=iterations + int(r.iterations))
        if not self._follows:
            return est
        mu = np.asarray(self._values.friction, float)
        state = np.ones(mu.shape) if state is None else np.asarray(state, float)
        phi = np.asarray(turning_program(prob.model.structure)(
            np.asarray(r.extra["x"])[None, :prob.model.nq], values))[0]
        said = labels(state, mu, phi, self.noise.tension, np.asarray(stuck) > 0)
        return replace(est, friction_state=state, sliding=said, note=joined(est.note, (
            "solved on its own: its range over the stuck tendon's friction band not "
            "searched") if "stuck" in said else ""))

    def _solve(self, T, targets, said, raw, restart=None, iterations=0):
        """The sample from the state's carry (or from ``restart``, a solution) in one
        compiled call (:class:`~tendonsense.fastpath.Live`): ``(estimate, row)``, the
        estimate None (and the state as it was) if it did not converge or left a located
        force's range (:class:`~tendonsense.fastpath.LiveRow`, its iterations counted from
        ``iterations``; ``raw``: the reading's displacements and tensions, for the band's
        ends solved on their own)."""
        prob = self.problem
        reading = self._reading(T, targets, said, restart)
        state, flat = self._live.sample(self._state, reading, self._loads, self._unknowns,
                                        self._values)
        row = self._live.unpack(np.asarray(flat), len(prob.robot.markers))
        row = row._replace(iterations=iterations + row.iterations)
        x = row.x
        if not row.converged or self._outside(x):
            return None, row
        self._state, self._x, self._failures = state, x, 0
        nq, n = prob.model.nq, prob.n_magnitudes
        over = self._ref.overloaded(x)[0]
        meas = list(prob.measured)
        misfit = "" if len(meas) == prob.n_z else misfit_note(
            row.Jz, row.JT, row.lengths[meas] - targets, T, self.noise)
        est = SampleEstimate(x[nq:nq + n], row.sigma[:n],
                             dict(zip(prob.robot.marker_names, row.markers)), not over,
                             row.iterations, x, over or joined(misfit, confounded(
                                 row.covariance, n)), self._ref.locations(x), row.sigma[n:])
        if not self._follows:
            return est, row
        est = replace(est, friction_state=row.state[:, -1],
                      sliding=tuple(map(DIRECTION.get, row.code.tolist())))
        stuck = np.flatnonzero(row.code == 0)
        if stuck.size:
            ends = self._ends_of(row.z[:2**stuck.size, :n], row.state, stuck, reading,
                                 self._ref.drive(T, targets), raw)
            est = replace(est, magnitude_range=band_range(est.magnitudes, ends),
                          note=joined(est.note, band_note(est.magnitudes, ends)))
        return est, row

    def _ends_of(self, z, state, stuck, reading, drive, raw) -> np.ndarray:
        """The magnitudes at the ends of the band (``z`` from the call, NaN where an end was
        not found), those not found solved from the straight rod with a fixed
        ``rescue_budget`` if there is one: an admissible solution is kept in the end's slot,
        for the next stuck sample to follow (eq. 10 with each stuck tendon's μφ at ±1)."""
        if not self.rescue_budget or not np.isnan(z).any():
            return z
        z = z.copy()
        for j, signs in enumerate(itertools.product((-1.0, 1.0), repeat=stuck.size)):
            if np.isnan(z[j]).any():
                s = state.copy()
                s[stuck] = np.asarray(signs)[:, None]
                x, ok, _ = self._rescue(drive, *raw, self.rescue_budget, self._signed(s))
                if ok and j < self._live.slots:
                    self._state, ok = self._live.put(self._state, x, reading, self._loads,
                                                     self._unknowns, self._values, j)
                if ok:
                    z[j] = x[self.problem.model.nq:][:z.shape[1]]
        return z

    def _signed(self, state):
        """The values with every tendon's friction signed by its ``state``, one a tendon
        (n_t,) or one at every turn (n_t, turns) (None: as they are)."""
        if state is None or np.all(state == 1.0):
            return self._values
        mu = np.asarray(self._values.friction)
        return self._values._replace(friction=state * (mu[:, None] if np.ndim(state) == 2
                                                       else mu))

    def _outside(self, x) -> str:
        """Why located forces at ``x`` are no estimate (an X outside its range), or ''."""
        if not self.problem.located:
            return ""
        X = self._ref.locations(x)
        for (_, (a, b)), x_ in zip(self.problem.located, X):
            if not a - 1e-9 <= x_ <= b + 1e-9:
                return f"location {x_:.4g} m left its range {a:g}:{b:g} m"
        return ""

    def _rescue(self, drive, displacements, tensions, budget, values):
        """A solve from the straight rod, with load continuation, within ``budget``
        evaluations: (x, converged, evaluations)."""
        prob = self.problem
        if self._square and not prob.located:
            res = solve_system(prob.model.structure, values, prob.measured, drive,
                               prob.unknowns, None, budget)
            return res.x, bool(res.converged), int(res.evaluations)
        r = estimate_problem(prob, displacements, tensions, self.noise, None,
                             jax.device_get(values), budget=budget, total_budget=budget)
        if prob.located and r.converged:  # its x is referred to the estimated X
            self._refer(prob.at([v for v in r.extra["locations"] if v is not None]))
        return r.extra["x"], r.converged, int(r.iterations)

    def _time_evaluation(self, drive, displacements, tensions, values) -> float:
        """Seconds per evaluation of the rescue (the unit of its budget: a residual with its
        Jacobian), timed on a rescue of a few evaluations after its program is loaded."""
        self._rescue(drive, displacements, tensions, 1, values)  # load its program
        best = []
        for _ in range(3):  # the least of three: the first runs may still warm up
            t0 = _clock()
            _, _, evaluations = self._rescue(drive, displacements, tensions, 4, values)
            best.append((_clock() - t0) / max(1, evaluations))
        return min(best)

    def _failed(self, note: str, row=None) -> SampleEstimate:
        if row is None:
            return SampleEstimate.failed(self.problem, note)
        return SampleEstimate.failed(self.problem, note, row.x, row.iterations)
