"""External loads (eq. 8b): gravity as a distributed load, lumped masses and point forces given
in the global frame at material points, as body wrenches where they act
(:func:`~tendonsense.kinematics.wrench`); pulled back through the configuration they give
``∫ Jᵀ M̄ Ad_g⁻¹ G dX`` and ``Σ_k J_kᵀ Ad*_{g_θ} F_k``."""

from __future__ import annotations

import jax.numpy as jnp

from .kinematics import wrench
from .lie import rotate_T


def gravity(values, g, nu, acceleration):
    """Gravity as body wrenches at the grid nodes ``g`` and a cotangent of the interval-end
    stretches ``nu`` (:func:`~tendonsense.kinematics.end_stretches`): the derivatives of its
    work ``ρ a · ∫ A p dX``, p cubic Hermite on every interval through the node positions and
    tangents ``p' = R ν`` (``values.gravity_weights``: ``Σ w · [p_i, R_i ν_i, p_{i+1},
    R_{i+1} ν'_i]``)."""
    w = values.density * values.gravity_weights  # (n_int, 4)
    local = rotate_T(g[:, :3, :3], acceleration)  # Rᵀ a at every node
    zero = jnp.zeros((1,), w.dtype)
    force = jnp.concatenate([w[:, 0], zero]) + jnp.concatenate([zero, w[:, 2]])
    arm = (jnp.concatenate([w[:, 1:2] * nu[:, 0], jnp.zeros((1, 3))])
           + jnp.concatenate([jnp.zeros((1, 3)), w[:, 3:4] * nu[:, 1]]))
    node = jnp.concatenate([jnp.cross(arm, local), force[:, None] * local], axis=1)
    return node, jnp.stack([w[:, 1:2] * local[:-1], w[:, 3:4] * local[1:]], axis=1)


def lumped_masses(values, g, acceleration):
    """The weights of the lumped masses at their centres (poses ``g`` of their points)."""
    return wrench(g, values.masses[:, None] * acceleration, values.mass_offsets)


def point_forces(g, forces):
    """Global forces ``forces`` (n_p, 3) at the origins of the poses ``g``."""
    return wrench(g, forces)
