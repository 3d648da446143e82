"""Statics ``K q = B(q) T + F(q)`` (eq. 7) and the one solver behind every problem.

Forward statics, forward kinematics (eq. 16) and square estimation (eq. 17) are the same
system: unknowns ``x = [q; z]`` where ``z`` enters the tensions and loads linearly, and the
equations are equilibrium plus ``y_j(q) = y_j^meas`` for the measured tendons. It is solved by
Newton's method with the exact (forward-mode autodiff) Jacobian and an Armijo line search;
when the full load fails, adaptive load continuation from the straight rod takes over, inside
the same compiled program and within a bounded number of evaluations.

Every compiled program is keyed by the model's :class:`~tendonsense.model.Structure` (and the
measured tendons and number of unknowns); every number is an input at run time.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from . import linalg, loads, tendons
from .compiled import Program
from .kinematics import configuration, poses, positions
from .model import VALUE_NAMES, Structure, Values, points_at

#: compiled programs kept per kind (each keyed by structure); older ones are released
CACHE_SIZE = 16

#: points along the rod at which results report the backbone
BACKBONE_POINTS = 101


class Drive(NamedTuple):
    """Known inputs; tensions, forces, gravity and targets are scaled together by the
    continuation parameter."""

    tensions: jax.Array  # (n_t,)
    forces: jax.Array  # (n_p, 3), global
    load_X: jax.Array  # (n_p,) where the point loads act, m
    gravity: jax.Array  # (3,) acceleration
    targets: jax.Array  # (n_m,) measured tendon length changes


#: inputs of a solve that :func:`derivatives` differentiates by name, besides the values
DRIVE_NAMES = ("tensions", "forces", "load_X", "gravity", "targets")


class Unknowns(NamedTuple):
    """How the extra unknowns z enter: tensions ``T += A z``, forces ``F += Σ z_k F_k``,
    gravity ``a += Σ z_k a_k``; the last ``n_loc`` of them move where the point loads act,
    ``X += Σ z_k P_k``."""

    tensions: jax.Array  # (n_t, n_z)
    forces: jax.Array  # (n_z, n_p, 3)
    gravity: jax.Array  # (n_z, 3)
    positions: jax.Array  # (n_loc, n_p)

    @staticmethod
    def none(n_tendons: int, n_loads: int = 0, n_z: int = 0) -> "Unknowns":
        return Unknowns(np.zeros((n_tendons, n_z)), np.zeros((n_z, n_loads, 3)),
                        np.zeros((n_z, 3)), np.zeros((0, n_loads)))


class Terms(NamedTuple):
    """The parts of eq. 7 at one configuration."""

    grid: jax.Array  # poses at the grid nodes (n_nodes, 4, 4)
    B: jax.Array | None  # (nq, n_t), eq. 14 (None unless asked for)
    y: jax.Array  # (n_t,), eq. 9
    tensions: jax.Array
    load: jax.Array  # B(q) T + F(q), eq. 7 and 8b


def terms(structure: Structure, values: Values, q, z, drive: Drive, unknowns: Unknowns,
          lam, actuation: bool = False) -> Terms:
    """Every generalized force is one pull-back of forces through the poses
    (:func:`~tendonsense.kinematics.configuration`), so that its exact Jacobian (forward mode
    through the pull-back) costs O(nq) passes, not O(nq²) body Jacobians. ``B`` is formed only
    with ``actuation`` (else None: a program that does not use it does not trace it)."""
    t, actuation_matrix = _terms(structure, values, q, z, drive, unknowns, lam)
    return t._replace(B=actuation_matrix()) if actuation else t


def _terms(structure, values, q, z, drive, unknowns, lam):
    """:func:`terms` without ``B``, and a function that forms it from the same pull-back."""
    T = lam * drive.tensions + unknowns.tensions @ z
    a = lam * drive.gravity + z @ unknowns.gravity
    n_loc = unknowns.positions.shape[0]
    X = drive.load_X + z[z.shape[0] - n_loc:] @ unknowns.positions if n_loc else drive.load_X
    sets = [points_at(structure, values, X)] if drive.load_X.shape[0] else []
    if values.masses.shape[0]:
        sets.append(points_at(structure, values, values.mass_X))

    (grid, nu, *points), pull = configuration(values, q, *sets)
    unit = tendons.unit_wrenches(structure, values, grid, values.friction)
    weight, weight_nu = loads.gravity(values, grid, nu, a)  # eq. 8b
    at_points = []
    if drive.load_X.shape[0]:
        at_points.append(loads.point_forces(
            points[0], lam * drive.forces + jnp.tensordot(z, unknowns.forces, axes=1)))
    if values.masses.shape[0]:
        at_points.append(loads.lumped_masses(values, points[-1], a))
    load = pull((jnp.tensordot(T, unit, axes=1) + weight, weight_nu, *at_points))
    if structure.continuous:
        continuous = tendons.continuous_actuation(structure, values, q, values.friction)
        load = load + continuous @ T

    def actuation_matrix():  # eq. 14: each tendon's unit wrenches pulled back
        zeros = [jnp.zeros_like(nu), *(jnp.zeros_like(w) for w in at_points)]
        B = jax.vmap(lambda w: pull((w, *zeros)))(unit).T
        return B + continuous if structure.continuous else B

    return (Terms(grid, None, tendons.length_changes(structure, values, grid, q), T, load),
            actuation_matrix)


class Scaling(NamedTuple):
    """Residual scaling: ``L⁻¹`` with ``K = L Lᵀ`` and the measured tendons' length stiffness
    ``√k ≈ 1 / ‖L⁻¹ b‖`` (b = ∂y/∂q at q = 0), both in √J."""

    L_inv: jax.Array
    root_k: jax.Array


def scaling(values: Values, measured: tuple[int, ...]) -> Scaling:
    L_inv = linalg.lower_inverse(linalg.cholesky(values.stiffness()))
    b = values.stretch_unit[:, np.array(measured, int)]
    root_k = 1.0 / jnp.maximum(jnp.linalg.norm(L_inv @ b, axis=0), 1e-150)
    E = jnp.sqrt(values.young_modulus)
    return Scaling(L_inv / E, root_k * E)


def residual(structure: Structure, values: Values, measured: tuple[int, ...], x, drive,
             unknowns, lam, sc: Scaling, with_actuation: bool | Callable = False):
    """Scaled residual ``[L⁻¹(Kq − BT − F); √k (y − y_meas)]`` (both parts in √J) and the size
    of the load in the same norm; with ``with_actuation`` also ``∂r/∂T`` (the residual is
    linear in the tensions). ``with_actuation`` may be a predicate ``(r, load size) -> bool``
    (traced): ``∂r/∂T`` is then formed only where it holds, zeros elsewhere."""
    nq = structure.nq
    q, z = x[:nq], x[nq:]
    t, actuation_matrix = _terms(structure, values, q, z, drive, unknowns, lam)
    load = t.load
    E = sc.L_inv @ (values.young_modulus * (values.stiffness() @ q) - load)  # eq. 7
    sel = np.array(measured, int)
    e = sc.root_k * (t.y[sel] - lam * drive.targets)
    out = jnp.concatenate([E, e]), jnp.linalg.norm(sc.L_inv @ load)
    if with_actuation is False:
        return out

    def dr_dT():
        B = actuation_matrix()
        return jnp.concatenate([-lam * (sc.L_inv @ B), jnp.zeros((sel.size, B.shape[1]))])

    if with_actuation is True:
        return (*out, dr_dT())
    return (*out, jax.lax.cond(with_actuation(*out), dr_dT,
                               lambda: jnp.zeros((out[0].size, t.tensions.size))))


class NewtonResult(NamedTuple):
    x: jax.Array
    converged: jax.Array
    iterations: jax.Array  # accepted Newton steps, continuation stages included
    residual: jax.Array  # ‖r‖ / (load size + floor)
    evaluations: jax.Array  # residual + Jacobian evaluations
    jacobian: jax.Array | None = None  # of the scaled residual at x (the last accepted point)
    level: jax.Array | None = None  # the share of the load solved (1 converged; continuation)
    stopped: jax.Array | None = None  # where the loop stopped, at any load level (x converged)


def _merit(r):
    m = 0.5 * jnp.dot(r, r)
    return jnp.where(jnp.isfinite(m), m, jnp.inf)


def default_budget(numerics) -> int:
    """Residual + Jacobian evaluations a solve may take, continuation included."""
    return 10 * numerics.max_iterations


@lru_cache(maxsize=CACHE_SIZE)
def newton_solver(structure: Structure, measured: tuple[int, ...], n_z: int):
    """Compiled solver for the system with tendons ``measured`` and ``n_z`` unknowns:
    ``solve(x0, drive, unknowns, values, budget) -> NewtonResult``.

    One loop whose every pass evaluates the residual and its Jacobian at a trial point
    ``x + α dx`` at the load level ``λ``: accepted (Armijo on ½‖r‖²) it becomes the iterate
    and gives the next Newton step, rejected it halves α. A level whose Newton iteration fails
    (α underflows or ``max_iterations`` evaluations) falls back: the full load from ``x0`` to
    continuation from the straight rod at λ = 1/4, a continuation step to half its size.
    Every pass counts against ``budget`` evaluations. The result is the last point accepted at
    the full load, with its residual: the solution, or where the solver stopped.
    """
    num = structure.numerics

    def solve(x0, drive, unknowns, values, budget):
        sc = scaling(values, measured)
        floor = values.energy_floor * jnp.sqrt(values.young_modulus)

        def linearise(x, lam):  # (J, (r, load size)), one residual evaluation
            def with_aux(x):
                out = residual(structure, values, measured, x, drive, unknowns, lam, sc)
                return out[0], out
            return jax.jacfwd(with_aux, has_aux=True)(x)

        def restart(st, x, lam_good, target, dlam, phase):
            return dict(st, x=x, x_good=x, lam_good=lam_good, target=target, dlam=dlam,
                        phase=phase, m=jnp.asarray(jnp.inf), dx=jnp.zeros_like(x),
                        alpha=jnp.asarray(1.0), it=jnp.asarray(-1), level_evals=jnp.asarray(0))

        def cond(st):
            return (st["status"] == 0) & (st["evals"] < budget)

        def body(st):
            xt = st["x"] + st["alpha"] * st["dx"]
            Jt, (rt, load_t) = linearise(xt, st["target"])
            ok = jnp.isfinite(_merit(rt)) & (_merit(rt) <= (1 - 2e-4 * st["alpha"]) * st["m"])
            conv = ok & (jnp.linalg.norm(rt) <= num.tolerance * (load_t + floor))
            accepted = dict(st, x=xt, r=rt, J=Jt, load=load_t, m=_merit(rt),
                            dx=linalg.solve(Jt, -rt), alpha=jnp.asarray(1.0),
                            it=st["it"] + 1, total=st["total"] + 1)
            rejected = dict(st, alpha=st["alpha"] / 2)
            new = jax.tree_util.tree_map(lambda a, b: jnp.where(ok, a, b), accepted, rejected)
            new["evals"] = st["evals"] + 1
            new["level_evals"] = st["level_evals"] + 1
            # the last point accepted at the full load: the result (a solution, or where the
            # solver stopped; a restart's straight rod and a partial level's iterates are not)
            full = ok & (st["target"] >= 1.0)
            new["x_full"] = jnp.where(full, xt, st["x_full"])
            new["J_full"] = jnp.where(full, Jt, st["J_full"])
            new["residual_full"] = jnp.where(full, jnp.linalg.norm(rt) / (load_t + floor),
                                             st["residual_full"])
            failed = ~conv & ((new["level_evals"] >= num.max_iterations)
                              | (~ok & ((new["alpha"] < 2.0**-40) | (st["it"] < 0))))
            done = conv & (st["target"] >= 1.0)
            # a level reached below full load: the next one, a larger step
            dlam_up = jnp.minimum(0.5, 1.5 * st["dlam"])
            up = restart(new, xt, st["target"], jnp.minimum(1.0, st["target"] + dlam_up),
                         dlam_up, st["phase"])
            # a level failed: continuation from the straight rod, or a smaller step
            dlam_down = jnp.where(st["phase"] == 0, 0.25, st["dlam"] / 2)
            lam_from = jnp.where(st["phase"] == 0, 0.0, st["lam_good"])
            x_from = jnp.where(st["phase"] == 0, jnp.zeros_like(xt), st["x_good"])
            down = restart(new, x_from, lam_from, lam_from + dlam_down, dlam_down, 1)
            down["status"] = jnp.where(dlam_down < 1e-3, 2, 0)
            pick = lambda a, b, c: jnp.where(conv & ~done, a, jnp.where(failed, b, c))  # noqa: E731
            out = jax.tree_util.tree_map(pick, up, down, new)
            out["status"] = jnp.where(done, 1, out["status"])
            return out

        n = x0.shape[0]
        st = dict(r=jnp.zeros(n), J=jnp.zeros((n, n)), load=jnp.asarray(0.0),
                  total=jnp.asarray(0),
                  evals=jnp.asarray(0), status=jnp.asarray(0), x_full=x0,
                  J_full=jnp.zeros((n, n)), residual_full=jnp.asarray(jnp.inf))
        st = restart(st, x0, jnp.asarray(0.0), jnp.asarray(1.0), jnp.asarray(0.25),
                     jnp.asarray(0))
        st = jax.lax.while_loop(cond, body, st)
        return NewtonResult(st["x_full"], st["status"] == 1, st["total"],
                            st["residual_full"], st["evals"], st["J_full"],
                            jnp.where(st["status"] == 1, 1.0, st["lam_good"]), st["x"])

    return Program(solve, "newton", (structure, measured, n_z))


def solve_system(structure: Structure, values: Values, measured: tuple[int, ...],
                 drive: Drive, unknowns: Unknowns, x0=None, budget: int | None = None
                 ) -> NewtonResult:
    """Newton from ``x0`` (default: the straight rod; a warm start may give q alone), load
    continuation from the straight rod if the full load fails, within ``budget`` evaluations
    (default :func:`default_budget`)."""
    n_z = unknowns.gravity.shape[0]
    solver = newton_solver(structure, tuple(measured), n_z)
    zero = np.zeros(structure.nq + n_z)
    if x0 is None:
        x0 = zero
    else:
        x0 = np.asarray(x0, float)
        x0 = np.concatenate([x0, zero[x0.size:]]) if x0.size == structure.nq else x0
    budget = default_budget(structure.numerics) if budget is None else budget
    return solver(x0, drive, unknowns, values, np.asarray(budget, np.int64))


def admissible(values: Values, q):
    """Whether the strain stays in the model's range: every fibre keeps a positive stretch,
    ``1 + εx − r √(κy² + κz²) > 0`` at every grid point (a fibre at distance r from the centre
    line on the inside of the bend). A solution outside it would need the rod to compress to
    nothing: equilibrium may hold numerically, but it is no state of the material."""
    xi = jnp.stack([values.Phi1 @ q, values.Phi2 @ q], axis=1) + jnp.asarray([0, 0, 0, 1.0, 0, 0])
    fibre = xi[..., 3] - values.radius_z * jnp.sqrt(xi[..., 1] ** 2 + xi[..., 2] ** 2)
    return jnp.all(fibre > 0) & jnp.all(jnp.isfinite(q))


@lru_cache(maxsize=CACHE_SIZE)
def _outputs_fn(structure: Structure):
    def out(values, q):
        backbone = points_at(structure, values,
                             jnp.linspace(0.0, values.length, BACKBONE_POINTS))
        markers = points_at(structure, values, values.marker_X)
        grid, bb, mk = poses(values, q, backbone, markers)
        return (positions(mk, values.marker_offsets), positions(bb),
                tendons.length_changes(structure, values, grid, q), admissible(values, q))

    return Program(out, "outputs", structure)


def shape_outputs(structure: Structure, values: Values, q):
    """Marker positions (n_m, 3), backbone (101, 3), tendon length changes and whether the
    strain is :func:`admissible` at q."""
    return tuple(np.asarray(a) for a in _outputs_fn(structure)(values, np.asarray(q, float)))


def preload_outputs(structure: Structure, values: Values) -> None:
    """:func:`shape_outputs`' program loaded from disk on another thread, ahead of its first
    call (:meth:`~tendonsense.compiled.Program.preload`)."""
    _outputs_fn(structure).preload(values, np.zeros(structure.nq))


def marker_positions(structure: Structure, values: Values, q):
    """Marker positions (n_m, 3) at q, traceable (differentiable in q and in the values)."""
    _, mk = poses(values, q, points_at(structure, values, values.marker_X))
    return positions(mk, values.marker_offsets)


@lru_cache(maxsize=CACHE_SIZE)
def _derivatives_fn(structure: Structure, measured: tuple[int, ...], wrt: tuple[str, ...]):
    def jac(x, drive, unknowns, values):
        sc = scaling(values, measured)

        def r(x, theta):
            v = values._replace(**{k: theta[k] for k in theta if k in VALUE_NAMES})
            d = drive._replace(**{k: theta[k] for k in theta if k in DRIVE_NAMES})
            return residual(structure, v, measured, x, d, unknowns, 1.0, sc)[0]

        theta = {k: getattr(values, k) if k in VALUE_NAMES else getattr(drive, k) for k in wrt}
        Rx, Rt = jax.jacfwd(r, argnums=(0, 1))(x, theta)
        flat = {k: v.reshape(x.size, -1) for k, v in Rt.items()}
        sol = -linalg.solve(Rx, jnp.concatenate(list(flat.values()), axis=1))
        cut = np.cumsum([v.shape[1] for v in flat.values()])[:-1]
        return {k: s.reshape(Rt[k].shape) for k, s in zip(flat, jnp.split(sol, cut, axis=1))}

    return Program(jac, "derivatives", (structure, measured, wrt))


def derivatives(structure: Structure, values: Values, measured: tuple[int, ...], x,
                drive: Drive, unknowns: Unknowns, wrt) -> dict[str, np.ndarray]:
    """``dx/dθ`` at an equilibrium ``x`` by implicit differentiation, ``−R_x⁻¹ ∂R/∂θ``, for
    every name θ in ``wrt``: values (:data:`~tendonsense.model.VALUE_NAMES`) or drive inputs
    (:data:`DRIVE_NAMES`). Each entry has shape ``(len(x), *shape of θ)``."""
    wrt = tuple(wrt)
    for k in wrt:
        if k not in VALUE_NAMES + DRIVE_NAMES:
            raise ValueError(f"{k}: cannot differentiate with respect to it (one of "
                             f"{', '.join(VALUE_NAMES + DRIVE_NAMES)})")
    out = _derivatives_fn(structure, tuple(measured), wrt)(jnp.asarray(x), drive, unknowns,
                                                           values)
    return {k: np.asarray(v) for k, v in out.items()}
