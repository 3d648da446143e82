"""Forward problems: statics (tensions → shape) and kinematics (tendon lengths → shape and
tensions, eq. 16), and the derivatives of a solution with respect to the values (batches:
:func:`tendonsense.tracking.solve_batch`)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from . import inputs, stability, tendons
from .inputs import PointForce, check_point_forces, finite, tendon_vector  # noqa: F401 (API)
from .compiled import Program
from .kinematics import poses
from .model import Model, material_values
from .result import Result, compact_repr, fields_json, joined, warns_if_not_converged
from .robot import Robot, check_robot
from .rod import Overlap, overlap
from .stability import SETTLED_NOTE, is_unstable, stiffness_ratio, tangent, unstable_note
from .statics import (CACHE_SIZE, Drive, NewtonResult, Unknowns, derivatives, marker_positions,
                      preload_outputs, shape_outputs, solve_system)

#: a tension below −TENSION_TOL times the largest (at least 1 N) is a tendon pushing: no
#: solution
TENSION_TOL = 1e-9
#: why a solution that satisfies the equations is not reported as converged
INADMISSIBLE = "strain outside the model's range (a fibre compressed to nothing)"
#: the note of a solution whose shape passes through itself
THROUGH_ITSELF = "the shape passes through itself"
#: a centre line longer or shorter than the rod by more than this share of it is noted
LARGE_STRAIN = 0.25


def model_for(robot: Robot) -> Model:
    """The discretised model of ``robot`` (cached; models of robots that differ only in
    their numbers share every compiled program, and those that differ only in their
    material values, :data:`~tendonsense.model.VALUE_NAMES` — e.g. each of
    :meth:`Robot.with_parameters <tendonsense.robot.Robot.with_parameters>` — share one
    build of the geometry)."""
    built = _built(check_robot(robot).geometry)
    return Model(robot, built.structure, built.values._replace(**material_values(robot)))


@lru_cache(maxsize=64)
def _built(geometry: Robot) -> Model:
    """:meth:`Model.build <tendonsense.model.Model.build>` of a :attr:`Robot.geometry
    <tendonsense.robot.Robot.geometry>` (:func:`model_for` puts the robot's own values)."""
    return Model.build(geometry)


def why_not(res: NewtonResult, fine: bool, tolerance: float) -> str:
    """Why the solver's ``res`` is no solution: its strain left the model's range (``fine``
    False), or where the solver stopped (and the share of the load its continuation solved,
    and its last iterate's strain, if out of range)."""
    if not fine and float(res.residual) <= tolerance:  # (the solver's test, whatever the
        return INADMISSIBLE  # verdict the caller put in res.converged)
    level = 0.0 if res.level is None else float(res.level)
    reached = f"; it solved {level:.0%} of the load" if 0.0 < level < 1.0 else ""
    return (f"the solver stopped after {int(res.iterations)} iterations (its load "
            f"continuation's stages included{reached}) at relative residual "
            f"{float(res.residual):.2e} under the full load (tolerance {tolerance:g})"
            + ("" if fine else f"; at the last iterate: {INADMISSIBLE}"))


def make_result(model: Model, x, tensions, res: NewtonResult, why: str | None = None,
                **extra) -> Result:
    """The result of a solve at ``x``; not converged, it says why: ``why`` if given, else the
    strain's range or the solver's iterations and residual."""
    robot = model.robot
    q = np.asarray(x)[: model.nq]
    markers, backbone, y, fine = shape_outputs(model.structure, model.values, q)
    if not (bool(res.converged) and fine):
        why = why_not(res, fine, robot.numerics.tolerance) if not fine or not why else why
        note = extra.get("extra", {}).get("note")
        extra["extra"] = {**extra.get("extra", {}),
                          "note": why if not note or why in note else f"{why}; {note}"}
    elif remarks := joined(through_itself(robot, backbone), large_strain(robot, backbone)):
        extra["extra"] = {**extra.get("extra", {}), "note": joined(
            extra.get("extra", {}).get("note"), remarks)}
    return Result(
        q=q, tensions=dict(zip(robot.tendon_names, map(float, tensions))),
        displacements=dict(zip(robot.tendon_names, map(float, y))),
        markers={m: markers[i] for i, m in enumerate(robot.marker_names)}, backbone=backbone,
        converged=bool(res.converged) and bool(fine), iterations=int(res.iterations),
        residual=float(res.residual), **extra)


def crossing(robot: Robot, backbone) -> Overlap | None:
    """Where the shape of centre line ``backbone`` (from base to tip, evenly spaced along the
    rod) passes through itself (:func:`~tendonsense.rod.overlap`), or None."""
    X = np.linspace(0.0, robot.rod.length, len(backbone))
    return overlap(backbone, X, robot.rod.radius(X))


def through_itself(robot: Robot, backbone) -> str:
    """A note where the shape of centre line ``backbone`` passes through itself
    (:func:`crossing`), or ''."""
    where = crossing(robot, backbone)
    if where is None:
        return ""
    return (f"{THROUGH_ITSELF}: its centre line at X = {where.X:.4g} m is "
            f"{where.distance * 1e3:.3g} mm from itself at X = {where.X_other:.4g} m, closer "
            f"than the rod's radii there together ({where.reach * 1e3:.3g} mm); the model has "
            f"no contact, so the robot cannot take this shape")


def stretched(robot: Robot, backbone) -> str:
    """"the centre line is P% longer (shorter) than the rod at rest" where the centre line
    ``backbone`` is longer or shorter than the rod at rest by more than :data:`LARGE_STRAIN`
    of it, or ''."""
    change = np.linalg.norm(np.diff(np.asarray(backbone, float), axis=0), axis=1).sum() \
        / robot.rod.length - 1.0
    if abs(change) <= LARGE_STRAIN:
        return ""
    return (f"the centre line is {abs(change):.0%} {'longer' if change > 0 else 'shorter'} "
            f"than the rod at rest")


def large_strain(robot: Robot, backbone) -> str:
    """A note where the centre line ``backbone`` is :func:`stretched`, or ''."""
    change = stretched(robot, backbone)
    return change and (f"large strain: {change} (the model's linear elasticity holds for "
                       f"strains of a few per cent; are the values in SI units, Young's "
                       f"modulus in Pa?)")


def _statics_drive(robot: Robot, tensions, point_forces) -> Drive:
    """The drive of a forward problem; without point forces, one of zero size at the base so
    that problems with and without a point force share one compiled program."""
    T = inputs.tensions(robot, tensions)
    X, F = check_point_forces(robot, point_forces)
    if not X.size:
        X, F = np.zeros(1), np.zeros((1, 3))
    return Drive(T, F, X, np.asarray(robot.gravity, float), np.zeros(0))


def sliding_values(robot: Robot, values, directions: Mapping[str, str] | None):
    """``values`` with every tendon's μ signed by its sliding direction, in or out
    (:func:`~tendonsense.inputs.friction_signs`); a stuck one is a ValueError: a solve needs
    its profile."""
    if not directions:
        return values
    for name, d in directions.items():
        if d == "stuck":
            raise ValueError(f"sliding {name}=stuck: the tension inside a stuck tendon "
                             f"depends on its history, so a solve needs in or out (an "
                             f"estimate takes stuck and gives the range of forces)")
    return values._replace(friction=values.friction * inputs.friction_signs(robot, directions))


@warns_if_not_converged
def solve(robot: Robot, tensions: Mapping[str, float] | None = None,
          point_forces: Sequence[PointForce] = (), q0=None,
          sliding: Mapping[str, str] | None = None, settle: bool = False) -> Result:
    """Forward statics: the equilibrium shape under tendon ``tensions`` (N, by tendon name;
    missing tendons are slack), gravity and known global ``point_forces`` [(X, f), ...];
    ``sliding`` ({tendon: 'in' | 'out'}, default in) is the direction each tendon slides,
    which sets the sense of its friction.

    Solved from the straight rod (or ``q0``), the shape keeps the plane of its loads; where it
    is an unstable equilibrium its note says so. With ``settle``, where it is unstable or no
    equilibrium was found, the result is instead the stable state the rod comes to rest in
    from it (:func:`~tendonsense.stability.settle`), its note says so. A result that did not
    converge (the solver's last iterate) is said by a
    :class:`~tendonsense.result.NotConvergedWarning`."""
    model = model_for(robot)
    drive = _statics_drive(robot, tensions, point_forces)
    values = sliding_values(robot, model.values, sliding)
    unknowns = Unknowns.none(len(robot.tendons), drive.load_X.shape[0])
    preload_outputs(model.structure, model.values)  # (as :func:`make_result`)
    if settle:
        stability.preload_settle(model.structure, values, drive, unknowns, np.zeros(model.nq))
    res = solve_system(model.structure, values, (), drive, unknowns,
                       inputs.start(q0, model.nq))
    ratio = stiffness_ratio(values, tangent(values, res, model.nq)) if bool(res.converged) \
        else np.nan
    if settle and (is_unstable(ratio) or not bool(res.converged)):
        return settled(model, values, drive, unknowns, res.stopped, int(res.iterations), ratio)
    shaky = unstable_note(ratio)
    return make_result(model, res.x, np.asarray(drive.tensions), res,
                       **({"extra": {"note": shaky}} if shaky else {}))


def settled(model: Model, values, drive: Drive, unknowns: Unknowns, x, iterations: int,
            ratio: float) -> Result:
    """:func:`solve`'s result where the rod settles from its first solution ``x`` (an
    unstable equilibrium of stiffness ratio ``ratio``, or no solution: NaN; found in
    ``iterations``) with the ``values`` it was solved with: Newton's from where
    :func:`~tendonsense.stability.settle` stopped, kept where it is stable."""
    came = stability.settle(model.structure, values, drive, unknowns, np.asarray(x, float),
                            model.robot.numerics.tolerance)
    res = solve_system(model.structure, values, (), drive, unknowns, came.x)
    at_rest = stiffness_ratio(values, tangent(values, res, model.nq)) if bool(res.converged) \
        else np.nan
    res = res._replace(iterations=iterations + came.steps + res.iterations,
                       converged=bool(res.converged) and not is_unstable(at_rest))
    found = f"was unstable (stiffness ratio {ratio:.3g})" if is_unstable(ratio) else \
        "was not found"
    how = (f"nudged along its unstable mode, {came.steps} pseudo-time steps" if came.nudges
           else f"{came.steps} pseudo-time steps")
    if not bool(res.converged):
        why = (f"the rod did not come to rest: the equilibrium solved for {found}, and "
               f"{came.steps} pseudo-time steps of the damped rod from it "
               f"({came.nudges} nudge{'' if came.nudges == 1 else 's'} along an unstable "
               f"mode) reached no stable equilibrium"
               + (f": {came.why}" if came.why else ""))
        return make_result(model, res.x, np.asarray(drive.tensions), res, why=why,
                           extra={"note": why})
    return make_result(model, res.x, np.asarray(drive.tensions), res, extra={"note": (
        f"{SETTLED_NOTE}: the equilibrium solved for {found}; this is the stable state the "
        f"rod comes to rest in from it ({how}; "
        f"another start may rest in another state, e.g. the mirror image where the loads lie "
        f"in a plane)")})


@warns_if_not_converged
def forward_kinematics(robot: Robot, displacements: Mapping[str, float],
                       tensions: Mapping[str, float] | None = None,
                       point_forces: Sequence[PointForce] = (), q0=None,
                       sliding: Mapping[str, str] | None = None) -> Result:
    """Forward kinematics (eq. 16): the shape and the tensions of the tendons whose length
    changes ``displacements`` (m) are prescribed; other tendons keep ``tensions`` (default 0);
    ``sliding`` as for :func:`solve`. A length change that only a pushing tendon could make
    (longer than the tendon is when slack) is no solution: not converged, the note says
    which (and a :class:`~tendonsense.result.NotConvergedWarning`, as for :func:`solve`)."""
    check_robot(robot)
    if not displacements:
        raise ValueError("forward kinematics needs at least one tendon displacement")
    y = inputs.displacements(robot, displacements)
    measured = tuple(robot.tendon_names.index(n) for n in displacements)
    clash = [n for n in displacements if n in (tensions or {})]
    if clash:
        raise ValueError(f"tendon {clash[0]}: give its displacement or its tension, not both")
    model = model_for(robot)
    drive = _statics_drive(robot, tensions, point_forces)._replace(
        targets=y[list(measured)])
    n_z = len(measured)
    select = np.zeros((len(robot.tendons), n_z))
    select[list(measured), np.arange(n_z)] = 1.0
    unknowns = Unknowns.none(len(robot.tendons), drive.load_X.shape[0], n_z)._replace(
        tensions=select)
    res = solve_system(model.structure, sliding_values(robot, model.values, sliding), measured,
                       drive, unknowns, inputs.start(q0, model.nq, model.nq + n_z))
    T = np.asarray(drive.tensions) + select @ np.asarray(res.x)[model.nq:]
    pushing = [k for k in measured if T[k] < -TENSION_TOL * max(1.0, np.abs(T).max())]
    if pushing and bool(res.converged):
        k = pushing[0]
        name, t = robot.tendon_names[k], T[k]
        return make_result(model, res.x, T, res._replace(converged=False), why=(
            f"tendon {name}: a length change of {y[k]:+.6f} m would need it to "
            f"push ({t:.4g} N): it is longer than the tendon is when slack (a slack tendon's "
            f"length does not set the shape; pulled in is negative)"))
    return make_result(model, res.x, T, res)


# ----------------------------------------------------------------------------- derivatives

@dataclass(frozen=True, eq=False)
class Derivatives:
    """Derivatives of a forward-statics solution with respect to each input ``θ`` by name:
    ``q[θ]`` has shape ``(nq, *θ)``, ``markers[θ]`` ``(n_m, 3, *θ)``, ``displacements[θ]``
    ``(n_t, *θ)``."""

    q: dict[str, np.ndarray]
    markers: dict[str, np.ndarray]
    displacements: dict[str, np.ndarray]

    __repr__ = compact_repr
    to_json = fields_json


@lru_cache(maxsize=CACHE_SIZE)
def _output_jacobian_fn(structure):
    def outputs(q, values):
        return (marker_positions(structure, values, q),
                tendons.length_changes(structure, values, poses(values, q)[0], q))

    return Program(jax.jacfwd(outputs), "output_jacobian", structure)


def solution_derivatives(robot: Robot, tensions: Mapping[str, float] | None = None,
                         point_forces: Sequence[PointForce] = (),
                         wrt: Sequence[str] = ("young_modulus",), q=None) -> Derivatives:
    """Derivatives of the forward-statics solution by implicit differentiation of the
    equilibrium (exact; no finite differences) with respect to values (``young_modulus``,
    ``poisson_ratio``, ``density``, ``friction`` per tendon) and inputs (``tensions``,
    ``forces``, ``load_X``, ``gravity``). ``q`` is the solution if already known.

    >>> d = solution_derivatives(robot, {"t1": 2.0}, [(0.2, (0, 0, -0.1))],
    ...                          wrt=("young_modulus", "load_X"))
    >>> d.markers["load_X"][:, :, 0]  # how each marker moves per metre the load moves
    """
    model = model_for(robot)
    drive = _statics_drive(robot, tensions, point_forces)
    unknowns = Unknowns.none(len(robot.tendons), drive.load_X.shape[0])
    if q is None:
        res = solve_system(model.structure, model.values, (), drive, unknowns)
        if not bool(res.converged):
            raise ValueError("the forward-statics solution did not converge: no derivatives")
        q = res.x
    q = jnp.asarray(q, float)
    dq = derivatives(model.structure, model.values, (), q, drive, unknowns, wrt)
    Pq, Yq = (np.asarray(a) for a in _output_jacobian_fn(model.structure)(q, model.values))
    markers, disp = {}, {}
    for k, d in dq.items():
        flat = d.reshape(model.nq, -1)
        markers[k] = (Pq.reshape(-1, model.nq) @ flat).reshape(Pq.shape[:2] + d.shape[1:])
        disp[k] = (Yq @ flat).reshape((Yq.shape[0],) + d.shape[1:])
    return Derivatives(dq, markers, disp)
