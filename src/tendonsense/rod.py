"""Rod geometry and material: circular cross-section of piecewise-linear radius."""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

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

    @property
    def relaxation_time(self) -> float:
        """τ = 3η/E, s: every mode of an incompressible Kelvin–Voigt rod relaxes with it
        (0 without damping)."""
        return 3.0 * self.damping / self.young_modulus

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


class Overlap(NamedTuple):
    """Where a rod's shape passes through itself (:func:`overlap`): the centre line at ``X``
    and at ``X_other`` (m, ``X < X_other``) is ``distance`` apart, less than the radii
    there together (``reach``), both in m."""

    X: float
    X_other: float
    distance: float
    reach: float


def overlap(points, X, radius) -> Overlap | None:
    """The deepest place where a rod of centre line ``points`` (n, 3) at arc lengths ``X``
    (n,), of radius ``radius`` (n,) there, passes through itself, or None. Two parts of the
    rod touch where their centre lines are closer than their radii together; parts that
    follow each other along the rod are always that close, so a point is compared only with
    the rod beyond its distance's first maximum going on along the rod (where the rod has
    turned back towards it; each pair is seen from its first point). Non-finite points are
    left out."""
    P, X, r = (np.asarray(a, float) for a in (points, X, radius))
    n = len(P)
    if n < 3:
        return None
    D = np.linalg.norm(P[:, None, :] - P[None, :, :], axis=-1)
    # row i's first maximum along the rod beyond i: the first j >= i with D[i, j+1] < D[i, j]
    falls = (np.diff(D, axis=1) < 0) & (np.arange(n - 1)[None, :] >= np.arange(n)[:, None])
    beyond = np.arange(n)[None, :] >= np.argmax(falls, axis=1)[:, None]
    gap = D - (r[:, None] + r[None, :])
    gap = np.where(beyond & falls.any(axis=1)[:, None] & np.isfinite(gap), gap, np.inf)
    i, j = np.unravel_index(np.argmin(gap), gap.shape)
    if not gap[i, j] < 0:
        return None
    return Overlap(float(X[i]), float(X[j]), float(D[i, j]), float(r[i] + r[j]))
