"""A robot discretised for computation, split in two: its :class:`Structure` (what shapes the
compiled programs: basis degrees, tendon grouping, solver settings) and its :class:`Values`
(every number, an array pytree passed to those programs at run time).

Two robots with the same structure share every compiled program, whatever their numbers. The
values are built once with numpy; points at a run-time X (markers, point loads, the backbone)
are reached by a partial Magnus step from the grid node below them (:func:`points_at`), so
they are differentiable in X.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .basis import ElementsBasis, LegendreBasis
from .lie import skew
from .robot import Numerics, Robot
from .rod import section

_Z = np.sqrt(3.0) / 6.0  # Zannah / two-point Gauss abscissae at 1/2 -+ sqrt(3)/6


@dataclass(frozen=True)
class Structure:
    """Everything that shapes a compiled program (hashable; the key of every cache).

    Array shapes (numbers of grid nodes, disks, markers, loads) key the programs too, through
    JAX's own tracing; no number of the robot does."""

    degrees: tuple[tuple[str, int], ...]  # Legendre degree per active strain mode
    groups: tuple[tuple[int, ...], ...]  # tendons with the same number of disks
    n_tendons: int
    numerics: Numerics
    n_elements: int = 1  # 1: the paper's global basis; more: an elements basis
    continuous: tuple[int, ...] = ()  # tendons routed continuously along the rod

    def basis(self, X, values: "Values", xp=np):
        """``Φξ(X)`` with the bounds and length of ``values`` (traceable with ``xp=jnp``)."""
        if self.n_elements == 1:
            return LegendreBasis(1.0, dict(self.degrees))(X, values.length, xp)
        return ElementsBasis((0.0,) * (self.n_elements + 1), dict(self.degrees))(
            X, values.element_bounds, xp)

    @cached_property
    def nq(self) -> int:
        return self.n_elements * sum(d + 1 for _, d in self.degrees)


class PointSet(NamedTuple):
    """Material points reached by a partial Magnus step of length ``h`` from grid node
    ``start``; ``Phi1``/``Phi2`` are the basis at that step's two Zannah points."""

    start: jax.Array
    h: jax.Array
    Phi1: jax.Array
    Phi2: jax.Array


class TendonGroup(NamedTuple):
    """Tendons with the same number of disks, computed together."""

    nodes: jax.Array  # (k, nd) grid-node index of every disk
    offsets: jax.Array  # (k, nd, 3) cross-section offsets d_i
    rest_length: jax.Array  # (k,) l* of eq. 9, the path length on the straight rod


class ContinuousTendons(NamedTuple):
    """Tendons along the whole rod at their offsets, at ``m`` Gauss points of every grid
    interval. Their path tangent in the body frame is ``w = ν + ω × d + d′ = A q + c``, linear
    in q, so that the length ``∫ |w| dX`` needs no poses."""

    A: jax.Array  # (k, n_int, m, 3, nq)
    c: jax.Array  # (k, n_int, m, 3), w on the straight rod
    dA: jax.Array  # (k, n_int, m, 3, nq), ∂w′/∂q (d is linear in X: c′ = 0)
    A_ends: jax.Array  # (k, n_int, 2, 3, nq) at both ends of every interval (inside it)
    c_ends: jax.Array  # (k, n_int, 2, 3)
    Omega: jax.Array  # (n_int, m, 3, nq): ω = Omega q at the points
    weights: jax.Array  # (n_int, m) Gauss weights, m
    cumulative: jax.Array  # (m, m) ∫ from an interval's start to point k, per unit length
    rest_length: jax.Array  # (k,) ∫ |c| dX


