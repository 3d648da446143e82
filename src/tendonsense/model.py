"""A robot discretised for computation: the Magnus grid, the basis sampled at its quadrature
points, the stiffness matrix and the indices of disks, markers and point loads on the grid.

Everything here is built once with numpy; the compiled functions close over it as constants.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .basis import LegendreBasis
from .robot import Robot

_Z = np.sqrt(3.0) / 6.0  # Zannah / two-point Gauss abscissae at 1/2 -+ sqrt(3)/6


@dataclass(frozen=True, eq=False)
class PointSet:
    """Material points reached by a partial Magnus step of length ``h`` from grid node
    ``start``; ``Phi1``/``Phi2`` are the basis at that step's two Zannah points."""

    X: np.ndarray
    start: np.ndarray
    h: np.ndarray
    Phi1: np.ndarray
    Phi2: np.ndarray


@dataclass(frozen=True, eq=False)
class TendonGrid:
    name: str
    nodes: np.ndarray  # grid-node index of every disk
    offsets: np.ndarray  # (nd, 3) cross-section offsets d_i
    rest_length: float  # l* of eq. 9, the path length of the straight rod


@dataclass(frozen=True, eq=False)
class Model:
    """``Model.build(robot, load_points)``: ``load_points`` are the X of every point load
    (known or unknown) so that they fall on grid nodes."""

    robot: Robot
    basis: LegendreBasis
    nodes: np.ndarray  # grid abscissae X_0 = 0 < ... < X_n = L
    Phi1: np.ndarray  # (n_int, 6, nq) at each interval's first Zannah point
    Phi2: np.ndarray
    K_unit: np.ndarray  # eq. 8a per unit Young's modulus
    gravity_points: PointSet
    gravity_weights: np.ndarray  # quadrature weight x area, so that ∫ρA f dX = ρ Σ w f
    tendons: tuple[TendonGrid, ...]
    marker_nodes: np.ndarray
    marker_offsets: np.ndarray
    load_points: tuple[float, ...]
    load_nodes: np.ndarray
    base: np.ndarray  # 4x4 base pose

    @property
    def nq(self) -> int:
        return self.basis.n

    @property
    def h(self) -> np.ndarray:
        return np.diff(self.nodes)

    @staticmethod
    def build(robot: Robot, load_points=()) -> "Model":
        rod, L = robot.rod, robot.rod.length
        basis = LegendreBasis(L, dict(robot.strain))
        special = [0.0, L, *rod.breakpoints(), *(m.X for m in robot.markers), *load_points]
        for t in robot.tendons:
            special += list(t.disks)
        nodes = _grid(L, robot.numerics.intervals, np.array(special, float))
        h = np.diff(nodes)
        z1, z2 = nodes[:-1] + (0.5 - _Z) * h, nodes[:-1] + (0.5 + _Z) * h

        # eq. 8a: K = ∫ Φᵀ Σ Φ dX, Gauss–Legendre per grid interval (Σ is polynomial in X there)
        xg, wg = np.polynomial.legendre.leggauss(8)
        X = (nodes[:-1, None] + 0.5 * h[:, None] * (xg + 1)).ravel()
        W = (0.5 * h[:, None] * wg).ravel()
        Phi = basis(X)
        S = rod.section_stiffness(X)
        K = np.einsum("k,kai,ka,kaj->ij", W, Phi, S, Phi)

        # gravity: two-point Gauss rule on every interval
        xg2 = np.array([0.5 - _Z, 0.5 + _Z])
        start = np.repeat(np.arange(h.size), 2)
        hsub = (h[:, None] * xg2).ravel()
        gp = _pointset(basis, nodes, start, hsub)
        gw = np.repeat(h / 2, 2) * rod.area(gp.X)

        index = {x: i for i, x in enumerate(nodes)}
        snap = lambda x: index[_nearest(nodes, x)]
        tendons = []
        for t in robot.tendons:
            X = np.array(t.disks)
            d = t.offset(X, L)
            straight = d + X[:, None] * np.array([1.0, 0.0, 0.0])
            tendons.append(TendonGrid(t.name, np.array([snap(x) for x in X]), d,
                                      float(np.linalg.norm(np.diff(straight, axis=0), axis=1).sum())))
        return Model(
            robot=robot, basis=basis, nodes=nodes, Phi1=basis(z1), Phi2=basis(z2), K_unit=K,
            gravity_points=gp, gravity_weights=gw, tendons=tuple(tendons),
            marker_nodes=np.array([snap(m.X) for m in robot.markers], int),
            marker_offsets=np.array([m.offset for m in robot.markers], float).reshape(-1, 3),
            load_points=tuple(float(x) for x in load_points),
            load_nodes=np.array([snap(x) for x in load_points], int),
            base=_pose(robot))

    def pointset(self, X) -> PointSet:
        """Arbitrary material points, each reached from the grid node at or below it."""
        X = np.clip(np.atleast_1d(np.asarray(X, float)), 0.0, self.nodes[-1])
        start = np.clip(np.searchsorted(self.nodes, X, side="right") - 1, 0, self.nodes.size - 2)
        return _pointset(self.basis, self.nodes, start, X - self.nodes[start])

    @cached_property
    def K_cholesky(self) -> np.ndarray:
        """Lower Cholesky factor of ``K_unit`` (used to scale equilibrium residuals)."""
        return np.linalg.cholesky(self.K_unit)


def _pose(robot: Robot) -> np.ndarray:
    g = np.eye(4)
    g[:3, :3] = np.array(robot.base_rotation)
    g[:3, 3] = robot.base_position
    return g


def _pointset(basis, nodes, start, hsub) -> PointSet:
    x0 = nodes[start]
    return PointSet(X=x0 + hsub, start=np.asarray(start, int), h=np.asarray(hsub, float),
                    Phi1=basis(x0 + (0.5 - _Z) * hsub), Phi2=basis(x0 + (0.5 + _Z) * hsub))


def _nearest(nodes, x):
    return nodes[int(np.argmin(np.abs(nodes - x)))]


def _grid(L: float, n: int, special: np.ndarray) -> np.ndarray:
    """Uniform grid of n intervals with every special point inserted; uniform points closer
    than a fifth of an interval to a special point give way to it."""
    special = np.unique(np.clip(special, 0.0, L))
    # special points closer than 1e-9 L are one node
    keep = np.concatenate([[True], np.diff(special) > 1e-9 * L])
    special = special[keep]
    uniform = np.linspace(0.0, L, n + 1)
    d = np.min(np.abs(uniform[:, None] - special[None, :]), axis=1)
    nodes = np.unique(np.concatenate([special, uniform[d > 0.2 * L / n]]))
    nodes[0], nodes[-1] = 0.0, L
    return nodes
