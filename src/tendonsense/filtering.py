"""Estimation of a rod in motion: an extended Kalman filter on the damped model (SPEC §5).

The quasi-static estimate (eq. 17) takes each sample at rest. A moving Kelvin–Voigt rod lags
its load, ``D q̇ = B(q) T + F(q, z) − K q`` (:mod:`tendonsense.dynamics` without inertia), and
the rest assumption then misreads the lag as a force. The filter's state is ``[q; z]`` (shape
and the unknown magnitudes) with a covariance ``P``; between two time stamps, h apart:

- **predict**: q by one linearly implicit Euler step of the damped model,
  ``D (q − q₋)/h = B(q) T + F(q, z) − K q`` linearised at q₋, z held; P carried through the
  step's linearisation, with the unknowns a random walk (``Q_z = w² h``) and the tensions
  read with noise (``σ_T = noise.tension · T``);
- **update**: with the measured length changes, ``y(q) = Δl + e``, ``σ_e = noise.length``
  (Joseph form).

Without damping (``D = 0``) the step is a Newton step towards the equilibrium and, at rest
with as many measured tendons as unknowns, the filter settles on the quasi-static estimate.
Inertia is taken where the rod rings, i.e. its first mode is underdamped
(:func:`~tendonsense.dynamics.first_mode`, ζ₁ < 1): a massless model reads the ringing after
every change of speed as a changing force. The state is then ``[q; q̇; z]`` and the step that
of ``M q̈ + D q̇ + E(q) = 0``, with ``M`` at the shape the filter starts from (the Coriolis
terms, quadratic in q̇, left out). The first sample is taken at rest: its quasi-static
estimate starts the filter.

Friction follows each tendon's history (:class:`~tendonsense.sliding.FrictionHistory`): the
state of a sample comes from its tension and the turning angles of the last estimated shape,
and signs the Capstan exponent of its step (one step a sample: no iteration on the state).
"""

from __future__ import annotations

from dataclasses import replace
from functools import lru_cache
from typing import Mapping, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .compiled import Program
from .dynamics import first_mode, mass_matrix
from .estimation import estimate_problem
from .inputs import WALK, Noise, sliding as check_sliding
from .kinematics import poses, positions
from .model import PointSet, Structure, Values, points_at
from .problem import Problem, _jacobians_fn
from .result import SampleEstimate
from .sliding import NOISE_REACH, FrictionHistory, labels
from .statics import CACHE_SIZE, Drive, Unknowns, admissible, terms
from .tendons import length_changes, turning

#: the time the robot is taken to have been at rest before the first sample, s
REST = 1e6

#: columns of the iteration Jacobian renewed per step
COLUMNS = 4

#: failed samples in a row after which the filter starts again from a quasi-static estimate
RESTART = 5

#: the friction history's margin in ln T, in units of the tension's read-out noise: a
#: tendon's friction turns only on a change of tension the noise cannot make
MARGIN = NOISE_REACH


class FilterState(NamedTuple):
    """Time of the last estimate, its ``x = [q; z]`` (with inertia ``[q; q̇; z]``) and
    covariance ``P``, the iteration Jacobians ``∂E/∂q`` and ``∂y/∂q`` (a few columns renewed
    per step, from ``column`` on) and, with inertia, the mass matrix ``M`` (made by the first
    step, ``column`` < 0, at the shape the filter starts from)."""

    t: jax.Array
    x: jax.Array
    P: jax.Array
    E_q: jax.Array
    y_q: jax.Array
    M: jax.Array
    column: jax.Array


class Tuning(NamedTuple):
    """The filter's noise model: the unknowns' random walk (per √s, in their own unit: N for
    a force), length noise (m), tension noise (relative)."""

    walk: jax.Array
    length: jax.Array
    tension: jax.Array


