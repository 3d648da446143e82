"""Rod dynamics ``M(q) q̈ + C(q, q̇) q̇ + D q̇ + K q = B(q) T + F(q)`` in GVS form, and
its time integration.

The inertial force ``M(q) q̈ + C(q, q̇) q̇ = ∫ Jᵀ (M_ρ η̇ − ad_ηᵀ M_ρ η) dX`` with the screw
inertia density ``M_ρ = ρ diag(Jx, Jy, Jz, A, A, A)`` (two-point Gauss per grid interval) plus
the lumped masses, pulled back like every other load; ``D`` is the Kelvin–Voigt
damping matrix (:meth:`~tendonsense.model.Values.damping_matrix`); the tendons' and the loads'
generalized force is the statics' (eq. 7, 8b, 14).

Integration: TR-BDF2 (a trapezoidal stage to ``t + γh``, a BDF2 stage to ``t + h``,
``γ = 2 − √2``): second order, L-stable, so that the stiff, heavily damped axial and shear modes
of a slender rod decay instead of ringing; both stages share one iteration matrix shape and are
solved by Newton's method (the exact Jacobian, with inertia less the inertial force's
derivatives at fixed q̈) and an Armijo line search. A step whose
Newton iteration fails is retried in halves. Without inertia (the quasi-static limit with
damping) the state is q alone: ``D q̇ = B T + F − K q``.

Friction direction: each tendon is pulled in, paid out, or follows its tension history (the
play operator of :mod:`tendonsense.sliding`, carried in the state): within a step its state
follows the tension at the turning angles of the step's start, and takes the new shape's
angles once the step is accepted.
"""

from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .compiled import Program
from .kinematics import configuration, poses, positions
from .lie import ad_apply, skew
from .model import Structure, Values, points_at
from .rod import section
from .sliding import Band, play
from .statics import CACHE_SIZE, Drive, Unknowns, admissible, scaling, terms
from .tendons import depths, length_changes, turns

_Z = np.sqrt(3.0) / 6.0
GAMMA = 2.0 - np.sqrt(2.0)
_KAPPA = GAMMA / 2.0  # = (1 − γ)/(2 − γ): both stages solve y = base + κh ẏ(y)
_B1 = 1.0 / (GAMMA * (2.0 - GAMMA))
_B0 = (1.0 - GAMMA) ** 2 / (GAMMA * (2.0 - GAMMA))

#: halvings of a step whose Newton iteration fails before the sample is marked failed
MAX_HALVINGS = 6
#: after a step that failed, the bound on the step length (half of it) grows by this factor
#: with each good step, up to the largest step
RECOVERY = 1.1
#: relative residual at which a stage's Newton iteration stops (or the robot file's looser
#: tolerance): far below a step's truncation error (prototype, 3 s, steps of 2 ms: markers move
#: by 6e-10 m from 1e-10, their error against steps of 0.5 ms is 1e-6 to 4e-5 m); simulate
#: 1.2-1.4x faster
STAGE_TOLERANCE = 1e-8


def _inertia_points(structure: Structure, values: Values):
    """The points of the mass quadrature (the two Zannah points of every grid interval, then
    the lumped masses) and their screw inertias ``w M_ρ`` (n, 6, 6) in the body frame."""
    h = values.h
    X = jnp.stack([values.nodes[:-1] + (0.5 - _Z) * h, values.nodes[:-1] + (0.5 + _Z) * h],
                  axis=1).ravel()
    r = values.radius_z.ravel()
    area, inertia = section(r)
    weight = values.density * jnp.repeat(h / 2, 2)
    M = jax.vmap(jnp.diag)(weight[:, None] * jnp.stack(
        [2 * inertia, inertia, inertia, area, area, area], 1))
    sets = [points_at(structure, values, X)]
    if values.masses.shape[0]:  # m [−d̂, I]ᵀ[−d̂, I]: the centre moves with v + ω × d
        d = values.mass_offsets
        P = jnp.concatenate([-jax.vmap(skew)(d), jnp.broadcast_to(jnp.eye(3), d.shape + (3,))],
                            axis=2)
        M = jnp.concatenate([M, values.masses[:, None, None] * jnp.swapaxes(P, 1, 2) @ P])
        sets.append(points_at(structure, values, values.mass_X))
    return sets, M


