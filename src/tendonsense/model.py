"""A robot discretised for computation: the Magnus grid, the basis sampled at its quadrature
points, the stiffness matrix and the indices of disks, markers and point loads on the grid.

Everything here is built once with numpy; the compiled functions close over it as constants.
"""

from __future__ import annotations

from dataclasses import dataclass

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
class TendonGroup:
    """Tendons with the same number of disks, computed together."""

    index: np.ndarray  # (k,) positions in the robot's tendon list
    nodes: np.ndarray  # (k, nd) grid-node index of every disk
    offsets: np.ndarray  # (k, nd, 3) cross-section offsets d_i
    rest_length: np.ndarray  # (k,) l* of eq. 9, the path length on the straight rod


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
    tendon_groups: tuple[TendonGroup, ...]
    marker_nodes: np.ndarray
    marker_offsets: np.ndarray
    load_points: tuple[float, ...]
    load_nodes: np.ndarray
    base: np.ndarray  # 4x4 base pose
    L_inv_unit: np.ndarray  # L⁻¹ with K_unit = L Lᵀ (scales equilibrium residuals)
    length_stiffness_unit: np.ndarray  # (n_t,) ≈ 1 / (bᵀ K_unit⁻¹ b), b = ∂y/∂q at q = 0

    @property
    def nq(self) -> int:
        return self.basis.n

    @property
    def n_tendons(self) -> int:
        return len(self.robot.tendons)

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
        L_inv = np.linalg.inv(np.linalg.cholesky(K))
        # small-strain tendon stretch y ≈ ∫ (εx + κy dz − κz dy) dX, for residual scaling only
        b = np.zeros((basis.n, len(robot.tendons)))
        for j, t in enumerate(robot.tendons):
            d = t.offset(X, L)
            w = np.stack([0 * X, d[:, 2], -d[:, 1], 1 + 0 * X, 0 * X, 0 * X], axis=1)
            b[:, j] = np.einsum("k,kai,ka->i", W, Phi, w)
        k_len = 1.0 / np.maximum(np.sum((L_inv @ b) ** 2, axis=0), 1e-300)

        # gravity: two-point Gauss rule on every interval
        xg2 = np.array([0.5 - _Z, 0.5 + _Z])
        start = np.repeat(np.arange(h.size), 2)
        hsub = (h[:, None] * xg2).ravel()
        gp = _pointset(basis, nodes, start, hsub)
        gw = np.repeat(h / 2, 2) * rod.area(gp.X)

        index = {x: i for i, x in enumerate(nodes)}
        snap = lambda x: index[_nearest(nodes, x)]
        groups = []
        for nd in sorted({len(t.disks) for t in robot.tendons}):
            idx = [i for i, t in enumerate(robot.tendons) if len(t.disks) == nd]
            X = np.array([robot.tendons[i].disks for i in idx])
            d = np.stack([robot.tendons[i].offset(X[k], L) for k, i in enumerate(idx)])
            straight = d + X[..., None] * np.array([1.0, 0.0, 0.0])
            groups.append(TendonGroup(
                np.array(idx), np.vectorize(snap)(X).astype(int), d,
                np.linalg.norm(np.diff(straight, axis=1), axis=2).sum(axis=1)))
        return Model(
            robot=robot, basis=basis, nodes=nodes, Phi1=basis(z1), Phi2=basis(z2), K_unit=K,
            gravity_points=gp, gravity_weights=gw, tendon_groups=tuple(groups),
            marker_nodes=np.array([snap(m.X) for m in robot.markers], int),
            marker_offsets=np.array([m.offset for m in robot.markers], float).reshape(-1, 3),
            load_points=tuple(float(x) for x in load_points),
            load_nodes=np.array([snap(x) for x in load_points], int),
            base=_pose(robot), L_inv_unit=L_inv, length_stiffness_unit=k_len)

    def pointset(self, X) -> PointSet:
        """Arbitrary material points, each reached from the grid node at or below it."""
        X = np.clip(np.atleast_1d(np.asarray(X, float)), 0.0, self.nodes[-1])
        start = np.clip(np.searchsorted(self.nodes, X, side="right") - 1, 0, self.nodes.size - 2)
        return _pointset(self.basis, self.nodes, start, X - self.nodes[start])


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
