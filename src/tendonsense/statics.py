"""Statics ``K q = B(q) T + F(q)`` (eq. 7) and the one solver behind every problem.

Forward statics, forward kinematics (eq. 16) and square estimation (eq. 17) are the same
system: unknowns ``x = [q; z]`` where ``z`` enters the tensions and loads linearly, and the
equations are equilibrium plus ``y_j(q) = y_j^meas`` for the measured tendons. It is solved by
Newton's method with the exact (forward-mode autodiff) Jacobian and an Armijo line search,
compiled whole; load continuation from the straight rod takes over when the full load fails.
"""

from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from . import loads, tendons
from .kinematics import Frames, grid_frames, positions
from .model import Model


class Params(NamedTuple):
    """Material parameters that identification may vary."""

    young_modulus: jax.Array
    density: jax.Array
    friction: jax.Array  # (n_t,)

    @staticmethod
    def of(model: Model) -> "Params":
        r = model.robot
        return Params(jnp.asarray(r.rod.young_modulus), jnp.asarray(r.rod.density),
                      jnp.asarray([t.friction for t in r.tendons], float).reshape(-1))


class Drive(NamedTuple):
    """Known inputs, all scaled together by the continuation parameter."""

    tensions: jax.Array  # (n_t,)
    forces: jax.Array  # (n_p, 3), global, at model.load_points
    gravity: jax.Array  # (3,) acceleration
    targets: jax.Array  # (n_m,) measured tendon length changes


class Unknowns(NamedTuple):
    """How the extra unknowns z enter: tensions ``T += A z``, forces ``F += Σ z_k F_k``,
    gravity ``a += Σ z_k a_k``."""

    tensions: jax.Array  # (n_t, n_z)
    forces: jax.Array  # (n_z, n_p, 3)
    gravity: jax.Array  # (n_z, 3)

    @staticmethod
    def none(model: Model, n_z: int = 0) -> "Unknowns":
        return Unknowns(jnp.zeros((model.n_tendons, n_z)),
                        jnp.zeros((n_z, len(model.load_points), 3)), jnp.zeros((n_z, 3)))


class Terms(NamedTuple):
    """The parts of eq. 7 at one configuration."""

    grid: Frames
    B: jax.Array  # (nq, n_t), eq. 14
    y: jax.Array  # (n_t,), eq. 9
    tensions: jax.Array
    external: jax.Array  # F(q) of eq. 8b


def terms(model: Model, q, z, drive: Drive, unknowns: Unknowns, params: Params, lam) -> Terms:
    grid, gp = grid_frames(model, q, model.gravity_points)
    B = tendons.actuation(model, grid, params.friction)
    T = lam * drive.tensions + unknowns.tensions @ z
    F = lam * drive.forces + jnp.tensordot(z, unknowns.forces, axes=1)
    a = lam * drive.gravity + z @ unknowns.gravity
    at_loads = Frames(grid.g[model.load_nodes], grid.J[model.load_nodes])
    external = (loads.point_forces(at_loads, F)
                + loads.gravity(gp, jnp.asarray(model.gravity_weights), params.density, a))
    return Terms(grid, B, tendons.length_changes(model, grid), T, external)


def residual(model: Model, measured: tuple[int, ...], x, drive, unknowns, params, lam,
             with_actuation: bool = False):
    """Scaled residual ``[L⁻¹(Kq − BT − F); √k (y − y_meas)]`` (K = LLᵀ, k the tendons'
    length stiffness: both parts in √J) and the size of the load in the same norm; with
    ``with_actuation`` also ``∂r/∂T`` (the residual is linear in the tensions)."""
    nq = model.nq
    q, z = x[:nq], x[nq:]
    t = terms(model, q, z, drive, unknowns, params, lam)
    L_inv = jnp.asarray(model.L_inv_unit) / jnp.sqrt(params.young_modulus)
    load = t.B @ t.tensions + t.external
    E = L_inv @ (params.young_modulus * (jnp.asarray(model.K_unit) @ q) - load)
    sel = np.array(measured, int)
    k = jnp.sqrt(params.young_modulus * model.length_stiffness_unit[sel])
    e = k * (t.y[sel] - lam * drive.targets)
    out = jnp.concatenate([E, e]), jnp.linalg.norm(L_inv @ load)
    if with_actuation:
        dr_dT = jnp.concatenate([-lam * (L_inv @ t.B), jnp.zeros((sel.size, t.B.shape[1]))])
        return (*out, dr_dT)
    return out


class NewtonResult(NamedTuple):
    x: jax.Array
    converged: jax.Array
    iterations: jax.Array
    residual: jax.Array  # ‖r‖ / (load size + floor)


