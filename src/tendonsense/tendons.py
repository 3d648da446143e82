"""Tendons: path through the guide disks, length change (eq. 9), Capstan friction (eq. 10–13)
and the actuation matrix ``B(q)`` (eq. 14); and tendons routed continuously along the rod
(the limit of infinitely many disks), by path integrals.

Tendons with the same number of disks are computed together (leading axis k)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax.custom_derivatives import SymbolicZero

from .kinematics import configuration, wrench
from .lie import rotate, safe_norm
from .model import Structure, TendonGroup, Values


def path(group: TendonGroup, g):
    """Poses at the disks (k, nd, 4, 4) and the global tendon points ``r_i = g_i [d_i; 1]``,
    from the grid poses ``g``."""
    at = g[group.nodes]
    r = at[..., :3, 3] + rotate(at[..., :3, :3], group.offsets)
    return at, r


def length_changes(structure: Structure, values: Values, g, q):
    """``y = Σ ‖r_{i+1} − r_i‖ − l*`` for every tendon (eq. 9), shape (n_t,), from the grid
    poses ``g``; ``y = ∫ |w| dX − l*`` for a continuous one (strains ``q``)."""
    y = jnp.zeros(structure.n_tendons)
    for index, grp in zip(structure.groups, values.tendons):
        _, r = path(grp, g)
        lengths = jnp.sum(jnp.linalg.norm(jnp.diff(r, axis=1), axis=2), axis=1)
        y = y.at[np.array(index)].set(lengths - grp.rest_length)
    if structure.continuous:
        ct = values.continuous
        lengths = jnp.einsum("im,kim->k", ct.weights, jnp.linalg.norm(ct.A @ q + ct.c, axis=-1))
        y = y.at[np.array(structure.continuous)].set(lengths - ct.rest_length)
    return y


def continuous_actuation(structure: Structure, values: Values, q, friction):
    """The generalized force of a unit tension of every continuously routed tendon, (nq, n_t)
    (zero columns for the others): ``−∫ T(X)/T₀ ∂|w|/∂q dX``, the virtual work of a tendon
    whose tension fades by ``exp(−μ θ(X))`` with the angle θ its path has turned through since
    the actuator (eq. 10 in the limit of infinitely many disks): its pull at the anchor, the
    distributed pressure on the curved path and the friction along it. Its derivatives in q
    and μ are analytic (:func:`_continuous`), so that forward mode costs one pass."""
    nq = structure.nq
    if not structure.continuous:
        return jnp.zeros((nq, structure.n_tendons))
    index = np.array(structure.continuous)
    mu = friction[index] if friction.ndim == 1 else friction[index, -1]  # one state: its anchor's
    B = _continuous_B(q, mu, values.continuous, values.h)
    return jnp.zeros((nq, structure.n_tendons)).at[:, index].set(B.T)


@jax.custom_jvp
def _continuous_B(q, mu, ct, h):
    """(k, nq) unit-tension generalized forces; the geometry ``ct``, ``h`` is not
    differentiated."""
    return _continuous(q, mu, ct, h, with_mu=False)[0]


def _continuous_B_jvp(primals, tangents):
    q, mu, ct, h = primals
    dq, dmu = tangents[:2]
    B, J_q, J_mu = _continuous(q, mu, ct, h, with_mu=not isinstance(dmu, SymbolicZero))
    dB = jnp.zeros_like(B)  # a solve moves q alone: ∂B/∂μ is not even computed
    if not isinstance(dq, SymbolicZero):
        dB = dB + J_q @ dq
    if not isinstance(dmu, SymbolicZero):
        dB = dB + J_mu * dmu[:, None]
    return B, dB


_continuous_B.defjvp(_continuous_B_jvp, symbolic_zeros=True)


def _rate(w, dw, omega):
    """|t′| of the path (unit tangent t = R ŵ), ``|ω × ŵ + ŵ′|`` with ``ŵ′ = (I − ŵŵᵀ) w′ / |w|``,
    and its gradients in w, w′ and ω (last axis 3; zero where the path does not turn)."""
    s = jnp.sqrt(_dot(w, w))[..., None]
    u = w / s
    along = _dot(u, dw)[..., None]
    across = dw - u * along  # (I − ŵŵᵀ) w′
    v = jnp.cross(omega, u) + across / s
    rate = safe_norm(v)
    n = v / jnp.where(rate > 0, rate, 1.0)[..., None]
    c = jnp.cross(n, omega) - (along * n + _dot(n, u)[..., None] * dw) / s
    g_w = (c - u * _dot(u, c)[..., None] - _dot(n, across)[..., None] * u / s) / s
    g_dw = (n - u * _dot(u, n)[..., None]) / s
    return rate, g_w, g_dw, jnp.cross(u, n)


def _unit_angle(a, b):
    """The angle between a and b (any length, last axis 3) and its gradients in a and b (zero
    at a straight pass, as :func:`_angle`)."""
    la, lb = jnp.sqrt(_dot(a, a))[..., None], jnp.sqrt(_dot(b, b))[..., None]
    ua, ub = a / la, b / lb
    normal = jnp.cross(ua, ub)  # exactly 0 for equal directions
    to_b, to_a = jnp.cross(normal, ua), jnp.cross(ub, normal)  # ⊥ a toward b, ⊥ b toward a
    sin = safe_norm(normal)[..., None]
    sin = jnp.where(sin > 0, sin, jnp.inf)
    return _angle(ua, ub), -to_b / (la * sin), -to_a / (lb * sin)


def _continuous(q, mu, ct, h, with_mu=True):
    """B (k, nq) and its exact derivatives ``∂B/∂q`` (k, nq, nq) and ``∂B/∂μ`` (k, nq): the
    angle θ is a sum of turning rates, entry and kink angles, each a function of a few local
    path quantities linear in q, differentiated locally and carried to q by those maps.
    Without ``with_mu`` θ is only computed if some μ > 0 (no friction: nothing fades), and
    ``∂B/∂μ`` is then not valid."""
    w = ct.A @ q + ct.c  # (k, n_int, m, 3)
    size = jnp.sqrt(jnp.sum(w * w, axis=-1, keepdims=True))  # ≈ 1 + ε: never 0
    unit = w / size
    pull = jnp.einsum("kima,kimaq->kimq", unit, ct.A)  # ∂|w|/∂q

    def turned():  # θ (k, n_int, m), its fade with the weights and the friction part of J_q
        rate, g_w, g_dw, g_om = _rate(w, ct.dA @ q, ct.Omega @ q)  # (k, n_int, m), (…, 3)
        d_rate = (jnp.einsum("kima,kimaq->kimq", g_w, ct.A)
                  + jnp.einsum("kima,kimaq->kimq", g_dw, ct.dA)
                  + jnp.einsum("kima,imaq->kimq", g_om, ct.Omega))
        ends = ct.A_ends @ q + ct.c_ends  # (k, n_int, 2, 3)
        # the entry from the actuator (along x) at [:, 0, 0], the kinks where intervals meet
        first = jnp.broadcast_to(jnp.array([1.0, 0.0, 0.0]), ends[:, :1, 1].shape)
        angles, g_before, g_after = _unit_angle(
            jnp.concatenate([first, ends[:, :-1, 1]], 1), ends[:, :, 0])
        g_ends = jnp.stack([g_after, jnp.concatenate([g_before[:, 1:], 0 * first], 1)], 2)
        d_ends = jnp.einsum("kija,kijaq->kijq", g_ends, ct.A_ends)
        d_angles = d_ends[:, :, 0] + jnp.concatenate([0 * d_ends[:, :1, 1], d_ends[:, :-1, 1]],
                                                     1)
        per_interval = jnp.sum(ct.weights * rate, axis=-1)
        d_per_interval = jnp.einsum("im,kimq->kiq", ct.weights, d_rate)
        before = jnp.concatenate([0 * per_interval[:, :1], per_interval[:, :-1]], 1)
        d_before = jnp.concatenate([0 * d_per_interval[:, :1], d_per_interval[:, :-1]], 1)
        steps, d_steps = jnp.cumsum(angles + before, 1), jnp.cumsum(d_angles + d_before, 1)
        theta = steps[..., None] + h[:, None] * (rate @ ct.cumulative.T)
        d_theta = d_steps[:, :, None] + h[:, None, None] * jnp.einsum(
            "mj,kijq->kimq", ct.cumulative, d_rate)
        fade = ct.weights * jnp.exp(-mu[:, None, None] * theta)
        return theta, fade, jnp.einsum("kim,kimq,kimr->kqr", mu[:, None, None] * fade, pull,
                                       d_theta)

    def frictionless():  # nothing fades
        k, nq = pull.shape[0], q.shape[0]
        return (jnp.zeros(w.shape[:-1], w.dtype), jnp.broadcast_to(ct.weights, w.shape[:-1]),
                jnp.zeros((k, nq, nq), w.dtype))

    if with_mu:
        theta, fade, friction = turned()
    else:
        theta, fade, friction = jax.lax.cond(jnp.any(mu != 0), turned, frictionless)
    B = -jnp.einsum("kim,kimq->kq", fade, pull)
    projected = (ct.A - unit[..., None] * pull[..., None, :]) / size[..., None]  # ∂ŵ/∂q
    J_q = friction - jnp.einsum("kim,kimaq,kimar->kqr", fade, ct.A, projected)
    J_mu = jnp.einsum("kim,kimq->kq", fade * theta, pull)
    return B, J_q, J_mu


def unit_wrenches(structure: Structure, values: Values, g, friction):
    """The pull of a unit tension of each tendon as body wrenches at the grid nodes ``g``,
    shape (n_t, n_nodes, 6) (:func:`~tendonsense.kinematics.wrench`).

    At disk i the tendon pulls with ``f_i = T_i v_L + T_{i+1} v_R`` (eq. 12) where the tension
    drops by ``exp(−μ φ_i)`` across every disk (eq. 10), ``φ_i`` the angle the tendon turns there;
    at the first disk it arrives from the actuator along the local −x axis. ``friction`` is one
    μ per tendon (n_t,), or one per turn (n_t, :func:`turns`): past its j-th turn a tendon's
    tension is then ``T exp(−μ_j ψ_j)``, ``ψ_j`` the turning from the actuator to there (a
    friction state per turn, :mod:`tendonsense.sliding`).
    """
    out = jnp.zeros((structure.n_tendons, g.shape[0], 6), g.dtype)
    for index, grp in zip(structure.groups, values.tendons):
        index = np.array(index)
        at, r = path(grp, g)
        k = r.shape[0]
        seg = jnp.diff(r, axis=1)
        u = seg / jnp.linalg.norm(seg, axis=2, keepdims=True)
        v_R = jnp.concatenate([u, jnp.zeros((k, 1, 3))], axis=1)
        v_L = jnp.concatenate([-at[:, :1, :3, 0], -u], axis=1)
        phi = _angle(-v_L[:, :-1], v_R[:, :-1])  # eq. 10: the turn at every disk but the anchor
        mu = friction[index][:, None] if friction.ndim == 1 else friction[index, :phi.shape[1]]
        ratio = jnp.exp(-jnp.concatenate([jnp.zeros((k, 1)), mu * jnp.cumsum(phi, axis=1)], axis=1))
        after = jnp.concatenate([ratio[:, 1:], jnp.zeros((k, 1))], axis=1)
        f = ratio[..., None] * v_L + after[..., None] * v_R  # eq. 12
        out = out.at[index[:, None], grp.nodes].add(wrench(at, f, grp.offsets))  # eq. 13
    return out


def turns(values: Values) -> int:
    """The most turns of any tendon (a disk-routed one turns at every disk but its anchor;
    at least 1): the columns of :func:`depths`."""
    return max([grp.nodes.shape[1] - 1 for grp in values.tendons] + [1])


def turning(structure: Structure, values: Values, q):
    """The angle φ (rad) every tendon turns through from the actuator to its anchor, shape
    (n_t,): the sum of its turns at the disks (eq. 10), or the turning of a continuous path;
    its Capstan band is ``T_anchor / T_actuator ∈ [exp(−μφ), exp(+μφ)]``."""
    return depths(structure, values, q)[:, -1]


def depths(structure: Structure, values: Values, q):
    """The angle (rad) every tendon turns through from the actuator to each of its turns,
    ``ψ_j = φ_1 + … + φ_j``, shape (n_t, :func:`turns`): a tendon with fewer turns repeats
    its last, a continuous one its whole turning (:func:`turning` is the last column)."""
    (g, _), _ = configuration(values, q)
    m = turns(values)
    phi = jnp.zeros((structure.n_tendons, m))
    for index, grp in zip(structure.groups, values.tendons):
        at, r = path(grp, g)
        u = jnp.diff(r, axis=1)
        u = u / jnp.linalg.norm(u, axis=2, keepdims=True)
        v_L = jnp.concatenate([-at[:, :1, :3, 0], -u], axis=1)
        psi = jnp.cumsum(_angle(-v_L[:, :-1], u), axis=1)
        psi = jnp.concatenate([psi, jnp.repeat(psi[:, -1:], m - psi.shape[1], axis=1)], axis=1)
        phi = phi.at[np.array(index)].set(psi)
    if structure.continuous:
        ct = values.continuous
        w = ct.A @ q + ct.c
        rate = _rate(w, ct.dA @ q, ct.Omega @ q)[0]
        ends = ct.A_ends @ q + ct.c_ends
        first = jnp.broadcast_to(jnp.array([1.0, 0.0, 0.0]), ends[:, :1, 1].shape)
        kinks = _unit_angle(jnp.concatenate([first, ends[:, :-1, 1]], 1), ends[:, :, 0])[0]
        total = jnp.sum(kinks, 1) + jnp.sum(ct.weights * rate, axis=(1, 2))
        phi = phi.at[np.array(structure.continuous)].set(total[:, None])
    return phi


def turning_along(points, entry) -> np.ndarray:
    """The angle (rad) a tendon through ``points`` (n, 3), arriving from its actuator along
    ``entry`` (3,), has turned through at each of its points but the last,
    ``ψ_i = φ_0 + … + φ_i`` (eq. 10: the turns at the disks of a disk-routed tendon; for a
    continuous one, the turning of the polyline through its points). Pulled in, the segment
    after point i carries ``T exp(−μ ψ_i)``."""
    u = np.diff(np.asarray(points, float), axis=0)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    before = np.concatenate([np.asarray(entry, float)[None] / np.linalg.norm(entry), u[:-1]])
    return np.cumsum(_angle(before, u, np))


def actuation(structure: Structure, values: Values, q, friction):
    """``B(q)`` of eq. 14, shape (nq, n_t): the generalized force of a unit tension, the
    pull-back of :func:`unit_wrenches` through the grid poses."""
    (g, nu), pull = configuration(values, q)
    zero = jnp.zeros_like(nu)
    return (jax.vmap(lambda w: pull((w, zero)))(unit_wrenches(structure, values, g, friction)).T
            + continuous_actuation(structure, values, q, friction))


def _angle(a, b, xp=jnp):
    """Angle between unit vectors (last axis), ``2 atan2(|a − b|, |a + b|)``; its derivative at a
    straight pass (angle 0, where the Capstan law has a kink) is taken as 0 (``xp`` numpy: on
    the host, no program to build)."""
    return 2.0 * xp.arctan2(safe_norm(a - b, xp), safe_norm(a + b, xp))


def _dot(a, b):
    return jnp.sum(a * b, axis=-1)