class Values(NamedTuple):
    """Every number of a discretised robot (a pytree of arrays, traced at run time)."""

    length: jax.Array
    element_bounds: jax.Array  # (n_elements + 1,) from 0 to L
    nodes: jax.Array  # grid abscissae X_0 = 0 < ... < X_n = L
    Phi1: jax.Array  # (n_int, 6, nq) at each interval's first Zannah point
    Phi2: jax.Array
    radius_z: jax.Array  # (n_int, 2) rod radius at the two Zannah points
    K_axial: jax.Array  # eq. 8a with Σ = diag(0, Jy, Jz, A, 0, 0): the part ∝ E
    K_shear: jax.Array  # eq. 8a with Σ = diag(Jx, 0, 0, 0, A, A): the part ∝ G
    stretch_unit: jax.Array  # (nq, n_t) small-strain ∂y/∂q at q = 0 (residual scaling)
    gravity_weights: jax.Array  # (n_int, 4): ∫ A p dX = Σ w · [p_i, p'_i, p_{i+1}, p'_{i+1}]
    stretch_ends: jax.Array  # (n_int, 2, 3, nq) the basis of ν at every interval's two ends
    tendons: tuple[TendonGroup, ...]
    continuous: ContinuousTendons | None
    marker_X: jax.Array  # (n_m,)
    marker_offsets: jax.Array  # (n_m, 3)
    mass_X: jax.Array  # (n_mass,) where the lumped masses sit
    mass_offsets: jax.Array  # (n_mass, 3) its centre in the cross-section frame
    masses: jax.Array  # (n_mass,) kg
    base: jax.Array  # 4x4 base pose
    young_modulus: jax.Array
    poisson_ratio: jax.Array
    density: jax.Array
    damping: jax.Array  # Kelvin–Voigt viscosity η, Pa·s
    friction: jax.Array  # (n_t,) Capstan μ per tendon; signed, per turn (n_t, turns)
    energy_floor: jax.Array  # residual floor per √E (an absolute tolerance)

    @property
    def h(self):
        return self.nodes[1:] - self.nodes[:-1]

    def stiffness(self):
        """``K`` per unit E (eq. 8a, ``G = E / 2(1 + ν)``)."""
        return self.K_axial + self.K_shear / (2.0 * (1.0 + self.poisson_ratio))

    def damping_matrix(self):
        """``D = ∫ Φᵀ Υ Φ dX``, ``Υ = η diag(Jx, 3Jy, 3Jz, 3A, A, A)``: the viscous analogue of
        K for an incompressible material, so that ``D = 3η/E · K`` at ν = 0.5 (the manual's
        *The robot in motion*)."""
        return self.damping * (3.0 * self.K_axial + self.K_shear)


#: values a user may vary at run time by name (:meth:`Model.with_values`, batched solves)
VALUE_NAMES = ("young_modulus", "poisson_ratio", "density", "damping", "friction")


