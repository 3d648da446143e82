"""Forward problems: statics (tensions → shape) and kinematics (tendon lengths → shape and
tensions, eq. 16)."""

from __future__ import annotations

import math
from functools import lru_cache
from typing import Mapping, Sequence

import jax.numpy as jnp
import numpy as np

from .model import Model
from .result import Result
from .robot import Robot
from .statics import Drive, NewtonResult, Params, Unknowns, shape_outputs, solve_system

#: a point force: (X, (fx, fy, fz)) in the global frame, N
PointForce = tuple[float, Sequence[float]]


@lru_cache(maxsize=64)
def model_for(robot: Robot, load_points: tuple[float, ...] = ()) -> Model:
    """The discretised model of ``robot`` with point loads at ``load_points`` (cached)."""
    return Model.build(robot, load_points)


def finite(name: str, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: not a number: {value!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{name}: must be finite, got {v}")
    return v


def tendon_vector(robot: Robot, values: Mapping[str, float] | None, what: str) -> np.ndarray:
    """Per-tendon values from a {name: value} mapping (missing tendons: 0)."""
    out = np.zeros(len(robot.tendons))
    for name, v in (values or {}).items():
        if name not in robot.tendon_names:
            raise ValueError(f"{what} {name}: no such tendon (robot has "
                             f"{', '.join(robot.tendon_names) or 'none'})")
        out[robot.tendon_names.index(name)] = finite(f"{what} {name}", v)
    return out


def check_point_forces(robot: Robot, point_forces: Sequence[PointForce]):
    """Validated ``(X tuple, forces (n, 3))`` of known point forces."""
    Xs, Fs = [], []
    for i, (X, f) in enumerate(point_forces):
        X = finite(f"point force {i + 1} X", X)
        if not 0.0 <= X <= robot.rod.length:
            raise ValueError(f"point force {i + 1}: X = {X:g} m is outside the rod "
                             f"[0, {robot.rod.length:g}]")
        f = np.asarray(f, float).reshape(-1)
        if f.size != 3 or not np.all(np.isfinite(f)):
            raise ValueError(f"point force {i + 1}: the force must be 3 finite numbers")
        Xs.append(X)
        Fs.append(f)
    return tuple(Xs), np.array(Fs, float).reshape(-1, 3)


def make_result(model: Model, x, tensions, res: NewtonResult, **extra) -> Result:
    robot = model.robot
    q = np.asarray(x[: model.nq])
    markers, backbone, y = shape_outputs(model, q)
    return Result(
        q=q, tensions=dict(zip(robot.tendon_names, map(float, tensions))),
        displacements=dict(zip(robot.tendon_names, map(float, y))),
        markers={m: markers[i] for i, m in enumerate(robot.marker_names)}, backbone=backbone,
        converged=bool(res.converged), iterations=int(res.iterations),
        residual=float(res.residual), **extra)


def solve(robot: Robot, tensions: Mapping[str, float] | None = None,
          point_forces: Sequence[PointForce] = (), q0=None) -> Result:
    """Forward statics: the equilibrium shape under tendon ``tensions`` (N, by tendon name;
    missing tendons are slack), gravity and known global ``point_forces`` [(X, f), ...]."""
    T = tendon_vector(robot, tensions, "tension")
    X, F = check_point_forces(robot, point_forces)
    model = model_for(robot, X)
    drive = Drive(jnp.asarray(T), jnp.asarray(F), jnp.asarray(robot.gravity), jnp.zeros(0))
    res = solve_system(model, (), drive, Unknowns.none(model), Params.of(model), q0)
    return make_result(model, res.x, T, res)


def forward_kinematics(robot: Robot, displacements: Mapping[str, float],
                       tensions: Mapping[str, float] | None = None,
                       point_forces: Sequence[PointForce] = (), q0=None) -> Result:
    """Forward kinematics (eq. 16): the shape and the tensions of the tendons whose length
    changes ``displacements`` (m) are prescribed; other tendons keep ``tensions`` (default 0)."""
    if not displacements:
        raise ValueError("forward kinematics needs at least one tendon displacement")
    y = tendon_vector(robot, displacements, "displacement")
    T = tendon_vector(robot, tensions, "tension")
    measured = tuple(robot.tendon_names.index(n) for n in displacements)
    clash = [n for n in displacements if n in (tensions or {})]
    if clash:
        raise ValueError(f"tendon {clash[0]}: give its displacement or its tension, not both")
    X, F = check_point_forces(robot, point_forces)
    model = model_for(robot, X)
    n_z = len(measured)
    select = np.zeros((len(robot.tendons), n_z))
    select[list(measured), np.arange(n_z)] = 1.0
    unknowns = Unknowns.none(model, n_z)._replace(tensions=jnp.asarray(select))
    drive = Drive(jnp.asarray(T), jnp.asarray(F), jnp.asarray(robot.gravity),
                  jnp.asarray(y[list(measured)]))
    res = solve_system(model, measured, drive, unknowns, Params.of(model), q0)
    z = np.asarray(res.x[model.nq:])
    return make_result(model, res.x, T + select @ z, res)