@lru_cache(maxsize=CACHE_SIZE)
def filter_step(structure: Structure, measured: tuple[int, ...], n_z: int,
                inertia: bool = False) -> Program:
    """The compiled ``step(state, t, drive, unknowns, values, tuning, markers) -> (state, row)``
    (``markers``: the markers' :class:`~tendonsense.model.PointSet`, made once): one
    predict and update at time t with the tensions and measured length changes of ``drive``;
    ``row`` is ``[q, z, σ_z, markers, φ, ok]`` packed in one vector (one transfer to the host;
    φ the tendons' turning angles at the estimate; ok (1 or 0): finite, later than the state
    and in the model's strain range). A sample that is not ok returns the state unchanged.

    The prediction is one linearly implicit Euler step (the implicit Euler equation
    linearised at the last estimate; no iteration, so that every sample's work is fixed).
    With ``inertia`` the state carries q̇ and the step is that of
    ``M(q₋) q̈ + D q̇ + E(q) = 0`` with ``M`` at the last estimate (the Coriolis terms,
    quadratic in q̇, left out)."""
    nq = structure.nq
    sel = np.array(measured, int)
    nv = nq if inertia else 0

    def step(state: FilterState, t, drive: Drive, unknowns: Unknowns, values: Values,
             tuning: Tuning, markers: PointSet):
        K = values.young_modulus * values.stiffness()
        D = values.damping_matrix()
        h = t - state.t
        q0, v0, z = state.x[:nq], state.x[nq:nq + nv], state.x[nq + nv:]

        def parts(q, z):  # (E, y) with E = K q − B T − F (eq. 7), and B = −∂E/∂T
            tm = terms(structure, values, q, z, drive, unknowns, 1.0, actuation=True)
            return (K @ q - tm.load, tm.y[sel]), tm.B

        # exact ∂E/∂z, and COLUMNS columns of ∂E/∂q, ∂y/∂q in turn (forward mode):
        # every step's work is the same, and the iteration matrix is never more than
        # nq/COLUMNS steps old (a W-method: first-order accurate with any iteration matrix,
        # L-stable with a close one)
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
        if inertia:  # M (v − v₀)/h + D v + E(q₀) + h E_q v = 0, q = q₀ + h v
            M = jax.lax.cond(state.column < 0, lambda: mass_matrix(structure, values, q0),
                             lambda: state.M)
            sol = jnp.linalg.solve(M / h + D + h * E_q, jnp.concatenate(
                [(M @ v0 / h - E)[:, None], -E_q, M / h, -E_z, B], 1))
            v, Phi = sol[:, 0], sol[:, 1:]  # ∂v/∂(q₀, v₀, z, T)
            x1 = jnp.concatenate([q0 + h * v, v])
            Phi_T = jnp.concatenate([h * Phi[:, -n_t:], Phi[:, -n_t:]])

            def ahead(P):  # F P, F = ∂(q, v, z)/∂(q₀, v₀, z₀) = [I 0 0; 0 0 0; 0 0 I] + [h; 1; 0] Φ
                WP = Phi[:, :n_s + n_z] @ P
                return jnp.concatenate([P[:nq] + h * WP, WP, P[n_s:]])
        else:  # D (q − q₀)/h + E(q₀) + E_q (q − q₀) = 0, and its linearisation in q₀, z, T
            M = state.M
            sol = jnp.linalg.solve(D / h + E_q,
                                   jnp.concatenate([E[:, None], D / h, -E_z, B], 1))
            x1, Phi = q0 - sol[:, 0], sol[:, 1:]  # ∂q/∂(q₀, z, T)
            Phi_T = Phi[:, -n_t:]

            def ahead(P):  # F P, F = ∂(q, z)/∂(q₀, z₀) = [Φ_q Φ_z; 0 I]
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
        x = jnp.concatenate([x1, z]) + gain @ (drive.targets - y)
        KHP = gain @ HP  # (I − KH) P (I − KH)ᵀ + K R Kᵀ, expanded: O(n² m)
        P = P - KHP - KHP.T + gain @ S @ gain.T
        P = 0.5 * (P + P.T)

        q, z = x[:nq], x[n_s:]
        _, mk = poses(values, q, markers)
        ok = (jnp.all(jnp.isfinite(x)) & jnp.all(jnp.isfinite(P)) & (h > 0)
              & admissible(values, q))
        new = FilterState(t, x, P, E_q, y_q, M, (jnp.maximum(state.column, 0) + k) % nq)
        new = jax.tree_util.tree_map(lambda a, b: jnp.where(ok, a, b), new, state)
        sigma = jnp.sqrt(jnp.maximum(jnp.diagonal(P)[n_s:], 0.0))
        return new, jnp.concatenate([q, z, sigma, jnp.ravel(positions(mk, values.marker_offsets)),
                                     turning(structure, values, q), ok[None]])

    return Program(step, "filter_step", (structure, measured, n_z, inertia))


