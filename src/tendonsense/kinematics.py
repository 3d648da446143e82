"""Kinematics: the pose ``g(X)`` by the 4th-order Magnus expansion with the two-point Zannah
quadrature (eq. 4, appendix) and the body Jacobian ``J(q, X)`` with ``η = J q̇`` (eq. 6).

The solvers use poses alone (:func:`poses`) and take generalized forces ``Σ Jᵀ w`` of body
wrenches w (:func:`wrench`) as their pull-back through the poses (:func:`configuration`), by
the backward wrench recursion of the GVS literature rather than with J: no cost grows with
the square of the coordinates. :func:`grid_frames` gives J itself.

Recursion over the grid intervals, ``g_{i+1} = g_i exp(Ω_i)`` and
``J_{i+1} = Ad_{exp(Ω_i)}^{-1} (J_i + dexp_{Ω_i} ∂Ω_i/∂q)``, exact for the discrete map.
"""

from __future__ import annotations

from functools import lru_cache, partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from . import lie
from .compiled import Program
from .model import PointSet, Structure, Values, points_at

_XI_STAR = np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0])
_C = np.sqrt(3.0) / 12.0

_vad = jax.vmap(lie.ad)
_vexp = jax.vmap(lie.expmap)
_vdexp = jax.vmap(lie.dexp)
_vAd_inv = jax.vmap(lie.Ad_inv)
_vAd = jax.vmap(lie.Ad)


class Frames(NamedTuple):
    """Poses (n, 4, 4) and body Jacobians (n, 6, nq) at a set of material points."""

    g: jax.Array
    J: jax.Array


def _strains(q, Phi1, Phi2):
    return Phi1 @ q + _XI_STAR, Phi2 @ q + _XI_STAR


def omega(q, h, Phi1, Phi2):
    """Ω over steps of length h (appendix): ``Ω = h/2 (ξ1 + ξ2) + √3 h²/12 ad_ξ1 ξ2``."""
    xi1, xi2 = _strains(q, Phi1, Phi2)
    h = h[:, None]
    return h / 2 * (xi1 + xi2) + _C * h**2 * lie.ad_apply(xi1, xi2)


def magnus(q, h, Phi1, Phi2):
    """Ω (:func:`omega`) and ∂Ω/∂q."""
    xi1, xi2 = _strains(q, Phi1, Phi2)
    h = h[:, None]
    a1, a2 = _vad(xi1), _vad(xi2)
    dOmega = (h[..., None] / 2 * (Phi1 + Phi2)
              + _C * h[..., None] ** 2 * (a1 @ Phi2 - a2 @ Phi1))
    return omega(q, h[:, 0], Phi1, Phi2), dOmega


def poses(values: Values, q, *points: PointSet):
    """Poses (n_nodes, 4, 4) at every grid node (base pose included) and, for each of
    ``points``, at those points."""
    grid, _, *at_points = configuration(values, q, *points)[0]
    return (grid, *at_points)


@lru_cache(maxsize=8)
def frames_fn(structure: Structure):
    """The compiled ``(values, q, X) -> (n, 4, 4)``: poses at the material abscissae X."""

    def at(values: Values, q, X):
        _, g = poses(values, q, points_at(structure, values, X))
        return g

    return Program(at, "frames", structure)


def configuration(values: Values, q, *points: PointSet):
    """The configuration ``(grid poses, interval-end stretches, poses at each point set)``
    (:func:`poses`, :func:`end_stretches`) and its pull-back ``pull(loads) -> Q``: for
    ``loads = (w_grid, c_nu, *w_points)``, body wrenches at the grid nodes and at the points
    (:func:`wrench`) and a cotangent of the stretches, the generalized force
    ``Σ_i J_iᵀ w_i + (∂ν/∂q)ᵀ c_nu`` (eq. 8b, 13–14).

    The pull-back is the backward wrench recursion in closed form: with ``G_i`` the grid
    poses relative to the base, ``S_i = Σ_{j≥i} Ad*_{G_j⁻¹} w_j`` (a reverse cumulative sum)
    and ``Q = Σ_i (dexp_{Ω_i} ∂Ω_i/∂q)ᵀ Ad_{G_i}ᵀ S_{i+1}`` (eq. 6 transposed); every product
    is a matrix-vector product, so that its exact forward-mode Jacobian is cheap. The grid
    intervals and the points' partial steps go through the exponentials as one batch."""
    n = values.h.shape[0]
    sizes = [p.h.shape[0] for p in points]
    grid_steps = (values.h, values.Phi1, values.Phi2)
    # the points' steps apart: at a traced X they must not make the grid's basis a variable
    point_steps = tuple(jnp.concatenate([getattr(p, f) for p in points])
                        for f in ("h", "Phi1", "Phi2")) if points else None
    starts = jnp.concatenate([jnp.zeros(0, int), *(p.start for p in points)])
    Omega = omega(q, *grid_steps)
    if points:
        Omega = jnp.concatenate([Omega, omega(q, *point_steps)])
    G, at_points = _products(Omega, starts, n)
    grid = values.base @ G
    at_points = values.base @ at_points
    cut = np.cumsum(sizes)[:-1]

    def pull(loads):
        w, c_nu, *w_points = loads
        w_p = jnp.zeros((0, 6), w.dtype)
        if points:
            w_p = lie.coAd_apply(_vexp(Omega[n:]), jnp.concatenate(w_points))
            w = w.at[starts].add(w_p)  # in the frames of the nodes below the points
        S = jnp.cumsum(lie.coAd_apply(G, w)[::-1], axis=0)[::-1]
        u = lie.dexp_apply(Omega, jnp.concatenate([lie.Ad_T_apply(G[:-1], S[1:]), w_p]),
                           transpose=True)
        Q = _omega_pullback(q, *grid_steps, u[:n]) + _contract(c_nu, values.stretch_ends)
        return Q + _omega_pullback(q, *point_steps, u[n:]) if points else Q

    return (grid, end_stretches(values, q), *(jnp.split(at_points, cut) if points else ())), pull