@dataclass(frozen=True, eq=False)
class Model:
    """A robot with its structure and values: ``Model.build(robot)``."""

    robot: Robot
    structure: Structure
    values: Values

    @property
    def nq(self) -> int:
        return self.structure.nq

    @property
    def n_tendons(self) -> int:
        return self.structure.n_tendons

    @staticmethod
    def build(robot: Robot) -> "Model":
        rod, L = robot.rod, robot.rod.length
        bounds = (0.0, *robot.elements, L)
        if robot.elements:
            basis = ElementsBasis(bounds, dict(robot.strain))
            uniform = np.unique(np.concatenate([
                np.linspace(a, b, robot.numerics.steps_per_element + 1)
                for a, b in zip(bounds, bounds[1:])]))
        else:
            basis = LegendreBasis(L, dict(robot.strain))
            uniform = np.linspace(0.0, L, robot.numerics.intervals + 1)
        special = [0.0, L, *rod.breakpoints(), *robot.elements]
        for t in robot.tendons:
            special += list(t.disks)
        nodes = _grid(L, uniform, np.array(special, float))
        h = np.diff(nodes)
        z1, z2 = nodes[:-1] + (0.5 - _Z) * h, nodes[:-1] + (0.5 + _Z) * h

        # eq. 8a: K = ∫ Φᵀ Σ Φ dX, Gauss–Legendre per grid interval (Σ is polynomial in X there)
        xg, wg = np.polynomial.legendre.leggauss(8)
        X = (nodes[:-1, None] + 0.5 * h[:, None] * (xg + 1)).ravel()
        W = (0.5 * h[:, None] * wg).ravel()
        Phi = basis(X)
        r = rod.radius(X)
        A, I = section(r)
        zero = 0 * A
        K_axial = np.einsum("k,kai,ka,kaj->ij", W, Phi, np.stack([zero, I, I, A, zero, zero], 1), Phi)
        K_shear = np.einsum("k,kai,ka,kaj->ij", W, Phi, np.stack([2 * I, zero, zero, zero, A, A], 1),
                            Phi)
        # small-strain tendon stretch y ≈ ∫ (εx + κy dz − κz dy) dX, for residual scaling only
        b = np.zeros((basis.n, len(robot.tendons)))
        for j, t in enumerate(robot.tendons):
            d = t.offset(X, L)
            w = np.stack([zero, d[:, 2], -d[:, 1], 1 + zero, zero, zero], axis=1)
            b[:, j] = np.einsum("k,kai,ka->i", W, Phi, w)

        # gravity (eq. 8b): ∫ ρ A(X) p(X) dX with p cubic Hermite on every interval through the
        # node positions and tangents p' = R ν, weights exact for A(X) (8-point Gauss)
        s = 0.5 * (xg + 1)
        hermite = np.stack([2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s,
                            -2 * s**3 + 3 * s**2, s**3 - s**2], axis=1)  # (8, 4)
        area = rod.area(nodes[:-1, None] + h[:, None] * s)  # (n_int, 8)
        gw = np.einsum("ik,k,kj->ij", area, 0.5 * wg, hermite) * h[:, None]
        gw[:, 1::2] *= h[:, None]  # the tangent terms carry h p'
        ends = np.stack([basis(nodes[:-1]), basis(nodes[1:], side="left")], axis=1)[:, :, 3:]

        groups, tendon_values = [], []
        continuous = tuple(i for i, t in enumerate(robot.tendons) if t.continuous)
        routed = [t for t in robot.tendons if not t.continuous]
        for nd in sorted({len(t.disks) for t in routed}):
            idx = [i for i, t in enumerate(robot.tendons)
                   if len(t.disks) == nd and not t.continuous]
            Xd = np.array([robot.tendons[i].disks for i in idx])
            d = np.stack([robot.tendons[i].offset(Xd[k], L) for k, i in enumerate(idx)])
            straight = d + Xd[..., None] * np.array([1.0, 0.0, 0.0])
            groups.append(tuple(idx))
            tendon_values.append(TendonGroup(
                np.argmin(np.abs(nodes - Xd[..., None]), axis=-1), d,
                np.linalg.norm(np.diff(straight, axis=1), axis=2).sum(axis=1)))
        base = np.eye(4)
        base[:3, :3] = np.array(robot.base_rotation)
        base[:3, 3] = robot.base_position
        r0 = rod.radius_knots[0][1]
        values = Values(
            length=np.float64(L), element_bounds=np.array(bounds, float), nodes=nodes,
            Phi1=basis(z1), Phi2=basis(z2),
            radius_z=np.stack([rod.radius(z1), rod.radius(z2)], axis=1),
            K_axial=K_axial, K_shear=K_shear, stretch_unit=b, gravity_weights=gw,
            stretch_ends=ends, tendons=tuple(tendon_values),
            continuous=_continuous(robot, basis, nodes, continuous) if continuous else None,
            marker_X=np.array([m.X for m in robot.markers], float),
            marker_offsets=np.array([m.offset for m in robot.markers], float).reshape(-1, 3),
            mass_X=np.array([m.X for m in robot.masses], float),
            mass_offsets=np.array([m.offset for m in robot.masses], float).reshape(-1, 3),
            masses=np.array([m.mass for m in robot.masses], float),
            base=base, **material_values(robot),
            energy_floor=np.float64(1e-6 * np.sqrt(r0**4 / L)))
        structure = Structure(tuple(robot.strain), tuple(groups), len(robot.tendons),
                              robot.numerics, len(bounds) - 1, continuous)
        return Model(robot, structure, values)

    def with_values(self, **changes) -> "Model":
        """The same model with other values by name (:data:`VALUE_NAMES`); ``friction`` is one
        μ for every tendon or one per tendon. Reuses every compiled program."""
        for name in changes:
            if name not in VALUE_NAMES:
                raise ValueError(f"{name}: not a value that can be changed (one of "
                                 f"{', '.join(VALUE_NAMES)})")
        v = {k: np.asarray(x, float) for k, x in changes.items()}
        if "friction" in v:
            v["friction"] = np.broadcast_to(v["friction"], np.shape(self.values.friction))
        return Model(self.robot, self.structure, self.values._replace(**v))


def material_values(robot: Robot) -> dict[str, np.ndarray]:
    """The robot's values by name (:data:`VALUE_NAMES`), as :class:`Values` holds them."""
    rod = robot.rod
    return dict(young_modulus=np.float64(rod.young_modulus),
                poisson_ratio=np.float64(rod.poisson_ratio), density=np.float64(rod.density),
                damping=np.float64(rod.damping),
                friction=np.array([t.friction for t in robot.tendons], float).reshape(-1))


