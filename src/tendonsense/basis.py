"""Strain bases ``Φξ(X)`` of eq. 5, ``ξ(X) = Φξ(X) q + ξ*``.

Two families, each a frozen description with a number of coordinates ``n`` and a call
``basis(X, <length or element bounds>, xp, side, derivative) -> (len(X), 6, n)`` (NumPy, or
traced with ``xp=jax.numpy`` at run-time points and dimensions): :class:`LegendreBasis`, the
paper's one polynomial block per mode over the rod, and :class:`ElementsBasis`, one block per
element between given cuts. :meth:`tendonsense.model.Structure.basis` picks the robot's.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

#: strain modes in the order of ξ = [κx, κy, κz, εx, εy, εz]
MODES = ("torsion", "bending_y", "bending_z", "elongation", "shear_y", "shear_z")

#: the paper's default basis: 1 + 5 + 5 + 4 = 15 coordinates
DEFAULT_DEGREES = {"torsion": 0, "bending_y": 4, "bending_z": 4, "elongation": 3}


@dataclass(frozen=True)
class LegendreBasis:
    """One block of Legendre polynomials ``P_0..P_n(s)``, ``s = 2X/L - 1``, per active mode.

    ``degrees`` maps mode name -> degree; modes left out are held rigid.
    """

    length: float
    degrees: Mapping[str, int]

    @property
    def n(self) -> int:
        return sum(d + 1 for d in self.degrees.values())

    def blocks(self) -> list[tuple[str, slice]]:
        """(mode, slice of q) for every active mode, in ξ order."""
        out, start = [], 0
        for mode in MODES:
            if mode in self.degrees:
                k = self.degrees[mode] + 1
                out.append((mode, slice(start, start + k)))
                start += k
        return out

    def __call__(self, X, length=None, xp=np, side="right", derivative=False):
        """``Φξ(X)``, shape (len(X), 6, n); with ``xp=jax.numpy`` X and ``length`` may be traced
        (a point at a run-time X, differentiable in X). ``side`` is that of
        :meth:`ElementsBasis.__call__` (one element here: no effect); ``derivative`` gives
        ``dΦξ/dX`` instead."""
        X = xp.atleast_1d(xp.asarray(X, dtype=float))
        L = self.length if length is None else length
        s = 2.0 * X / L - 1.0
        K = max(self.degrees.values(), default=0) + 1
        P = [xp.ones_like(s), s]  # Bonnet: (k+1) P_{k+1} = (2k+1) s P_k − k P_{k−1}
        for k in range(1, K - 1):
            P.append(((2 * k + 1) * s * P[k] - k * P[k - 1]) / (k + 1))
        if derivative:  # P′_{k+1} = P′_{k−1} + (2k + 1) P_k, times ds/dX = 2 / L
            dP = [xp.zeros_like(s), xp.ones_like(s)]
            for k in range(1, K - 1):
                dP.append(dP[k - 1] + (2 * k + 1) * P[k])
            P = [p * (2.0 / L) for p in dP]
        # P_k placed in its modes' columns: one product (a small program where X is traced)
        return xp.einsum("xk,kin->xin", xp.stack(P[:K], axis=-1), self._placement())

    def _placement(self) -> np.ndarray:
        """(K, 6, n): 1 where coordinate j is the degree-k polynomial of mode i."""
        M = np.zeros((max(self.degrees.values(), default=0) + 1, 6, self.n))
        for mode, sl in self.blocks():
            i = MODES.index(mode)
            for k in range(sl.stop - sl.start):
                M[k, i, sl.start + k] = 1.0
        return M


@dataclass(frozen=True)
class ElementsBasis:
    """A piecewise basis: the rod split at ``bounds`` (X_0 = 0 < ... < X_m = L) into elements,
    each with its own :class:`LegendreBasis` block per active mode in its local coordinate,
    no continuity imposed where elements meet (the strain may jump at a disk). Coordinates are
    ordered element by element. A point on a boundary belongs to the element after it (the
    last point, X = L, to the last element), or with ``side="left"`` to the one before it."""

    bounds: tuple[float, ...]
    degrees: Mapping[str, int]

    @property
    def n_elements(self) -> int:
        return len(self.bounds) - 1

    @property
    def n(self) -> int:
        return self.n_elements * sum(d + 1 for d in self.degrees.values())

    def __call__(self, X, bounds=None, xp=np, side="right", derivative=False):
        """``Φξ(X)`` (or ``dΦξ/dX`` with ``derivative``), shape (len(X), 6, n); with
        ``xp=jax.numpy``, X and ``bounds`` may be traced."""
        X = xp.atleast_1d(xp.asarray(X, dtype=float))
        b = xp.asarray(self.bounds if bounds is None else bounds, dtype=float)
        k = xp.clip(xp.searchsorted(b, X, side=side) - 1, 0, self.n_elements - 1)
        a, c = b[k], b[k + 1]
        local = LegendreBasis(1.0, self.degrees)((X - a) / (c - a), 1.0, xp,
                                                 derivative=derivative)
        if derivative:
            local = local / (c - a)[:, None, None]
        one_hot = (k[:, None] == xp.arange(self.n_elements)[None, :]).astype(float)
        blocks = one_hot[:, None, :, None] * local[:, :, None, :]
        return blocks.reshape(X.shape[0], 6, self.n)