def wrench(g, f, offsets=None):
    """Body wrenches ``[d × Rᵀf; Rᵀf]`` (..., 6) of global forces f (..., 3) acting at
    ``g [d; 1]`` (d in the cross-section frame; at the origin without ``offsets``)."""
    local = lie.rotate_T(g[..., :3, :3], f)
    moment = jnp.zeros_like(local) if offsets is None else jnp.cross(offsets, local)
    return jnp.concatenate([moment, local], axis=-1)


@partial(jax.custom_jvp, nondiff_argnums=(2,))
def _products(Omega, starts, n):
    """``G_i = exp(Ω_0) ⋯ exp(Ω_{i−1})`` (G_0 = I; a parallel prefix product) over the first
    ``n`` steps Ω, and ``G_start exp(Ω_p)`` for the steps Ω_p after them."""
    E = _vexp(Omega)
    eye = jnp.eye(4, dtype=E.dtype)[None]
    G = jnp.concatenate([eye, jax.lax.associative_scan(jnp.matmul, E[:n])])
    return G, G[starts] @ E[n:]


@_products.defjvp
def _products_jvp(n, primals, tangents):
    """Spatial twists ``σ = δG G⁻¹``: ``σ_{i+1} = σ_i + Ad_{G_i} dexp_{Ω_i} δΩ_i`` (eq. 6 in
    the base frame), matrix-vector products only."""
    Omega, starts = primals
    G, at_points = _products(Omega, starts, n)
    step = lie.dexp_apply(Omega, tangents[0])
    sigma = jnp.concatenate([jnp.zeros((1, 6), G.dtype),
                             jnp.cumsum(lie.Ad_apply(G[:-1], step[:n]), axis=0)])
    sigma_points = sigma[starts] + lie.Ad_apply(G[starts], step[n:])
    return (G, at_points), (lie.hat_times(sigma, G), lie.hat_times(sigma_points, at_points))


def _omega_pullback(q, h, Phi1, Phi2, u):
    """``Σ_i (∂Ω_i/∂q)ᵀ u_i`` (:func:`magnus`) by matrix-vector products."""
    xi1, xi2 = _strains(q, Phi1, Phi2)
    h = h[:, None]
    u1 = h / 2 * u - _C * h**2 * lie.ad_apply(xi2, u, transpose=True)
    u2 = h / 2 * u + _C * h**2 * lie.ad_apply(xi1, u, transpose=True)
    return _contract(u1, Phi1) + _contract(u2, Phi2)


def _contract(u, M):
    """``Σ u[...] M[..., :]`` as a row vector times the matrix M (..., nq) as stored, which
    XLA does without a transposed copy of M."""
    return jnp.reshape(u, (-1,)) @ jnp.reshape(M, (u.size, -1))


def end_stretches(values: Values, q):
    """The linear strain ν (body frame) at the two ends of every interval, (n_int, 2, 3)."""
    return values.stretch_ends @ q + _XI_STAR[3:]


def grid_frames(structure: Structure, values: Values, q, *points: PointSet):
    """Poses and body Jacobians at every grid node (base pose included); with ``points``, also
    at each of those point sets (one batched Magnus/exp evaluation for all)."""
    n = values.h.shape[0]
    sets = [PointSet(None, values.h, values.Phi1, values.Phi2), *points]
    Omega, dOmega = magnus(q, *(jnp.concatenate([getattr(p, f) for p in sets])
                                for f in ("h", "Phi1", "Phi2")))
    E, A = _vexp(Omega), _vdexp(Omega) @ dOmega
    grid = _chain(structure, values, E[:n], A[:n])
    if not points:
        return grid
    out, k = [grid], n
    for p in points:
        m = p.h.shape[0]
        Ek, Ak = E[k:k + m], A[k:k + m]
        g0, J0 = grid.g[p.start], grid.J[p.start]
        out.append(Frames(g0 @ Ek, _vAd_inv(Ek) @ (J0 + Ak)))
        k += m
    return tuple(out)


def _chain(structure, values, E, A) -> Frames:
    """Recursion in closed form: with ``G_i = E_0 ⋯ E_{i−1}`` (a parallel prefix product),
    ``Ad_{G_i} J_i = Σ_{k<i} Ad_{G_k} A_k`` (a cumulative sum)."""
    eye = jnp.eye(4, dtype=E.dtype)[None]
    G = jnp.concatenate([eye, jax.lax.associative_scan(jnp.matmul, E)])
    AdG = _vAd(G)
    C = jnp.cumsum(AdG[:-1] @ A, axis=0)
    J = jnp.concatenate([jnp.zeros((1, 6, structure.nq), E.dtype), _vAd_inv(G[1:]) @ C])
    return Frames(values.base @ G, J)


def positions(g, offsets=None) -> jax.Array:
    """Points ``p + R d`` of the poses ``g`` (global), d in the cross-section frame."""
    p = g[:, :3, 3]
    if offsets is None:
        return p
    return p + lie.rotate(g[:, :3, :3], offsets)
