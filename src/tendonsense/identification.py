"""Identification of E, ρ and μ from marker positions over static snapshots (eq. 18–19).

Each snapshot's equilibrium is an exact constraint: its shape ``q_k(θ)`` is solved by the core
Newton solver, and the marker Jacobian follows by implicit differentiation,
``dp/dθ = p_q (−E_q⁻¹ ∂E/∂θ)``; Levenberg–Marquardt on ``log θ`` minimises
``Σ_k ‖p_k(q_k(θ)) − p_k^meas‖²``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from .forward import model_for
from .model import Structure
from .readings import read_csv_rows
from .robot import Robot
from .statics import CACHE_SIZE, Drive, Unknowns, marker_positions, solve_system, terms

PARAMETERS = ("young_modulus", "density", "friction")
_DESCRIPTIVE = ("source", "note", "comment", "time", "id", "name")


class SnapshotError(ValueError):
    """Snapshots that cannot identify what was asked; the message says why."""


@dataclass(frozen=True)
class Snapshot:
    """One static pose: tensions (N, per tendon), an optional known global point load and the
    measured marker positions (m, global)."""

    tensions: dict[str, float]
    markers: dict[str, np.ndarray]
    load: tuple[float, tuple[float, float, float]] | None = None


@dataclass(frozen=True)
class Identified:
    parameters: dict[str, float]
    marker_rmse: float  # m, after the fit
    initial_rmse: float  # m, with the robot file's values
    converged: bool
    iterations: int
    robot: Robot  # the robot with the fitted values

    def to_json(self) -> dict:
        return {**self.parameters, "marker_rmse": self.marker_rmse,
                "initial_marker_rmse": self.initial_rmse, "converged": self.converged,
                "iterations": self.iterations}


def read_snapshots(path: str | Path, robot: Robot) -> list[Snapshot]:
    """SNAPSHOTS.csv of SPEC §4."""
    path = Path(path)
    raw = read_csv_rows(path, SnapshotError)
    header = raw[0] if raw else []
    rows = [dict(zip(header, r + [""] * (len(header) - len(r))))
            for r in raw[1:] if any(c.strip() for c in r)]
    if not rows:
        raise SnapshotError(f"{path}: no snapshot rows")
    load_cols = ("load_X", "load_fx", "load_fy", "load_fz")
    markers = [m for m in robot.marker_names if f"marker_{m}_x" in header]
    for col in header:
        kind, _, name = col.partition("_")
        ok = (col in _DESCRIPTIVE or col in load_cols
              or (kind == "tension" and name in robot.tendon_names)
              or (kind == "marker" and name[:-2] in markers and name[-2:] in ("_x", "_y", "_z")))
        if not ok:
            raise SnapshotError(f"{path}: column {col!r} is not tension_<tendon>, "
                                f"load_X/_fx/_fy/_fz or marker_<marker>_x/_y/_z")
    if not markers:
        raise SnapshotError(f"{path}: no marker_<name>_x/_y/_z columns: nothing to fit to")
    out = []
    for i, row in enumerate(rows, start=1):
        def num(col, required=True):
            text = (row.get(col) or "").strip()
            if not text:
                if required:
                    raise SnapshotError(f"{path}: snapshot row {i}: column {col} is missing")
                return None
            try:
                v = float(text)
            except ValueError:
                v = math.nan
            if not math.isfinite(v):
                raise SnapshotError(f"{path}: snapshot row {i}: column {col}: {text!r} is "
                                    f"not a finite number")
            return v
        tensions = {n: num(f"tension_{n}") for n in robot.tendon_names if f"tension_{n}" in row}
        pos = {m: np.array([num(f"marker_{m}_{a}") for a in "xyz"]) for m in markers}
        load_vals = [num(c, required=False) if c in row else None for c in load_cols]
        if all(v is None for v in load_vals):
            load = None
        elif any(v is None for v in load_vals):
            raise SnapshotError(f"{path}: snapshot row {i}: a load needs load_X, load_fx, "
                                f"load_fy and load_fz")
        else:
            if not 0 <= load_vals[0] <= robot.rod.length:
                raise SnapshotError(f"{path}: snapshot row {i}: load_X = {load_vals[0]:g} is "
                                    f"outside the rod")
            load = (load_vals[0], tuple(load_vals[1:]))
        out.append(Snapshot(tensions, pos, load))
    return out


def _check(robot: Robot, snapshots: Sequence[Snapshot], params: Sequence[str]):
    if not snapshots:
        raise SnapshotError("no snapshots")
    bad = [p for p in params if p not in PARAMETERS]
    if bad or not params:
        raise SnapshotError(f"parameters to fit must be among {', '.join(PARAMETERS)}; got "
                            f"{', '.join(params) or 'none'}")
    for k, s in enumerate(snapshots, start=1):
        if not s.markers:
            raise SnapshotError(f"snapshot {k}: no measured markers")
        for m, p in s.markers.items():
            if m not in robot.marker_names:
                raise SnapshotError(f"snapshot {k}: no marker {m!r} in the robot")
            if np.shape(p) != (3,) or not np.all(np.isfinite(p)):
                raise SnapshotError(f"snapshot {k}: marker {m!r} is not 3 finite numbers")
    tensioned = any(any(v != 0 for v in s.tensions.values()) for s in snapshots)
    if "friction" in params and not tensioned:
        raise SnapshotError("friction cannot be identified: no snapshot has a tendon under "
                            "tension")
    loaded = any(s.load is not None for s in snapshots)
    if {"young_modulus", "density"} <= set(params) and not (loaded or tensioned):
        raise SnapshotError("young_modulus and density cannot both be identified from "
                            "gravity-only snapshots (only density / young_modulus is "
                            "observable): add a known load or tendon tension")


@lru_cache(maxsize=CACHE_SIZE)
def _snapshot_fns(structure: Structure):
    """Jitted marker positions and the Jacobians (E_q, E_θ, p_q) of one snapshot, θ the
    values :data:`PARAMETERS` by name."""
    unknowns = Unknowns.none(structure.n_tendons, 1)

    def equilibrium(q, theta, values, drive):
        values = values._replace(**theta)
        t = terms(structure, values, q, jnp.zeros(0), drive, unknowns, 1.0)
        return values.young_modulus * (values.stiffness() @ q) - t.load

    def jacobians(q, values, drive):
        theta = {k: getattr(values, k) for k in PARAMETERS}
        Eq, Et = jax.jacfwd(equilibrium, argnums=(0, 1))(q, theta, values, drive)
        return Eq, Et, jax.jacfwd(lambda q: marker_positions(structure, values, q))(q)

    return (jax.jit(lambda q, values: marker_positions(structure, values, q)),
            jax.jit(jacobians))


def identify(robot: Robot, snapshots: Sequence[Snapshot],
             params: Sequence[str] = ("young_modulus", "density"), max_iterations: int = 50,
             progress=None) -> Identified:
    """Fit ``params`` (a subset of young_modulus, density, friction — one μ for every tendon)
    to the snapshots' markers, starting from the robot file's values."""
    params = tuple(dict.fromkeys(params))
    _check(robot, snapshots, params)
    model = model_for(robot)
    structure, base = model.structure, model.values
    names = robot.marker_names
    gravity = jnp.asarray(robot.gravity, float)
    unknowns = Unknowns.none(len(robot.tendons), 1)
    drives, meas, idx = [], [], []
    for s in snapshots:
        T = np.array([s.tensions.get(n, 0.0) for n in robot.tendon_names])
        X, F = (s.load[0], s.load[1]) if s.load is not None else (robot.rod.length, (0, 0, 0))
        drives.append(Drive(jnp.asarray(T), jnp.asarray([F], float), jnp.asarray([X], float),
                            gravity, jnp.zeros(0)))
        sel = [names.index(m) for m in s.markers]
        idx.append(sel)
        meas.append(np.array([s.markers[m] for m in s.markers]))
    markers_fn, jac_fn = _snapshot_fns(structure)

    theta0 = {"young_modulus": float(base.young_modulus), "density": float(base.density),
              "friction": max(float(np.mean(np.asarray(base.friction))) if robot.tendons
                              else 0.0, 0.05)}
    scale = np.array([theta0[p] for p in params])

    def make_values(log_ratio):
        v = dict(zip(params, scale * np.exp(log_ratio)))
        return model.with_values(**v).values, v

    def evaluate(log_ratio, q_start):
        """Marker residuals, their Jacobian w.r.t. log θ and the snapshot shapes, or None if
        an equilibrium fails."""
        values, chosen = make_values(log_ratio)
        dtheta = np.array([chosen[n] for n in params])  # d/d log θ = θ d/dθ
        res, jac, qs = [], [], []
        for k, d in enumerate(drives):
            sol = solve_system(structure, values, (), d, unknowns, q_start[k])
            if not bool(sol.converged):
                return None
            res.append((np.asarray(markers_fn(sol.x, values))[idx[k]] - meas[k]).ravel())
            Eq, Et, Pq = jac_fn(sol.x, values, d)
            dE = np.stack([_param_column(Et, n) for n in params], axis=1) * dtheta
            dq = -np.linalg.solve(np.asarray(Eq), dE)
            jac.append((np.asarray(Pq)[idx[k]] @ dq).reshape(-1, len(params)))
            qs.append(sol.x)
        return np.concatenate(res), np.concatenate(jac), qs

    theta = np.zeros(len(params))
    first = evaluate(theta, [None] * len(drives))
    if first is None:
        raise SnapshotError("a snapshot's equilibrium did not converge with the robot file's "
                            "parameters")
    r, J, qs = first
    initial_rmse = _rmse(r)
    damping, converged, it = 1e-3, False, 0
    for it in range(1, max_iterations + 1):
        g, H = J.T @ r, J.T @ J
        # the undamped Gauss–Newton step, relative change of θ: converged below 1e-6, or below
        # 1e-5 once no step lowers the cost (the equilibrium solves' resolution)
        gn = np.linalg.norm(np.linalg.lstsq(H, -g, rcond=None)[0])
        if gn <= 1e-6:
            converged = True
            break
        improved = False
        while damping < 1e10:
            step = np.linalg.solve(H + damping * np.diag(np.diag(H) + 1e-12), -g)
            trial = evaluate(theta + step, qs)
            if trial is not None and trial[0] @ trial[0] < r @ r:
                theta, (r, J, qs) = theta + step, trial
                damping, improved = max(damping / 5, 1e-10), True
                break
            damping *= 5
        if progress is not None:
            progress(it, max_iterations)
        if not improved:
            converged = gn <= 1e-5
            break
    _, fitted = make_values(theta)
    fitted = {k: float(v) for k, v in fitted.items()}
    new_robot = robot.with_parameters(**fitted)
    return Identified(fitted, _rmse(r), initial_rmse, bool(converged), it, new_robot)


def _param_column(Et: dict, name: str) -> np.ndarray:
    """∂E/∂θ for one parameter (friction: one μ shared by every tendon)."""
    if name == "friction":
        return np.asarray(Et["friction"]).sum(axis=1)
    return np.asarray(Et[name])


def _rmse(r: np.ndarray) -> float:
    """Root-mean-square marker distance: r holds xyz triples."""
    return float(np.sqrt(np.mean(np.sum(r.reshape(-1, 3) ** 2, axis=1))))
