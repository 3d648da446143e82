"""Strain bases ``Φξ(X)`` of eq. 5, ``ξ(X) = Φξ(X) q + ξ*``.

A basis is any object with a number of coordinates ``n`` and a call ``basis(X) -> (len(X), 6, n)``
(numpy, evaluated once at fixed points when a model is discretised). :class:`LegendreBasis`
is the paper's; other families plug in behind the same :class:`StrainBasis` protocol.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Protocol

import numpy as np
from numpy.polynomial import legendre

#: strain modes in the order of ξ = [κx, κy, κz, εx, εy, εz]
MODES = ("torsion", "bending_y", "bending_z", "elongation", "shear_y", "shear_z")

#: the paper's default basis: 1 + 5 + 5 + 4 = 15 coordinates
DEFAULT_DEGREES = {"torsion": 0, "bending_y": 4, "bending_z": 4, "elongation": 3}


class StrainBasis(Protocol):
    n: int

    def __call__(self, X: np.ndarray) -> np.ndarray: ...


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

    def __call__(self, X) -> np.ndarray:
        X = np.atleast_1d(np.asarray(X, dtype=float))
        s = 2.0 * X / self.length - 1.0
        Phi = np.zeros((X.size, 6, self.n))
        for mode, sl in self.blocks():
            row = MODES.index(mode)
            Phi[:, row, sl] = legendre.legvander(s, self.degrees[mode])
        return Phi