def points_at(structure: Structure, values: Values, X, xp=jnp) -> PointSet:
    """Material points at ``X`` (traced, any shape → flat), each reached by a partial Magnus
    step from the grid node at or below it; differentiable in X. ``xp`` numpy: on the host
    (values on the host, :func:`host`; no program to build)."""
    nodes = xp.asarray(values.nodes)
    X = xp.clip(xp.ravel(xp.asarray(X, float)), 0.0, values.length)
    n_int = nodes.shape[0] - 1
    start = xp.clip(xp.searchsorted(nodes, X, side="right") - 1, 0, n_int - 1)
    x0 = nodes[start]
    h = X - x0
    return PointSet(start, h, structure.basis(x0 + (0.5 - _Z) * h, values, xp),
                    structure.basis(x0 + (0.5 + _Z) * h, values, xp))


def host(values: Values) -> Values:
    """``values`` with every array on the host (NumPy): what is computed from them outside a
    program (e.g. :meth:`Values.stiffness`) then builds no program."""
    return jax.tree_util.tree_map(np.asarray, values)


#: Gauss points per grid interval of a continuously routed tendon's path integrals
CONTINUOUS_POINTS = 3


def _continuous(robot: Robot, basis, nodes: np.ndarray, index) -> ContinuousTendons:
    """The path-integral data of the continuously routed tendons ``index``."""
    L, h = robot.rod.length, np.diff(nodes)
    m = CONTINUOUS_POINTS
    xg, wg = np.polynomial.legendre.leggauss(m)
    u = 0.5 * (xg + 1)
    X = nodes[:-1, None] + h[:, None] * u  # (n_int, m)
    n_int, nq = X.shape[0], basis.n
    Phi = basis(X.ravel()).reshape(n_int, m, 6, nq)
    dPhi = basis(X.ravel(), derivative=True).reshape(n_int, m, 6, nq)
    Phi_ends = np.stack([basis(nodes[:-1]), basis(nodes[1:], side="left")], axis=1)
    A, c, dA, A_ends, c_ends = [], [], [], [], []
    for i in index:
        t = robot.tendons[i]
        slope = np.r_[0.0, (np.array(t.offset_tip) - t.offset_base) / L]  # d′
        for Xs, P, out_A, out_c in ((X, Phi, A, c), (np.stack([nodes[:-1], nodes[1:]], 1),
                                                     Phi_ends, A_ends, c_ends)):
            d = t.offset(Xs.ravel(), L).reshape(Xs.shape + (3,))
            out_A.append(P[..., 3:, :] - skew(d) @ P[..., :3, :])  # ν + ω × d
            out_c.append(np.broadcast_to(np.r_[1.0, 0.0, 0.0] + slope, Xs.shape + (3,)))
        d = t.offset(X.ravel(), L).reshape(n_int, m, 3)
        dA.append(dPhi[..., 3:, :] - skew(d) @ dPhi[..., :3, :] - skew(slope) @ Phi[..., :3, :])
    weights = 0.5 * h[:, None] * wg
    # cumulative integration of the interpolant through the m points, on [0, 1]
    V_inv = np.linalg.inv(np.polynomial.legendre.legvander(xg, m - 1))
    cumulative = np.stack([0.5 * np.polynomial.legendre.legval(
        xg, np.polynomial.legendre.legint(V_inv[:, j], lbnd=-1)) for j in range(m)], axis=1)
    c = np.array(c)
    return ContinuousTendons(np.array(A), c, np.array(dA), np.array(A_ends), np.array(c_ends),
                             Phi[..., :3, :], weights, cumulative,
                             np.einsum("im,kim->k", weights, np.linalg.norm(c, axis=-1)))


def _grid(L: float, uniform: np.ndarray, special: np.ndarray) -> np.ndarray:
    """The ``uniform`` grid with every special point inserted; uniform points closer than a
    fifth of their local spacing to a special point give way to it."""
    special = np.unique(np.clip(special, 0.0, L))
    # special points closer than 1e-9 L are one node
    keep = np.concatenate([[True], np.diff(special) > 1e-9 * L])
    special = special[keep]
    spacing = np.diff(uniform)
    local = np.minimum(np.r_[spacing[0], spacing], np.r_[spacing, spacing[-1]])
    d = np.min(np.abs(uniform[:, None] - special[None, :]), axis=1)
    nodes = np.unique(np.concatenate([special, uniform[d > 0.2 * local]]))
    nodes[0], nodes[-1] = 0.0, L
    return nodes