class MotionFilter:
    """Estimate shape and load magnitudes of a moving rod sample by sample, from time-stamped
    readings::

        f = MotionFilter(problem(robot, ["t1"], [PointForceUnknown(0.25, (0, 0, -1))]))
        for t, y, T in readings:
            est = f.update({"t1": y}, {"t1": T}, t)

    ``walk`` is how fast the unknowns may change (a random walk, in their unit per √s): larger
    follows a changing force sooner, smaller averages the noise over longer. ``inertia``:
    whether the model has mass; by default where the rod rings (module docstring). The first
    sample (and the first after ``RESTART`` failures in a row) is taken at rest: its
    quasi-static estimate starts the filter. A bad reading, a time that does not follow the
    last, or a step that leaves the model's strain range is answered not converged with the
    reason in ``note`` and leaves the state as it was; ``RESTART`` of the last two in a row
    (e.g. a clock that was reset) start the filter again at rest. Friction follows each
    tendon's history (module docstring); ``update(..., sliding={"t1": "out"})`` sets it."""

    def __init__(self, prob: Problem, noise: Noise = Noise(), walk: float = WALK,
                 inertia: bool | None = None):
        if prob.located:
            raise ValueError("estimation in motion takes forces at known points (a location "
                             "range ('A:B' or '?') is estimated quasi-statically only)")
        if not (noise.length > 0 and np.isfinite(noise.length)):
            raise ValueError(f"estimation in motion needs a length noise > 0 m (the filter "
                             f"weighs the readings by it), got {noise.length!r}")
        if not (walk > 0 and np.isfinite(walk)):
            raise ValueError(f"force walk: must be a number > 0 (per √s), got {walk!r}")
        self.problem, self.noise, self.walk = prob, noise, walk
        model = prob.model
        if inertia is None:  # where the rod rings: a massless model reads the ringing as force
            rod = prob.robot.rod
            inertia = (rod.damping > 0 and rod.density > 0
                       and first_mode(model.structure, model.values)[1] < 1.0)
        self.inertia = inertia
        self._step = filter_step(model.structure, prob.measured, prob.n_z, inertia)
        self._values, self._unknowns = jax.device_put((model.values, prob.unknowns))
        self._markers = jax.device_put(points_at(model.structure, model.values,
                                                 model.values.marker_X))
        self._tuning = Tuning(*(np.float64(v) for v in (walk, noise.length, noise.tension)))
        history = FrictionHistory(model.values.friction, MARGIN * noise.tension)
        self._history = history if history.active else None
        self._start = self._tuning._replace(walk=np.float64(0.0))
        self._call = None  # the step's executable, once loaded
        self.reset()

    def prepare(self):
        """Build (or load from the disk cache) the step's program now."""
        prob = self.problem
        n = prob.model.nq + prob.n_z
        drive = prob.drive(np.zeros(prob.model.n_tendons), np.zeros(len(prob.measured)))
        state = self._at_rest(0.0, np.zeros(n), np.eye(n), drive)
        self._call = self._step.executable(state, np.float64(1.0), drive, self._unknowns,
                                           self._values, self._tuning, self._markers)

    def reset(self):
        """Forget the state: the next sample starts the filter again, at rest."""
        self._state, self._t, self._failures = None, -np.inf, 0
        if self._history is not None:
            self._history = FrictionHistory(self._history.mu, self._history.margin)

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
                given = {names.index(n): d for n, d in sliding.items()}
        except ValueError as exc:
            return self._failed(f"bad value: {exc}")
        try:
            time = float(time)
        except (TypeError, ValueError):
            time = None
        if time is None or not np.isfinite(time):
            return self._failed("time: estimation in motion needs a finite time stamp (s)")
        drive = prob.drive(T, y[list(prob.measured)])
        state, tuning, values = self._state, self._tuning, self._values
        history = None if self._history is None else self._history.copy()
        friction = None
        if history is not None and not history.pulled(T, given):
            friction = history.step(T, None, given)  # at the last shape's turning angles
            values = values._replace(friction=friction * history.mu)  # copied in with the call
        if state is None:
            start = estimate_problem(prob, displacements, tensions, self.noise,
                                     values=values)
            if not start.converged:
                return self._failed("the first sample's quasi-static estimate did not converge",
                                    start.extra["x"], start.iterations)
            n = prob.n_z
            z = start.extra["x"][prob.model.nq:]
            P = np.zeros((len(z) + prob.model.nq,) * 2)
            P[-n:, -n:] = np.diag((10 * start.sigma + 1e-3 * np.abs(z) + 1e-12) ** 2)
            state, tuning = self._at_rest(time - REST, start.extra["x"], P, drive), self._start
        elif not time > self._t:
            return self._lost(f"time {time:g} s does not follow the last estimate's "
                              f"{self._t:g} s")
        args = (state, np.float64(time), drive, self._unknowns, values, tuning,
                self._markers)
        if self._call is None:
            self._call = self._step.executable(*args)
        new, row = self._call(*args)
        n_x, n_m = prob.model.nq + prob.n_z, len(prob.robot.markers)
        x, sigma, markers, phi, ok = np.split(np.asarray(row), np.cumsum(
            [n_x, prob.n_z, 3 * n_m, prob.model.n_tendons]))
        markers, ok = markers.reshape(n_m, 3), bool(ok[0])
        if not ok:
            return self._lost("the step left the model's strain range or did not stay finite")
        self._state, self._t, self._failures = new, float(time), 0
        n = prob.n_magnitudes
        est = SampleEstimate(x[prob.model.nq:][:n], sigma[:n],
                             dict(zip(prob.robot.marker_names, markers)), True, 1, x)
        if history is None:
            return est
        history.phi = phi  # the next sample's state turns at this shape
        self._history = history
        if friction is None:
            return est
        return replace(est, friction_state=friction, sliding=labels(
            friction, history.mu, phi, self.noise.tension,
            [given.get(k) == "stuck" for k in range(len(friction))]))

    def _at_rest(self, t, x, P, drive) -> FilterState:
        """A state at rest at ``x = [q; z]`` with covariance ``P`` (of q and z) and the exact
        Jacobians there (with inertia: q̇ = 0 and known, the mass matrix made by the first
        step)."""
        prob = self.problem
        model = prob.model
        nq = model.nq
        E_q, _, _, y_q = _jacobians_fn(model.structure, prob.measured)(
            x[:nq], x[nq:], drive.tensions, drive, self._unknowns, self._values)
        x, M, column = np.asarray(x, float), np.zeros(0), 0
        if self.inertia:
            x = np.insert(x, nq, np.zeros(nq))
            P = np.insert(np.insert(P, [nq] * nq, 0.0, axis=0), [nq] * nq, 0.0, axis=1)
            M, column = np.zeros((nq, nq)), -1
        return FilterState(np.float64(t), x, P, np.asarray(E_q), np.asarray(y_q), M,
                           np.int64(column))

    def _lost(self, note: str) -> SampleEstimate:
        """A failed sample after the filter has started: RESTART of them in a row start it
        again at rest."""
        self._failures += 1
        if self._failures >= RESTART:
            self.reset()
        return self._failed(note)

    def _failed(self, note: str, x=None, iterations: int = 0) -> SampleEstimate:
        return SampleEstimate.failed(self.problem, note, x, iterations)
