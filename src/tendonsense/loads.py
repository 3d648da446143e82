"""External loads (eq. 8b): gravity as a distributed load, lumped masses and point forces given in the global
frame at material points, as cotangents of the configuration (poses and stretches) where they
act (:func:`~tendonsense.kinematics.force_cotangent`); pulled back through it they give
``∫ Jᵀ M̄ Ad_g⁻¹ G dX`` and ``Σ_k J_kᵀ Ad*_{g_θ} F_k``."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .kinematics import force_cotangent


def gravity(values, g, nu, acceleration):
    """Gravity by its cotangents of the grid poses ``g`` and of the interval-end stretches
    ``nu`` (:func:`~tendonsense.kinematics.end_stretches`): the derivatives of its work
    ``ρ a · ∫ A p dX``, p cubic Hermite on every interval through the node positions and
    tangents ``p' = R ν`` (``values.gravity_weights``)."""

    def work(g, nu):
        p, R, w = g[:, :3, 3], g[:, :3, :3], values.gravity_weights
        left = jnp.einsum("nij,nj->ni", R[:-1], nu[:, 0])
        right = jnp.einsum("nij,nj->ni", R[1:], nu[:, 1])
        integral = (w[:, 0:1] * p[:-1] + w[:, 1:2] * left + w[:, 2:3] * p[1:]
                    + w[:, 3:4] * right).sum(axis=0)
        return values.density * jnp.dot(acceleration, integral)

    return jax.grad(work, argnums=(0, 1))(g, nu)


def lumped_masses(values, acceleration):
    """The weights of the lumped masses at their centres, by their cotangents."""
    return force_cotangent(values.masses[:, None] * acceleration, values.mass_offsets)


def point_forces(forces):
    """Global forces ``forces`` (n_p, 3) at their points' origins by their cotangents."""
    return force_cotangent(forces)