def _twists(values: Values, sets, q, v):
    """Body twists ``η = (g⁻¹ ġ)ˇ`` (n, 6) at the points of ``sets`` for ``q̇ = v``."""
    def at(q):
        return jnp.concatenate(poses(values, q, *sets)[1:])

    g, dg = jax.jvp(at, (q,), (v,))
    R = g[:, :3, :3]
    W = jnp.einsum("nji,njk->nik", R, dg[:, :3, :3])
    omega = jnp.stack([W[:, 2, 1], W[:, 0, 2], W[:, 1, 0]], axis=1)
    return jnp.concatenate([omega, jnp.einsum("nji,nj->ni", R, dg[:, :3, 3])], axis=1)


def inertial_force(structure: Structure, values: Values, q, v, a):
    """``M(q) q̈ + C(q, q̇) q̇ = ∫ Jᵀ (M_ρ η̇ − ad_ηᵀ M_ρ η) dX`` (+ the lumped masses): the
    Newton–Euler wrench of every quadrature point pulled back through the configuration
    (:func:`~tendonsense.kinematics.configuration`), η and η̇ by forward-mode derivatives of
    the poses along the motion. No J is formed."""
    sets, M = _inertia_points(structure, values)
    eta, eta_dot = jax.jvp(lambda q, v: _twists(values, sets, q, v), (q, v), (v, a))
    p = jnp.einsum("nij,nj->ni", M, eta)
    w = jnp.einsum("nij,nj->ni", M, eta_dot) - ad_apply(eta, p, transpose=True)
    (grid, nu, *_), pull = configuration(values, q, *sets)
    sizes = np.cumsum([st.h.shape[0] for st in sets])[:-1]
    return pull((jnp.zeros((grid.shape[0], 6)), jnp.zeros_like(nu), *jnp.split(w, sizes)))


def mass_matrix(structure: Structure, values: Values, q):
    """``M(q) = Σ Jᵀ M_ρ J`` (nq, nq) over the mass points, ``J = ∂η/∂q̇`` their body Jacobians
    (the Jacobian of :func:`inertial_force` in q̈)."""
    sets, M = _inertia_points(structure, values)
    J = jax.jacfwd(lambda v: _twists(values, sets, q, v))(jnp.zeros_like(q))
    return jnp.einsum("nik,nij,njl->kl", J, M, J)


@lru_cache(maxsize=CACHE_SIZE)
def mass_matrix_fn(structure: Structure) -> Program:
    """The compiled ``(values, q) -> M(q)`` (:func:`mass_matrix`)."""
    return Program(lambda values, q: mass_matrix(structure, values, q), "mass_matrix",
                   structure)


def free_modes(structure: Structure, values: Values, q=None):
    """The free modes of the rod at shape ``q`` (default straight), slowest first:
    ``K φ = ω² M φ`` with the elastic stiffness K and ``M(q)``, each φ M-normalised. Returns
    ω (rad/s), the damping ratios ``ζ = φᵀ D φ / (2ω)`` (ζ < 1: the mode rings after a sudden
    change of load; for the paper's section ζ = τω/2), the modes (nq, nq) as columns and M."""
    from scipy.linalg import eigh
    q = np.zeros(structure.nq) if q is None else np.asarray(q, float)
    M = np.asarray(mass_matrix_fn(structure)(values, q))
    w2, phi = eigh(values.young_modulus * np.asarray(values.stiffness()), M)
    omega = np.sqrt(np.maximum(w2, 0.0))
    D = np.asarray(values.damping_matrix())
    zeta = np.einsum("ik,ij,jk->k", phi, D, phi) / (2 * np.maximum(omega, 1e-300))
    return omega, zeta, phi, M


def energy(structure: Structure, values: Values, q, v):
    """Kinetic and elastic energy ``½ ∫ ηᵀ M_ρ η dX + ½ E qᵀ K q`` (J), without the loads'
    work."""
    sets, M = _inertia_points(structure, values)
    eta = _twists(values, sets, q, v)
    return (0.5 * jnp.einsum("ni,nij,nj->", eta, M, eta)
            + 0.5 * values.young_modulus * q @ values.stiffness() @ q)


class Schedule(NamedTuple):
    """Known inputs over time, linear between the rows and held after the last: tensions
    ``(k, n_t)`` at ``tension_times``; point forces ``(k', n_p, 3)`` (global) at
    ``force_times`` acting at ``load_X``; gravity constant; every tendon's friction direction
    (n_t,): +1 pulled in, −1 paid out, NaN its tension history decides."""

    tension_times: jax.Array
    tensions: jax.Array
    force_times: jax.Array
    forces: jax.Array
    load_X: jax.Array
    gravity: jax.Array
    sliding: jax.Array

    def drive(self, t) -> Drive:
        T = jax.vmap(lambda col: jnp.interp(t, self.tension_times, col), 1)(self.tensions)
        F = jax.vmap(lambda col: jnp.interp(t, self.force_times, col), 1)(
            self.forces.reshape(self.forces.shape[0], -1))
        return Drive(T, F.reshape(self.forces.shape[1:]), self.load_X, self.gravity,
                     jnp.zeros(0))

    def friction(self, band: Band, mu, t):
        """Every tendon's signed friction coefficient at each turn at time t from the state
        ``band`` (the play operator at the band's turning), and its friction state there."""
        s, _ = play(band, mu, self.drive(t).tensions, band.phi, self.sliding)
        return s * mu[:, None], s


