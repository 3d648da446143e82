"""Kinematics: the pose ``g(X)`` by the 4th-order Magnus expansion with the two-point Zannah
quadrature (eq. 4, appendix) and the body Jacobian ``J(q, X)`` with ``η = J q̇`` (eq. 6).

The solvers use poses alone (:func:`poses`) and take generalized forces ``Jᵀ W`` as the
pull-back (reverse-mode derivative) of forces through them; :func:`grid_frames` gives J itself.

Recursion over the grid intervals, ``g_{i+1} = g_i exp(Ω_i)`` and
``J_{i+1} = Ad_{exp(Ω_i)}^{-1} (J_i + dexp_{Ω_i} ∂Ω_i/∂q)``, exact for the discrete map.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from . import lie
from .model import PointSet, Structure, Values

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
    return h / 2 * (xi1 + xi2) + _C * h**2 * jnp.einsum("nij,nj->ni", _vad(xi1), xi2)


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
    ``points``, at those points — no Jacobians: generalized forces are taken as the pull-back
    of forces through this map (:func:`force_cotangent`), so the cost of an exact Jacobian
    grows with the coordinates, not their square."""
    # each set on its own: points at a traced X must not make the grid's basis a variable
    E = _vexp(omega(q, values.h, values.Phi1, values.Phi2))
    eye = jnp.eye(4, dtype=E.dtype)[None]
    g = values.base @ jnp.concatenate([eye, jax.lax.associative_scan(jnp.matmul, E)])
    return (g, *(g[p.start] @ _vexp(omega(q, p.h, p.Phi1, p.Phi2)) for p in points))


def end_stretches(values: Values, q):
    """The linear strain ν (body frame) at the two ends of every interval, (n_int, 2, 3)."""
    return values.stretch_ends @ q + _XI_STAR[3:]


def force_cotangent(f, offsets=None):
    """The cotangent of a pose ``g`` for a global force ``f`` at ``g [d; 1]``: the derivative
    of the virtual work ``f · (p + R d)`` with respect to g, so that pulling it back through
    :func:`poses` gives the generalized force ``Jᵀ [d × Rᵀf; Rᵀf]`` of eq. 8b and 13–14."""
    top = f[..., :, None] if offsets is None else jnp.concatenate(
        [f[..., :, None] * offsets[..., None, :], f[..., :, None]], axis=-1)
    if offsets is None:
        top = jnp.concatenate([jnp.zeros(f.shape + (3,), f.dtype), top], axis=-1)
    return jnp.concatenate([top, jnp.zeros(f.shape[:-1] + (1, 4), f.dtype)], axis=-2)


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
    return p + jnp.einsum("nij,nj->ni", g[:, :3, :3], offsets)