@lru_cache(maxsize=None)
def newton_solver(model: Model, measured: tuple[int, ...], n_z: int):
    """Compiled damped Newton for the system with tendons ``measured`` and ``n_z`` unknowns:
    ``solve(x0, drive, unknowns, params, lam) -> NewtonResult``.

    One loop whose every pass evaluates the residual and its Jacobian at a trial point
    ``x + α dx``: accepted (Armijo on ½‖r‖²) it becomes the iterate and gives the next Newton
    step, rejected it halves α.
    """
    num = model.robot.numerics
    r0 = model.robot.rod.radius_knots[0][1]
    floor_unit = 1e-6 * np.sqrt(r0**4 / model.robot.rod.length)  # energy floor per √E

    def solve(x0, drive, unknowns, params, lam):
        args = (drive, unknowns, params, lam)
        floor = floor_unit * jnp.sqrt(params.young_modulus)

        def linearise(x):
            f = lambda x: residual(model, measured, x, *args)  # noqa: E731
            return jax.jacfwd(lambda x: (f(x)[0], f(x)), has_aux=True)(x)

        def merit(r):
            m = 0.5 * jnp.dot(r, r)
            return jnp.where(jnp.isfinite(m), m, jnp.inf)

        def cond(st):
            return (st["status"] == 0) & (st["it"] < num.max_iterations)

        def body(st):
            xt = st["x"] + st["alpha"] * st["dx"]
            Jt, (rt, st_load) = linearise(xt)
            ok = merit(rt) <= (1 - 2e-4 * st["alpha"]) * st["m"]
            conv = jnp.linalg.norm(rt) <= num.tolerance * (st_load + floor)
            dx_new = jnp.linalg.solve(Jt, -rt)
            accept = dict(x=xt, r=rt, load=st_load, m=merit(rt), dx=dx_new, alpha=1.0,
                          it=st["it"] + 1, status=jnp.where(conv, 1, 0))
            give_up = st["alpha"] < 2.0**-40
            reject = dict(st, alpha=st["alpha"] / 2, status=jnp.where(give_up, 2, 0))
            return jax.tree_util.tree_map(lambda a, b: jnp.where(ok, a, b), accept, reject)

        n = x0.shape[0]
        st = dict(x=x0, r=jnp.zeros(n), load=jnp.asarray(0.0), m=jnp.asarray(jnp.inf),
                  dx=jnp.zeros(n), alpha=jnp.asarray(1.0), it=jnp.asarray(-1),
                  status=jnp.asarray(0))
        st = jax.lax.while_loop(cond, body, st)
        return NewtonResult(st["x"], st["status"] == 1, st["it"],
                            jnp.linalg.norm(st["r"]) / (st["load"] + floor))

    return jax.jit(solve)


def solve_system(model: Model, measured: tuple[int, ...], drive: Drive, unknowns: Unknowns,
                 params: Params, x0=None) -> NewtonResult:
    """Newton from ``x0`` (default: the straight rod); if the full load fails, load
    continuation from the unloaded straight rod with adaptive steps."""
    n_z = unknowns.gravity.shape[0]
    solver = newton_solver(model, tuple(measured), n_z)
    zero = jnp.zeros(model.nq + n_z)
    if x0 is None:
        x0 = zero
    else:  # a warm start may give q alone
        x0 = jnp.asarray(x0, float)
        x0 = jnp.concatenate([x0, zero[x0.size:]]) if x0.size == model.nq else x0
    res = solver(x0, drive, unknowns, params, 1.0)
    if bool(res.converged):
        return res
    total = int(res.iterations)
    lam, x, dlam = 0.0, zero, 0.25
    while lam < 1.0:
        target = min(1.0, lam + dlam)
        r = solver(x, drive, unknowns, params, target)
        total += int(r.iterations)
        if bool(r.converged):
            lam, x, dlam = target, r.x, min(0.5, dlam * 1.5)
            res = r
        else:
            dlam /= 2
            if dlam < 1e-3:
                return NewtonResult(r.x, jnp.asarray(False), jnp.asarray(total), r.residual)
    return NewtonResult(res.x, res.converged, jnp.asarray(total), res.residual)


@lru_cache(maxsize=None)
def _outputs_fn(model: Model):
    backbone = model.pointset(np.linspace(0.0, model.robot.rod.length, 101))

    def out(q):
        grid, bb = grid_frames(model, q, backbone)
        markers = positions(Frames(grid.g[model.marker_nodes], grid.J[model.marker_nodes]),
                            jnp.asarray(model.marker_offsets))
        return (markers, positions(bb),
                tendons.length_changes(model, grid))

    return jax.jit(out)


def shape_outputs(model: Model, q):
    """Marker positions (n_m, 3), backbone (101, 3) and tendon length changes at q."""
    return tuple(np.asarray(a) for a in _outputs_fn(model)(jnp.asarray(q)))
