"""External loads as generalized forces (eq. 8b): gravity as a distributed load and point
forces given in the global frame at material points."""

from __future__ import annotations

import jax.numpy as jnp

from .kinematics import Frames


def _force_wrench(frames: Frames, f_global):
    """Body wrenches ``[0; Rᵀ f]`` of forces applied at the frames' origins."""
    f_loc = jnp.einsum("nji,nj->ni", frames.g[:, :3, :3], f_global)
    return jnp.concatenate([jnp.zeros_like(f_loc), f_loc], axis=1)


def gravity(frames: Frames, weights, density, acceleration):
    """``∫ Jᵀ M̄ Ad_g⁻¹ G dX`` by quadrature: ``weights`` carry the area and the rule's weights."""
    f = (density * weights)[:, None] * acceleration[None, :]
    return jnp.einsum("nki,nk->i", frames.J, _force_wrench(frames, f))


def point_forces(frames: Frames, forces):
    """``Σ_k J_kᵀ Ad*_{g_θ} F_k`` for global forces ``forces`` (n_p, 3) at the frames."""
    return jnp.einsum("nki,nk->i", frames.J, _force_wrench(frames, forces))