def _load(structure, values, q, drive):
    unknowns = Unknowns.none(structure.n_tendons, drive.load_X.shape[0])
    return terms(structure, values, q, jnp.zeros(0), drive, unknowns, 1.0).load


class State(NamedTuple):
    """The integrator's state: time, q, v (q̇) and a (q̈; without inertia q̇ again), the
    LU factors of the last iteration matrix (reused while Newton converges fast) and the
    tendons' friction history."""

    t: jax.Array
    q: jax.Array
    v: jax.Array
    a: jax.Array
    lu: tuple
    band: Band


def _equations(structure: Structure, values: Values, inertia: bool):
    """``residual(q, base_q, base_v, κh, drive, μ) -> (r, v, a)``: the stage equation
    ``y = base + κh ẏ(y)`` with q the unknown, in force units (v and a follow from q), and
    ``rate(q, drive, μ)``: q̈ at rest at q (q̇ without inertia), and with inertia
    ``matrix(q, κh, drive, μ)``: the stage's iteration matrix; μ the tendons' signed friction
    coefficients."""
    K = values.young_modulus * values.stiffness()
    D = values.damping_matrix()

    def residual(q, base_q, base_v, kh, drive, mu):
        v = (q - base_q) / kh
        load = _load(structure, values._replace(friction=mu), q, drive)
        if not inertia:
            return D @ v + K @ q - load, v, v
        a = (v - base_v) / kh
        return inertial_force(structure, values, q, v, a) + D @ v + K @ q - load, v, a

    def rate(q, drive, mu):  # (at rest: no damping or Coriolis force)
        f = _load(structure, values._replace(friction=mu), q, drive) - K @ q
        return jnp.linalg.solve(mass_matrix(structure, values, q) if inertia else D, f)

    def matrix(q, kh, drive, mu):
        # M(q)/(κh)² + D/(κh) + K − ∂load/∂q: the residual's exact Jacobian but for the
        # derivatives of the inertial force M(q) q̈ + C(q, q̇) q̇ in q and q̇ at fixed q̈
        # (O(κh) against M/(κh)²)
        m = values._replace(friction=mu)
        J = K - jax.jacfwd(lambda q: _load(structure, m, q, drive))(q)
        return J + D / kh + mass_matrix(structure, values, q) / kh**2

    return residual, rate, matrix


def _hermite(s0: State, s1: State, t):
    """q and q̇ at t in [s0.t, s1.t] by the cubic through both states' q and q̇."""
    dt = jnp.maximum(s1.t - s0.t, 1e-300)
    th = jnp.clip((t - s0.t) / dt, 0.0, 1.0)
    h00, h10 = 2 * th**3 - 3 * th**2 + 1, th**3 - 2 * th**2 + th
    h01, h11 = -2 * th**3 + 3 * th**2, th**3 - th**2
    d00, d10, d01, d11 = 6 * th**2 - 6 * th, 3 * th**2 - 4 * th + 1, 6 * th - 6 * th**2, \
        3 * th**2 - 2 * th
    q = h00 * s0.q + h10 * dt * s0.v + h01 * s1.q + h11 * dt * s1.v
    v = (d00 * s0.q + d01 * s1.q) / dt + d10 * s0.v + d11 * s1.v
    return q, v


