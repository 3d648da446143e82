"""External loads (eq. 8b): gravity as a distributed load and point forces given in the global
frame at material points, as cotangents of the poses where they act
(:func:`~tendonsense.kinematics.force_cotangent`); pulled back through the poses they give
``∫ Jᵀ M̄ Ad_g⁻¹ G dX`` and ``Σ_k J_kᵀ Ad*_{g_θ} F_k``."""

from __future__ import annotations

from .kinematics import force_cotangent


def gravity(weights, density, acceleration):
    """Gravity at the quadrature points by its cotangents; ``weights`` carry the area and the
    rule's weights."""
    return force_cotangent((density * weights)[:, None] * acceleration[None, :])


def point_forces(forces):
    """Global forces ``forces`` (n_p, 3) at their points' origins by their cotangents."""
    return force_cotangent(forces)
