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
from .fastpath import Track, stepper, unpack_row
from .filtering import MotionFilter
from .forward import INADMISSIBLE
from .inputs import WALK, Noise, check_noise, sliding as check_sliding
from .problem import Problem, band
from .result import SampleEstimate
from .sliding import FIXED_POINT, STATE_TOL, FrictionHistory, band_range, labels
from .statics import solve_system

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

    Friction follows each tendon's history (:class:`~tendonsense.sliding.FrictionHistory`,
    the turning angles of the sample's own estimated shape; forces at known points): a
    tendon whose tension falls sticks, then is paid out; a stuck sample also gets the range of
    its magnitudes over the friction band (``magnitude_range``), each end followed from its
    last estimate like the sample itself. ``update(..., sliding={"t1": "out"})`` overrides it.

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
        self._square = len(prob.measured) == prob.n_z
        self._tcols = tuple(range(model.n_tendons))
        self._init, self._step = stepper(model.structure, prob.measured, prob.n_z, self._tcols)
        # on the device once: a numpy leaf would be copied in at every call
        self._values, self._unknowns = jax.device_put((model.values, prob.unknowns))
        self._carry = None
        self._x = None  # last good [q; z]
        self._phi = None  # the turning angles of its shape (n_t,)
        self._eval_cost = None  # s per evaluation with a Jacobian, measured
        self._ref = prob  # located forces: the problem at the last estimated X
        self._search_cost = None  # s per search over X, measured
        self._failures = 0  # samples failed in a row
        history = FrictionHistory(model.values.friction)
        self._history = history if history.active and not dynamic and not prob.located else None
        self._corners = {}  # the ends of a stuck tendon's band: signs -> carry

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
        self._carry, self._x, self._phi = None, None, None
        self._ref, self._failures = self.problem, 0
        self._corners = {}
        if self._history is not None:
            self._history = FrictionHistory(self._history.mu)
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
        try:
            T, y = prob.readings(displacements, tensions)
            names = prob.robot.tendon_names
            given = {}
            if sliding:
                check_sliding(prob.robot, sliding)
                given = {names.index(n): d for n, d in sliding.items()}
        except ValueError as exc:
            return self._failed(f"bad value: {exc}")
        if self._history is None:
            return self._sample(start, T, y, displacements, tensions, self._values)
        before = self._history.copy()
        if self._history.pulled(T, given):  # pulled in: the band does not matter
            est = self._sample(start, T, y, displacements, tensions, self._values)
            if not est.converged:  # a failed sample leaves the history as it was
                self._history = before
            return est
        if self._x is not None:  # the turning of the last shape
            self._history.phi = before.phi = self._phi
        state = self._history.step(T, None, given)
        for _ in range(FIXED_POINT):  # the state at the sample's own shape
            est = self._sample(start, T, y, displacements, tensions, self._signed(state))
            if not est.converged:  # a failed sample leaves the history as it was
                self._history = before
                return est
            h = before.copy()
            new = h.step(T, self._phi, given)  # at the turning of its own shape
            self._history = h
            if np.max(np.abs(new - state)) <= STATE_TOL:
                break
            state = new
        directions = labels(state, self._history.mu, self._history.phi, self.noise.tension,
                            [given.get(k) == "stuck" for k in range(len(names))])
        stuck = [k for k, d in enumerate(directions) if d == "stuck"]
        est = replace(est, friction_state=state, sliding=directions)
        if not stuck:
            self._corners = {}
            return est
        return replace(est, magnitude_range=self._band_range(est, state, stuck, T, y))

    def _signed(self, state):
        """The values with every tendon's friction signed by its state."""
        if np.all(state == 1.0):
            return self._values
        # a NumPy leaf: copied in by the call itself (jax.device_put costs ~0.15 ms)
        return self._values._replace(friction=state * self._history.mu)

    def _band_range(self, est, state, stuck, T, y) -> np.ndarray:
        """(n, 2) the range of the magnitudes over the stuck tendons' band: each end followed
        from its own last estimate (the first time from the sample's estimate, or a solve from
        the straight rod with a fixed ``rescue_budget``); open on the side of an end not
        found (:func:`~tendonsense.sliding.band_range`)."""
        prob = self.problem
        drive = self._ref.drive(T, y[list(prob.measured)])
        found = []
        for signs in itertools.product((-1.0, 1.0), repeat=len(stuck)):
            s = state.copy()
            s[stuck] = signs
            values = self._signed(s)
            carry = self._corners.get(signs)
            if carry is None and self.rescue_budget:
                x, ok, _ = self._rescue(drive, None, None, self.rescue_budget, values)
                carry = self._init(x, drive, {}, self._unknowns, values) if ok else None
            if carry is None:  # from the sample's own estimate, within the step's budget
                carry = self._carry
            carry, row = self._step(carry, drive, {}, self._unknowns, values)
            row, _ = self._unpack(row)
            if row.converged:
                self._corners[signs] = carry
                found.append(row.x[prob.model.nq:prob.model.nq + prob.n_magnitudes])
            else:
                self._corners.pop(signs, None)
                found.append(np.full(prob.n_magnitudes, np.nan))
        return band_range(est.magnitudes, found)

    def _sample(self, start, T, y, displacements, tensions, values) -> SampleEstimate:
        """One sample on the fast path with ``values``, rescued if it fails."""
        prob = self.problem
        targets = y[list(prob.measured)]
        drive = self._ref.drive(T, targets)
        model = prob.model
        unknowns = self._unknowns
        if prob.located and self._x is None:  # no X yet: search its whole range
            return self._after_rescue(T, targets, displacements, tensions, None, 0,
                                      "no estimate of the location", None, values)
        if self._carry is None:
            x0 = np.zeros(model.nq + prob.n_z)
            self._carry = self._init(x0, drive, {}, unknowns, values)
            if self._eval_cost is None:
                self._eval_cost = self._time_evaluation(drive, displacements, tensions, values)
        carry, row = self._step(self._carry, drive, {}, unknowns, values)
        row, phi = self._unpack(row)
        outside = self._outside(row.x)
        if row.converged and not outside:
            self._carry, self._x, self._phi, self._failures = carry, row.x, phi, 0
            return self._estimate(row, T, int(row.iterations))
        note = (INADMISSIBLE if not row.admissible else outside if row.converged
                else "did not converge within the work budget")
        self._failures += 1
        left = self.time_limit - (_clock() - start)
        if prob.located:
            # a search over X when it fits in the time left, or after five failures in a row
            if (self.rescue_budget is None and self._search_cost is not None
                    and left < self._search_cost and self._failures < 5):
                return self._failed(note, row)
            return self._after_rescue(T, targets, displacements, tensions, self.rescue_budget,
                                      int(row.iterations), note, row, values)
        # evaluations that fit in the time left, less three for the step that follows a rescue
        budget = (None if self._x is None else self.rescue_budget if self.rescue_budget
                  else int(left / max(self._eval_cost, 1e-6)) - 3)
        if budget is not None and budget < 3:
            return self._failed(note, row)
        return self._after_rescue(T, targets, displacements, tensions, budget,
                                  int(row.iterations), note, row, values)

    def _after_rescue(self, T, targets, displacements, tensions, budget, iterations, note,
                      row, values):
        """A rescue solve, then one step of the fast path from it (which also gives the
        sensitivities): the estimate, or a failed sample."""
        prob = self.problem
        unknowns = self._unknowns
        t0 = _clock()
        x, converged, evaluations = self._rescue(
            self._ref.drive(T, targets), displacements, tensions, budget, values)
        if prob.located:
            self._search_cost = _clock() - t0
        if not converged:
            return self._failed(note, row)
        drive = self._ref.drive(T, targets)
        carry = self._init(x, drive, {}, unknowns, values)
        if self._eval_cost is None and not prob.located:  # (located: timed by its search)
            self._eval_cost = self._time_evaluation(drive, displacements, tensions, values)
        carry, row2 = self._step(carry, drive, {}, unknowns, values)
        row2, phi = self._unpack(row2)
        if not row2.converged or self._outside(row2.x):
            return self._failed(INADMISSIBLE if not row2.admissible else note, row2)
        self._carry, self._x, self._phi, self._failures = carry, row2.x, phi, 0
        return self._estimate(row2, T, iterations + evaluations + int(row2.iterations))

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
            self._ref = prob.at([v for v in r.extra["locations"] if v is not None])
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

    def _unpack(self, flat) -> tuple[Track, np.ndarray]:
        prob = self.problem
        return unpack_row(np.asarray(flat), prob.model.nq + prob.n_z,
                          len(prob.measured) + len(self._tcols), len(prob.robot.markers),
                          prob.model.n_tendons)

    def _estimate(self, row, T, iterations) -> SampleEstimate:
        prob, noise = self.problem, self.noise
        nq = prob.model.nq
        sigma = band(row.dx_dm[nq:, :], len(prob.measured), T[list(self._tcols)], noise)
        n = prob.n_magnitudes
        return SampleEstimate(row.x[nq:nq + n], sigma[:n],
                              dict(zip(prob.robot.marker_names, row.markers)), True, iterations,
                              row.x, "", self._ref.locations(row.x), sigma[n:])

    def _failed(self, note: str, row=None) -> SampleEstimate:
        if row is None:
            return SampleEstimate.failed(self.problem, note)
        return SampleEstimate.failed(self.problem, note, row.x, int(row.iterations))