@lru_cache(maxsize=CACHE_SIZE)
def integrator(structure: Structure, inertia: bool):
    """The compiled programs ``start(q, t, schedule, values) -> State`` (at rest) and
    ``run(state, times, h_max, schedule, values) -> (state, samples)``: TR-BDF2 steps of
    ``h_max`` from ``state`` (a step that fails retried in halves) past every output time in
    ``times``, and at each output time (cubic Hermite interpolation of q and q̇ between the
    steps around it, third order) q, q̇, the marker positions, the tendon length changes,
    whether every step converged, whether the strain is admissible and the tendons' friction
    states (+1 pulled in, −1 paid out, stuck between).

    Each stage is solved to :data:`STAGE_TOLERANCE` by Newton's method on q with the stage's
    exact Jacobian (with inertia, less the derivatives of the inertial force at fixed q̈:
    ``M(q)/(κh)² + D/(κh) + ∂(K q − load)/∂q``), factored once and reused over iterations,
    stages and steps while the residual falls at least tenfold per iteration, refreshed
    otherwise (at most once per iteration); an Armijo line search on the fresh matrix's
    steps. Every stage is solved to its tolerance on the exact residual; a step whose stage
    that matrix cannot solve is retried in halves like any other."""
    num = structure.numerics
    stage_tol = max(num.tolerance, STAGE_TOLERANCE)

    def parts(values, schedule):
        residual, _, matrix = _equations(structure, values, inertia)
        sc = scaling(values, ())
        floor = values.energy_floor * jnp.sqrt(values.young_modulus)

        def scaled(q, base_q, base_v, kh, t, mu):
            r, v, a = residual(q, base_q, base_v, kh, schedule.drive(t), mu)
            return sc.L_inv @ r, (v, a)

        def factor(q, base_q, base_v, kh, t, mu):
            if not inertia:  # the stage residual's exact Jacobian
                J = jax.jacfwd(lambda q: scaled(q, base_q, base_v, kh, t, mu)[0])(q)
                return jax.scipy.linalg.lu_factor(J)
            return jax.scipy.linalg.lu_factor(sc.L_inv @ matrix(q, kh, schedule.drive(t), mu))

        def size(q):
            return jnp.linalg.norm(sc.L_inv @ (values.young_modulus
                                               * (values.stiffness() @ q))) + floor

        return scaled, factor, size

    def run(state, times, h_max, schedule: Schedule, values: Values):
        scaled, factor, size = parts(values, schedule)

        def merit(r):
            m = 0.5 * r @ r
            return jnp.where(jnp.isfinite(m), m, jnp.inf)

        def stage(q0, base_q, base_v, kh, t, mu, lu):
            """Newton on ``y = base + κh ẏ(y)`` from q0; (q, v, a, converged, LU)."""
            args = (base_q, base_v, kh, t, mu)

            def body(st):
                q, r, dq, alpha, fresh, lu, it, _, _ = st
                qt = q + alpha * dq
                rt, _ = scaled(qt, *args)
                ok = merit(rt) <= (1 - 2e-4 * alpha) * merit(r)
                conv = ok & (jnp.linalg.norm(rt) <= stage_tol * size(qt))
                slow = ok & (merit(rt) > 1e-2 * merit(r)) & (it > 0)
                none = ~jnp.any(lu[0] != 0)  # no iteration matrix formed yet (a start)
                refresh = ~conv & ((~ok & ~fresh) | slow | none)
                q, r = jnp.where(ok, qt, q), jnp.where(ok, rt, r)
                lu = jax.lax.cond(refresh, lambda: factor(q, *args), lambda: lu)
                step = ok | refresh
                dq = jnp.where(step, jax.scipy.linalg.lu_solve(lu, -r), dq)
                fail = ~step & (alpha < 2.0**-20)
                return (q, r, dq, jnp.where(step, 1.0, alpha / 2), refresh, lu, it + 1,
                        conv, fail)

            def cond(st):
                return ~st[7] & ~st[8] & (st[6] < num.max_iterations)

            # the first pass evaluates the residual at q0 (a step of zero) and steps from it
            inf = jnp.full_like(q0, jnp.inf)
            st = (q0, inf, jnp.zeros_like(q0), jnp.asarray(0.0), jnp.asarray(False), lu,
                  jnp.asarray(0), jnp.asarray(False), jnp.asarray(False))
            st = jax.lax.while_loop(cond, body, st)
            q = st[0]
            v = (q - base_q) / kh
            return q, v, (v - base_v) / kh if inertia else v, st[7], st[5]

        def step(s: State, h):
            """One TR-BDF2 step of length h; (new state, converged). Its two stages are one
            loop of two passes (one copy of the stage in the program)."""
            qd = s.v if inertia else s.a  # q̇ at the start
            kh = _KAPPA * h

            def one(c, k):
                q1, v1, a1, lu, ok = c
                first = k == 0
                base_q = jnp.where(first, s.q + kh * qd, _B1 * q1 - _B0 * s.q)
                base_v = jnp.where(first, s.v + kh * s.a, _B1 * v1 - _B0 * s.v)
                # second-order guesses: Newton 4.3 -> 3.7 passes a stage (prototype)
                guess = jnp.where(first, s.q + GAMMA * h * qd
                                  + (0.5 * (GAMMA * h) ** 2 * s.a if inertia else 0.0),
                                  q1 + (1 - GAMMA) * h * v1
                                  + (0.5 * ((1 - GAMMA) * h) ** 2 * a1 if inertia else 0.0))
                t = s.t + jnp.where(first, GAMMA, 1.0) * h
                mu, _ = schedule.friction(s.band, values.friction, t)
                q, v, a, good, lu = stage(guess, base_q, base_v, kh, t, mu, lu)
                return (q, v, a, lu, ok & good), a

            (q, v, _, lu, ok), a = jax.lax.scan(one, (s.q, s.v, s.a, s.lu, jnp.asarray(True)),
                                                jnp.arange(2))
            _, band = play(s.band, values.friction, schedule.drive(s.t + h).tensions,
                           depths(structure, values, q), schedule.sliding)
            return State(s.t + h, q, v, a[1], lu, band), ok

        def advance(c, t_end):
            """Steps until the newest state passes t_end, from the last sample's next step
            length (``h_max`` at first): a failing step is retried in halves, and later
            steps are no longer than half of it, a bound that grows by :data:`RECOVERY` with
            each good step (a step that failed once fails again: a run of steps far too
            long, e.g. seconds for milliseconds, retried each sample, took minutes); a good
            step is followed by one twice as long, within that bound; (the last two states,
            the next step's length and its bound, whether every step converged)."""
            def cond(c):
                s, _, h, top, halvings = c
                return (s.t < t_end - 1e-9 * h_max) & (halvings <= MAX_HALVINGS)

            def body(c):
                s, prev, h, top, halvings = c
                new, good = step(s, h)
                keep = s._replace(lu=new.lu)
                pick = lambda a, b: jax.tree_util.tree_map(  # noqa: E731
                    lambda x, y: jnp.where(good, x, y), a, b)
                top = jnp.where(good, jnp.minimum(RECOVERY * top, h_max),
                                jnp.minimum(top, h / 2))
                h_next = jnp.where(good, jnp.minimum(2 * h, top), h / 2)
                halvings = jnp.where(good, jnp.maximum(halvings - 1, 0), halvings + 1)
                return pick(new, keep), pick(s, prev), h_next, top, halvings

            s, prev, h, top = c
            s, prev, h, top, halvings = jax.lax.while_loop(
                cond, body, (s, prev, h, top, jnp.asarray(0)))
            ok = halvings <= MAX_HALVINGS
            # a sample that failed: the run goes on from the last state, marked
            prev = jax.tree_util.tree_map(lambda x, y: jnp.where(ok, x, y), prev, s)
            s = s._replace(t=jnp.where(ok, s.t, t_end))
            return (s, prev, h, top), ok

        def sample(c, t_end):
            (s, prev, h, top), ok = advance(c, t_end)
            q, v = _hermite(prev, s, t_end)
            grid, mk = poses(values, q, points_at(structure, values, values.marker_X))
            _, state = schedule.friction(prev.band, values.friction, t_end)
            state = state[:, -1]  # a tendon's state: its anchor's
            out = (q, v, positions(mk, values.marker_offsets),
                   length_changes(structure, values, grid, q),
                   ok & jnp.all(jnp.isfinite(q)), admissible(values, q), state)
            return (s, prev, h, top), out

        h0 = jnp.asarray(h_max, float)
        (state, *_), out = jax.lax.scan(sample, (state, state, h0, h0), times)
        return state, out

    def start(q, t, schedule: Schedule, values: Values):
        """The state at rest at q at time t with its acceleration (without inertia the rod
        is not at rest: v and a are both the q̇ of the damped motion), no iteration matrix
        yet (the first stage forms it), and every tendon's first reading ahead (pulled in
        unless told)."""
        rate = _equations(structure, values, inertia)[1]
        n_t, nq = values.friction.shape[0], q.shape[0]
        band = Band(jnp.full((n_t, turns(values)), jnp.nan), jnp.zeros(n_t),
                    depths(structure, values, q))
        _, band = play(band, values.friction, schedule.drive(t).tensions, band.phi,
                       schedule.sliding)
        mu, _ = schedule.friction(band, values.friction, t)
        a = rate(q, schedule.drive(t), mu)
        v = jnp.zeros(nq) if inertia else a
        lu = (jnp.zeros((nq, nq)), jnp.zeros(nq, jnp.int32))
        return State(t, q, v, a, lu, band)

    key = (structure, inertia)
    return Program(start, "dynamics_start", key), Program(run, "dynamics", key)
