"""Tendons: path through the guide disks, length change (eq. 9), Capstan friction (eq. 10–13)
and the actuation matrix ``B(q)`` (eq. 14).

Tendons with the same number of disks are computed together (leading axis k)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .kinematics import force_cotangent, poses
from .lie import safe_norm
from .model import Structure, TendonGroup, Values


def path(group: TendonGroup, g):
    """Poses at the disks (k, nd, 4, 4) and the global tendon points ``r_i = g_i [d_i; 1]``,
    from the grid poses ``g``."""
    at = g[group.nodes]
    r = at[..., :3, 3] + jnp.einsum("knij,knj->kni", at[..., :3, :3], group.offsets)
    return at, r


def length_changes(structure: Structure, values: Values, g):
    """``y = Σ ‖r_{i+1} − r_i‖ − l*`` for every tendon (eq. 9), shape (n_t,), from the grid
    poses ``g``."""
    y = jnp.zeros(structure.n_tendons)
    for index, grp in zip(structure.groups, values.tendons):
        _, r = path(grp, g)
        lengths = jnp.sum(jnp.linalg.norm(jnp.diff(r, axis=1), axis=2), axis=1)
        y = y.at[np.array(index)].set(lengths - grp.rest_length)
    return y


def unit_cotangents(structure: Structure, values: Values, g, friction):
    """The pull of a unit tension of each tendon as cotangents of the grid poses,
    shape (n_t, n_nodes, 4, 4) (:func:`~tendonsense.kinematics.force_cotangent`).

    At disk i the tendon pulls with ``f_i = T_i v_L + T_{i+1} v_R`` (eq. 12) where the tension
    drops by ``exp(−μ φ_i)`` across every disk (eq. 10), ``φ_i`` the angle the tendon turns there;
    at the first disk it arrives from the actuator along the local −x axis.
    """
    out = jnp.zeros((structure.n_tendons,) + g.shape, g.dtype)
    for index, grp in zip(structure.groups, values.tendons):
        index = np.array(index)
        at, r = path(grp, g)
        k = r.shape[0]
        seg = jnp.diff(r, axis=1)
        u = seg / jnp.linalg.norm(seg, axis=2, keepdims=True)
        v_R = jnp.concatenate([u, jnp.zeros((k, 1, 3))], axis=1)
        v_L = jnp.concatenate([-at[:, :1, :3, 0], -u], axis=1)
        phi = _angle(-v_L[:, :-1], v_R[:, :-1])  # eq. 10: the turn at every disk but the anchor
        mu = friction[index][:, None]
        ratio = jnp.exp(-mu * jnp.concatenate([jnp.zeros((k, 1)), jnp.cumsum(phi, axis=1)], axis=1))
        after = jnp.concatenate([ratio[:, 1:], jnp.zeros((k, 1))], axis=1)
        f = ratio[..., None] * v_L + after[..., None] * v_R  # eq. 12
        out = out.at[index[:, None], grp.nodes].add(force_cotangent(f, grp.offsets))  # eq. 13
    return out


def actuation(structure: Structure, values: Values, q, friction):
    """``B(q)`` of eq. 14, shape (nq, n_t): the generalized force of a unit tension, the
    pull-back of :func:`unit_cotangents` through the grid poses."""
    g, pull = jax.vjp(lambda q: poses(values, q)[0], q)
    return jax.vmap(lambda c: pull(c)[0])(unit_cotangents(structure, values, g, friction)).T


def _angle(a, b):
    """Angle between unit vectors (last axis), ``2 atan2(|a − b|, |a + b|)``; its derivative at a
    straight pass (angle 0, where the Capstan law has a kink) is taken as 0."""
    n = jax.vmap(jax.vmap(safe_norm))
    return 2.0 * jnp.arctan2(n(a - b), n(a + b))
