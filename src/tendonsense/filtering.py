"""Estimation of a rod in motion: an extended Kalman filter on the damped model.

The quasi-static estimate (eq. 17) takes each sample at rest. A moving Kelvin–Voigt rod lags
its load, ``D q̇ = B(q) T + F(q, z) − K q`` (:mod:`tendonsense.dynamics` without inertia), and
the rest assumption then misreads the lag as a force. The filter's state is ``[q; z]`` (shape
and the unknown magnitudes) with a covariance ``P``; between two time stamps, h apart:

- **predict**: q by one linearly implicit Euler step of the damped model,
  ``D (q − q₋)/h = B(q) T + F(q, z) − K q`` linearised at q₋, z held; P carried through the
  step's linearisation, with the unknowns a random walk (``Q_z = w² h``) and the tensions
  read with noise (``σ_T = noise.tension · T``);
- **update**: with the measured length changes, ``y(q) = Δl + e``, ``σ_e = noise.length``
  (Joseph form). The innovation ν (measured less predicted lengths, covariance S) tests the
  sample: where ``νᵀ S⁻¹ ν`` is beyond the χ² quantile the sensor noise gives
  (:data:`~tendonsense.problem.MISFIT_QUANTILE`), its note says the readings disagree beyond
  their noise, as a least-squares estimate's does at rest.

Without damping (``D = 0``) the step is a Newton step towards the equilibrium and, at rest
with as many measured tendons as unknowns, the filter settles on the quasi-static estimate.
Inertia is taken in the modes that ring, i.e. are underdamped
(:func:`~tendonsense.dynamics.free_modes`, ζ < 1): a massless model reads their ringing after
every change of speed as a changing force. Their modal velocities w join the state and the
step is that of ``M Ψ Ψᵀ M q̈ + D q̇ + E(q) = 0``, Ψ those modes and ``M`` the mass matrix at
the shape the filter starts from (the Coriolis terms, quadratic in q̇, left out); the
overdamped modes keep the massless model. The first sample is taken at rest: its quasi-static
estimate starts the filter.

Friction follows each tendon's history (:class:`~tendonsense.sliding.FrictionHistory`): the
state of a sample comes from its tension and the turning angles of the last estimated shape,
and signs the Capstan exponent of its step (one step a sample: no iteration on the state).
The history follows the mean tension of the readings of the last :data:`HISTORY_WINDOW`
at the mean turning of their shapes, so that a faster log's read-out noise moves it no more
than a 100 Hz log's.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Mapping, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .compiled import Program
from .dynamics import free_modes
from .estimation import estimate_problem
from .inputs import (WALK, Noise, check_noise, check_stuck, sliding as check_sliding,
                     warn_no_damping)
from .kinematics import poses, positions
from .model import PointSet, Structure, Values, host, points_at
from .problem import (MISFIT, MISFIT_QUANTILE, Problem, _jacobians_fn, confounded,
                      misfit_part)
from .result import SampleEstimate, joined
from .sliding import NOISE_REACH, FrictionHistory, labels
from .statics import CACHE_SIZE, Drive, Unknowns, admissible, terms
from .tendons import depths, length_changes, turns

#: the time the robot is taken to have been at rest before the first sample, s
REST = 1e6

#: columns of the iteration Jacobian renewed per step
COLUMNS = 4

#: failed samples in a row after which the filter starts again from a quasi-static estimate
RESTART = 5

#: the friction history's margin in ln T, in units of the tension's read-out noise: a
#: tendon's friction turns only on a change of tension the noise cannot make
MARGIN = NOISE_REACH

#: s: the friction history follows the mean tension of the readings this recent at the mean
#: turning of their shapes (at 100 Hz the reading alone; at 1 kHz, one reading a time, the
#: noise of a pulled tendon's readings took its first turns to paid out: the force 3 σ off;
#: the window's lag of 5 ms leaves a noise-free 1 kHz log 1.7 % of the weight off at rest
#: after a release, against 0.02 % without it)
HISTORY_WINDOW = 0.01


class FilterState(NamedTuple):
    """Time of the last estimate, its ``x = [q; z]`` (with ringing modes ``[q; w; z]``, w
    their modal velocities) and covariance ``P``, the iteration Jacobians ``∂E/∂q`` and
    ``∂y/∂q`` (a few columns renewed per step, from ``column`` on) and ``M Ψ``, the mass
    matrix times the ringing modes Ψ at the shape the filter started from."""

    t: jax.Array
    x: jax.Array
    P: jax.Array
    E_q: jax.Array
    y_q: jax.Array
    MP: jax.Array
    column: jax.Array


class Tuning(NamedTuple):
    """The filter's noise model: the unknowns' random walk (per √s, in their own unit: N for
    a force), length noise (m), tension noise (relative)."""

    walk: jax.Array
    length: jax.Array
    tension: jax.Array


@lru_cache(maxsize=CACHE_SIZE)
def filter_step(structure: Structure, measured: tuple[int, ...], n_z: int,
                ringing: int = 0) -> Program:
    """The compiled ``step(state, t, drive, unknowns, values, tuning, markers) -> (state, row)``
    (``markers``: the markers' :class:`~tendonsense.model.PointSet`, made once): one
    predict and update at time t with the tensions and measured length changes of ``drive``;
    ``row`` is ``[q, z, σ_z, markers, ψ, ν, ν·S⁻¹ν, ok]`` packed in one vector (one transfer
    to the host; ψ the tendons' turning to each turn at the estimate,
    :func:`~tendonsense.tendons.depths`; ν the innovation, measured less predicted lengths,
    and ν·S⁻¹ν its χ²(n_meas) statistic; ok (1 or 0): finite, later than the state and in the
    model's strain range). A sample that is not ok returns the state unchanged.

    The prediction is one linearly implicit Euler step (the implicit Euler equation
    linearised at the last estimate; no iteration, so that every sample's work is fixed).
    With ``ringing`` modes Ψ (M-normalised, ``M Ψ`` in the state) the mass matrix is
    ``M Ψ Ψᵀ M``: inertia in those modes alone, ``w = Ψᵀ M q̇`` in the state, and the step is
    that of ``M Ψ ẇ + D q̇ + E(q) = 0`` (the Coriolis terms, quadratic in q̇, left out)."""
    nq = structure.nq
    sel = np.array(measured, int)
    nv = ringing

    def step(state: FilterState, t, drive: Drive, unknowns: Unknowns, values: Values,
             tuning: Tuning, markers: PointSet):
        K = values.young_modulus * values.stiffness()
        D = values.damping_matrix()
        h = t - state.t
        q0, w0, z = state.x[:nq], state.x[nq:nq + nv], state.x[nq + nv:]
        MP = state.MP

        def parts(q, z):  # (E, y) with E = K q − B T − F (eq. 7), and B = −∂E/∂T
            tm = terms(structure, values, q, z, drive, unknowns, 1.0, actuation=True)
            return (K @ q - tm.load, tm.y[sel]), tm.B

        # exact ∂E/∂z, and COLUMNS columns of ∂E/∂q, ∂y/∂q in turn (forward mode): every
        # step's work is the same, and the iteration matrix is never more than nq/COLUMNS
        # steps old (a W-method: first-order accurate with any iteration matrix, L-stable
        # with a close one)
        k = min(COLUMNS, nq)
        cols = (state.column + jnp.arange(k)) % nq
        Vq = jnp.concatenate([jnp.eye(nq)[cols], jnp.zeros((n_z, nq))])
        Vz = jnp.concatenate([jnp.zeros((k, n_z)), jnp.eye(n_z)])
        (E, _), (dE, dy), B = jax.vmap(
            lambda vq, vz: jax.jvp(parts, (q0, z), (vq, vz), has_aux=True),
            out_axes=(None, 0, None))(Vq, Vz)
        E_q = state.E_q.at[:, cols].set(dE[:k].T)
        y_q = state.y_q.at[:, cols].set(dy[:k].T)
        E_z = dE[k:].T
        n_t, n_s = B.shape[1], nq + nv
        if ringing:  # MΨ (w − w₀)/h + C v + E(q₀) = 0, w = (MΨ)ᵀ v, C = D + h E_q, q = q₀ + h v
            Y = jnp.linalg.solve(D + h * E_q, jnp.concatenate([E[:, None], MP, E_q, E_z, B], 1))
            Y_E, Y_M, U = Y[:, 0], Y[:, 1:1 + nv], Y[:, 1 + nv:]
            Sw = jnp.linalg.inv(h * jnp.eye(nv) + MP.T @ Y_M)
            w = Sw @ (MP.T @ Y_M @ w0 - h * MP.T @ Y_E)
            v = -Y_E + Y_M @ Sw @ (w0 + MP.T @ Y_E)
            x1 = jnp.concatenate([q0 + h * v, w])
            # ∂(q, w)/∂(q₀, w₀, z, T): C⁻¹ ∂E/∂· = U (no w₀ column), I_w the w₀ columns
            U = jnp.concatenate([U[:, :nq], jnp.zeros((nq, nv)), U[:, nq:nq + n_z],
                                 -U[:, nq + n_z:]], 1)
            I_w = jnp.eye(nv, n_s + n_z + n_t, nq)
            Phi = jnp.concatenate([jnp.eye(nq, n_s + n_z + n_t)
                                   + h * (Y_M @ Sw @ (MP.T @ U + I_w) - U),
                                   Sw @ (MP.T @ Y_M @ I_w - h * MP.T @ U)])
        else:  # D (q − q₀)/h + E(q₀) + E_q (q − q₀) = 0, and its linearisation in q₀, z, T
            sol = jnp.linalg.solve(D / h + E_q,
                                   jnp.concatenate([E[:, None], D / h, -E_z, B], 1))
            x1, Phi = q0 - sol[:, 0], sol[:, 1:]  # ∂q/∂(q₀, z, T)
        Phi_T = Phi[:, -n_t:]

        def ahead(P):  # F P, F = ∂(q, w, z)/∂(q₀, w₀, z₀) = [Φ_s Φ_z; 0 I]
            return jnp.concatenate([Phi[:, :n_s + n_z] @ P, P[n_s:]])

        G = ahead(jnp.eye(n_s + n_z)[:, n_s:])  # the unknowns' walk enters as a change of z
        GT = jnp.concatenate([Phi_T, jnp.zeros((n_z, n_t))])
        sT = tuning.tension * jnp.abs(drive.tensions)
        P = (ahead(ahead(state.P).T) + (tuning.walk**2 * h) * (G @ G.T)
             + (GT * sT**2) @ GT.T)

        # update with the measured length changes (Joseph form)
        q = x1[:nq]
        grid, = poses(values, q)
        y = length_changes(structure, values, grid, q)[sel]
        HP = y_q @ P[:nq]  # H = [∂y/∂q, 0]
        S = HP[:, :nq] @ y_q.T + tuning.length**2 * jnp.eye(sel.size)
        gain = jnp.linalg.solve(S, HP).T
        innovation = drive.targets - y
        nis = innovation @ jnp.linalg.solve(S, innovation)  # χ²(n_meas) if consistent
        x = jnp.concatenate([x1, z]) + gain @ innovation
        KHP = gain @ HP  # (I − KH) P (I − KH)ᵀ + K R Kᵀ, expanded: O(n² m)
        P = P - KHP - KHP.T + gain @ S @ gain.T
        P = 0.5 * (P + P.T)

        q, z = x[:nq], x[n_s:]
        _, mk = poses(values, q, markers)
        ok = (jnp.all(jnp.isfinite(x)) & jnp.all(jnp.isfinite(P)) & (h > 0)
              & admissible(values, q))
        new = FilterState(t, x, P, E_q, y_q, MP, (state.column + k) % nq)
        new = jax.tree_util.tree_map(lambda a, b: jnp.where(ok, a, b), new, state)
        sigma = jnp.sqrt(jnp.maximum(jnp.diagonal(P)[n_s:], 0.0))
        return new, jnp.concatenate([q, z, sigma, jnp.ravel(positions(mk, values.marker_offsets)),
                                     jnp.ravel(depths(structure, values, q)), innovation,
                                     nis[None], ok[None]])

    return Program(step, "filter_step", (structure, measured, n_z, ringing))


class MotionFilter:
    """Estimate shape and load magnitudes of a moving rod sample by sample, from time-stamped
    readings::

        f = MotionFilter(problem(robot, ["t1"], [PointForceUnknown(0.25, (0, 0, -1))]))
        for t, y, T in readings:
            est = f.update({"t1": y}, {"t1": T}, t)

    ``walk`` is how fast the unknowns may change (a random walk, in their unit per √s): larger
    follows a changing force sooner, smaller averages the noise over longer. ``inertia``:
    the mass of the modes that ring (module docstring; ``ringing`` counts them), or none. The first
    sample (and the first after ``RESTART`` failures in a row) is taken at rest: its
    quasi-static estimate starts the filter. A bad reading, a time that does not follow the
    last, or a step that leaves the model's strain range is answered not converged with the
    reason in ``note`` and leaves the state as it was; ``RESTART`` of the last two in a row
    (e.g. a clock that was reset) start the filter again at rest. Friction follows each
    tendon's history (module docstring); ``update(..., sliding={"t1": "out"})`` sets it."""

    def __init__(self, prob: Problem, noise: Noise = Noise(), walk: float = WALK,
                 inertia: bool = True):
        if prob.located:
            raise ValueError("estimation in motion takes forces at known points (a location "
                             "range ('A:B' or '?') is estimated quasi-statically only)")
        check_noise(noise, prob.robot)
        if not (walk > 0 and np.isfinite(walk)):
            raise ValueError(f"force walk: must be a number > 0 (per √s), got {walk!r}")
        self.problem, self.noise, self.walk = prob, noise, walk
        model = prob.model
        rod = prob.robot.rod
        warn_no_damping(prob.robot, stacklevel=3)
        self.ringing = 0  # the modes that ring (ζ < 1) carry the rod's inertia
        if inertia and rod.damping > 0 and rod.density > 0:
            self.ringing = int(np.sum(free_modes(model.structure, model.values)[1] < 1.0))
        self._step = filter_step(model.structure, prob.measured, prob.n_z, self.ringing)
        history = FrictionHistory(model.values.friction, MARGIN * noise.tension,
                                  turns(model.values))
        self._history = history if history.active else None
        values = model.values
        if self._history is not None:  # friction per turn, at every sample (one program)
            values = values._replace(friction=np.outer(values.friction, np.ones(history.turns)))
        self._values, self._unknowns = jax.device_put((values, prob.unknowns))
        self._markers = jax.device_put(points_at(model.structure, host(model.values),
                                                 model.values.marker_X, np))
        tuning = Tuning(*(np.float64(v) for v in (walk, noise.length, noise.tension)))
        # on the device once: a sample copies in its time, tensions, targets and friction only
        self._tuning, self._start, self._drive = jax.device_put((
            tuning, tuning._replace(walk=np.float64(0.0)),
            prob.drive(np.zeros(model.n_tendons), np.zeros(len(prob.measured)))))
        # where the parts of the step's row [q, z, σ_z, markers, ψ, ν, NIS, ok] start
        self._row = np.cumsum([0, model.nq, prob.n_z, prob.n_z, 3 * len(prob.robot.markers),
                               model.n_tendons * turns(model.values), len(prob.measured), 1,
                               1]).tolist()
        # a sample whose normalised innovation is beyond this is more than the noise explains
        from scipy.special import chdtri  # (here: SciPy's import is not every run's)
        self._nis_limit = float(chdtri(len(prob.measured), 1 - MISFIT_QUANTILE))
        self.reset()

    def prepare(self):
        """Build (or load from the disk cache) the step's program now."""
        prob = self.problem
        n = prob.model.nq + prob.n_z
        state = self._at_rest(0.0, np.zeros(n), np.eye(n), self._drive)
        self._step.executable(state, np.float64(1.0), self._drive, self._unknowns,
                              self._values, self._tuning, self._markers)

    def reset(self):
        """Forget the state: the next sample starts the filter again, at rest."""
        self._state, self._t, self._failures = None, -np.inf, 0
        self._recent: list[tuple] = []  # (time, tensions, turning) of the window's readings
        if self._history is not None:
            self._history = FrictionHistory(self._history.mu, self._history.margin,
                                            self._history.turns)

    def update(self, displacements: Mapping[str, float], tensions: Mapping[str, float],
               time: float | None, sliding: Mapping[str, str] | None = None
               ) -> SampleEstimate:
        """Estimate one sample: length changes (m) and tensions (N) by tendon name at
        ``time`` (s); ``sliding`` {tendon: in|out|stuck} where the direction is known."""
        prob = self.problem
        try:
            T, y = prob.readings(displacements, tensions)
            names = prob.robot.tendon_names
            given = {}
            if sliding:
                check_sliding(prob.robot, sliding)
                check_stuck(prob.robot, sliding, tensions)
                given = {names.index(n): d for n, d in sliding.items()}
        except ValueError as exc:
            return self._failed(f"bad value: {exc}")
        try:
            time = float(time)
        except (TypeError, ValueError):
            time = None
        if time is None or not np.isfinite(time):
            return self._failed("time: estimation in motion needs a finite time stamp (s)")
        drive = self._drive._replace(tensions=T, targets=y[list(prob.measured)])
        state, tuning, values = self._state, self._tuning, self._values
        history = None if self._history is None else self._history.copy()
        friction, first = None, ""
        recent = [r for r in self._recent  # (a time before the last: refused below)
                  if time - HISTORY_WINDOW * (1 - 1e-6) < r[0] < time]
        window = np.array([T] + [r[1] for r in recent], float)
        live = window > 0  # (a slack reading is not in its tendon's mean)
        mean = np.where(T > 0, np.sum(np.where(live, window, 0.0), axis=0)
                        / np.maximum(live.sum(axis=0), 1), 0.0)
        if history is not None and not history.pulled(mean, given):
            friction = history.step(mean, None, given)  # at the last shape's turning angles
            values = values._replace(friction=friction * history.mu[:, None])  # copied in
        if state is None:  # (friction at each tendon's anchor's state, as a single reading)
            start = estimate_problem(prob, displacements, tensions, self.noise, values=(
                values if history is None else values._replace(
                    friction=np.asarray(values.friction)[:, -1])))
            if not start.converged:
                return self._failed(joined("the first sample's quasi-static estimate did not "
                                           "converge", start.note),
                                    start.extra["x"], start.iterations)
            n = prob.n_z
            z = start.extra["x"][prob.model.nq:]
            P = np.zeros((len(z) + prob.model.nq,) * 2)
            P[-n:, -n:] = np.diag((10 * start.sigma + 1e-3 * np.abs(z) + 1e-12) ** 2)
            state, tuning = self._at_rest(time - REST, start.extra["x"], P, drive), self._start
            # (its innovation is against its own static fit: the fit's misfit test is its test)
            first = misfit_part(start.note)
        elif not time > self._t:
            return self._lost(f"time {time:g} s does not follow the last estimate's "
                              f"{self._t:g} s")
        args = (state, np.float64(time), drive, self._unknowns, values, tuning,
                self._markers)
        new, row = self._step(*args)
        row = np.asarray(row)
        _, z, sigma, markers, phi, innovation, nis, ok = (
            row[a:b] for a, b in zip(self._row, self._row[1:]))
        if not ok[0]:
            return self._lost("the step left the model's strain range or did not stay finite")
        self._state, self._t, self._failures = new, float(time), 0
        if history is not None:  # the next sample's turns: the window's shapes', as its tension
            window = recent + [(float(time), T, phi.reshape(history.phi.shape))]
            history.phi = np.mean([r[2] for r in window], axis=0)
            self._recent = window
            self._history = history
        n = prob.n_magnitudes
        more = {} if friction is None else dict(  # a tendon's state and direction: its anchor's
            friction_state=friction[:, -1], sliding=labels(
                friction[:, -1], history.mu, history.phi[:, -1], self.noise.tension,
                [given.get(k) == "stuck" for k in range(len(friction))]))
        over = prob.overloaded(row[:self._row[2]])[0]  # a force the model cannot hold
        return SampleEstimate(z[:n], sigma[:n], dict(zip(prob.robot.marker_names,
                                                         markers.reshape(-1, 3))),
                              not over, 1, row[:self._row[2]], joined(
                                  # (the covariance fetched only where there is a pair to
                                  # compare)
                                  over or confounded(np.asarray(new.P)[-prob.n_z:, -prob.n_z:], n)
                                  if n > 1 or over else "",
                                  first or self._misfit(innovation, nis[0])),
                              **more)

    def _misfit(self, innovation, nis: float) -> str:
        """A note where the measured lengths differ from the step's prediction by more than
        the noise explains (the normalised innovation squared above its χ² quantile), or ''."""
        if not nis > self._nis_limit:
            return ""
        return (f"{MISFIT}: the measured lengths differ from the filter's prediction by "
                f"{np.sqrt(np.mean(innovation**2)) * 1e3:.3g} mm RMS, "
                f"{np.sqrt(nis / innovation.size):.2g} times what the noise and the filter's "
                f"uncertainty explain (is a tendon swapped or mislabelled, its sliding "
                f"direction wrong, a load not given, or the robot not at rest at the first "
                f"sample?)")

    def _at_rest(self, t, x, P, drive) -> FilterState:
        """A state at rest at ``x = [q; z]`` with covariance ``P`` (of q and z) and the exact
        Jacobians there; the ringing modes those of this shape, their velocities 0 and
        known."""
        prob = self.problem
        model = prob.model
        nq, r = model.nq, self.ringing
        E_q, _, _, y_q = _jacobians_fn(model.structure, prob.measured)(
            x[:nq], x[nq:], drive.tensions, drive, self._unknowns, self._values)
        x, MP = np.asarray(x, float), np.zeros((nq, r))
        if r:  # the r least damped modes here (ζ grows with ω only where D ∝ K)
            _, zeta, modes, M = free_modes(model.structure, model.values, x[:nq])
            MP = M @ modes[:, np.argsort(zeta, kind="stable")[:r]]
            x = np.insert(x, nq, np.zeros(r))
            P = np.insert(np.insert(P, [nq] * r, 0.0, axis=0), [nq] * r, 0.0, axis=1)
        return FilterState(np.float64(t), x, P, np.asarray(E_q), np.asarray(y_q), MP,
                           np.int64(0))

    def _lost(self, note: str) -> SampleEstimate:
        """A failed sample after the filter has started: RESTART of them in a row start it
        again at rest."""
        self._failures += 1
        if self._failures >= RESTART:
            self.reset()
        return self._failed(note)

    def _failed(self, note: str, x=None, iterations: int = 0) -> SampleEstimate:
        return SampleEstimate.failed(self.problem, note, x, iterations)
