"""Rod geometry and material: circular cross-section of piecewise-linear radius."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Rod:
    """A Cosserat rod of length ``length`` whose radius is linear between ``radius_knots``
    ``((0, r0), ..., (L, rn))``; linear elastic, ``G = E / (2 (1 + ν))``, with Kelvin–Voigt
    damping of viscosity ``damping``."""

    length: float
    radius_knots: tuple[tuple[float, float], ...]
    young_modulus: float
    poisson_ratio: float
    density: float
    disk_radius: float | None = None  # spacer disks wider than the rod; None: tendons inside
    damping: float = 0.0  # Kelvin–Voigt viscosity η, Pa·s

    def radius(self, X) -> np.ndarray:
        Xk, rk = np.array(self.radius_knots).T
        return np.interp(X, Xk, rk)

    def breakpoints(self) -> np.ndarray:
        """Abscissae where the radius law changes slope (interior knots)."""
        return np.array([x for x, _ in self.radius_knots[1:-1]])

    def area(self, X) -> np.ndarray:
        return section(self.radius(X))[0]


def section(r):
    """Area ``A = π r²`` and second moment of area ``I = π r⁴ / 4`` of a circular section of
    radius ``r`` (NumPy or JAX): ``Σ = diag(2 G I, E I, E I, E A, G A, G A)`` (eq. 8a)."""
    return np.pi * r**2, np.pi * r**4 / 4.0
