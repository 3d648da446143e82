"""Tendons: path through the guide disks, length change (eq. 9), Capstan friction (eq. 10–13)
and the actuation matrix ``B(q)`` (eq. 14)."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .kinematics import Frames, positions
from .lie import safe_norm
from .model import Model, TendonGrid


def path(tendon: TendonGrid, grid: Frames):
    """Frames at the disks and the global tendon points ``r_i = g_i [d_i; 1]``."""
    at = Frames(grid.g[tendon.nodes], grid.J[tendon.nodes])
    return at, positions(at, tendon.offsets)


def length_changes(model: Model, grid: Frames):
    """``y = Σ ‖r_{i+1} − r_i‖ − l*`` for every tendon (eq. 9), shape (n_t,)."""
    out = []
    for t in model.tendons:
        _, r = path(t, grid)
        out.append(jnp.sum(jnp.linalg.norm(jnp.diff(r, axis=0), axis=1)) - t.rest_length)
    return jnp.stack(out) if out else jnp.zeros((0,))


def actuation(model: Model, grid: Frames, friction):
    """``B(q)`` of eq. 14, shape (nq, n_t): the generalized force of a unit tension.

    At disk i the tendon pulls with ``f_i = T_i v_L + T_{i+1} v_R`` (eq. 12) where the tension
    drops by ``exp(−μ φ_i)`` across every disk (eq. 10), ``φ_i`` the angle the tendon turns there;
    at the first disk it arrives from the actuator along the local −x axis.
    """
    cols = []
    for j, t in enumerate(model.tendons):
        at, r = path(t, grid)
        seg = jnp.diff(r, axis=0)
        u = seg / jnp.linalg.norm(seg, axis=1, keepdims=True)
        v_R = jnp.concatenate([u, jnp.zeros((1, 3))])
        v_L = jnp.concatenate([-at.g[:1, :3, 0], -u])
        phi = _vangle(-v_L[:-1], v_R[:-1])  # eq. 10, turning angle at every disk but the anchor
        ratio = jnp.exp(-friction[j] * jnp.concatenate([jnp.zeros(1), jnp.cumsum(phi)]))
        f = ratio[:, None] * v_L + jnp.concatenate([ratio[1:], jnp.zeros(1)])[:, None] * v_R
        f_loc = jnp.einsum("nji,nj->ni", at.g[:, :3, :3], f)  # R_iᵀ f_i
        W = jnp.concatenate([jnp.cross(t.offsets, f_loc), f_loc], axis=1)  # eq. 13
        cols.append(jnp.einsum("nki,nk->i", at.J, W))
    return jnp.stack(cols, axis=1) if cols else jnp.zeros((model.nq, 0))


def _vangle(a, b):
    """Row-wise angle between unit vectors, ``2 atan2(|a − b|, |a + b|)``; its derivative at a
    straight pass (angle 0, where the Capstan law has a kink) is taken as 0."""
    return 2.0 * jnp.arctan2(jax.vmap(safe_norm)(a - b), jax.vmap(safe_norm)(a + b))
