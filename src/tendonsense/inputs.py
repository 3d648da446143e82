"""What a user gives a solver — tendon readings, known and unknown loads, sensor noise — and
the one set of rules every path checks them by (command line, Python, logs, streams,
calibration). No JAX: the command line checks everything before it starts a solver.

The rules for a reading:
- a tendon is named by the robot file; a value is a finite number;
- a tension is ≥ 0 (a tendon cannot push) and shortens the rod by at most half where it is
  thinnest (T ≤ E·A / 2: a value in gram-force, for one, does not); a slack tendon is a
  tension of 0, said explicitly
  in a file (a ``tension_<name>`` column for every tendon), or by leaving the tendon out of a
  command line or a Python mapping;
- a tendon whose length change is measured needs its tension measured too;
- a length change is smaller than the tendon's whole length (no tendon is pulled in or paid
  out by more than it is long: a value in mm typed as m, for one).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from functools import lru_cache
from typing import Collection, Mapping, Sequence

import numpy as np

from .robot import Robot

#: a known point force: (X, (fx, fy, fz)) in the global frame, N
PointForce = tuple[float, Sequence[float]]


def finite(name: str, value) -> float:
    """``value`` as a float, or a ValueError naming ``name``."""
    if isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name}: not a number: {value!r}")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: not a number: {value!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{name}: must be finite, got {v}")
    return v


def start(q0, nq: int, n_x: int | None = None) -> np.ndarray | None:
    """A solve's start ``q0`` (None: the straight rod) as an array of the robot's ``nq``
    strain coordinates (a solution's ``Result.q``; or all ``n_x`` unknowns of the solve), or a
    ValueError saying what it is."""
    if q0 is None:
        return None
    try:
        q = np.asarray(q0, float)
    except (TypeError, ValueError):
        raise ValueError(f"q0: not an array of numbers: {q0!r}") from None
    if q.shape not in ((nq,), (n_x or nq,)):
        raise ValueError(f"q0: {q.size} values of shape {q.shape}; the robot has {nq} strain "
                         f"coordinates (a solution's Result.q)")
    if not np.all(np.isfinite(q)):
        raise ValueError("q0: not finite")
    return q


def rest_lengths(robot: Robot) -> np.ndarray:
    """Every tendon's path length on the straight rod (l* of eq. 9), m (read-only)."""
    return _rest_lengths(robot.geometry)


@lru_cache(maxsize=64)
def _rest_lengths(robot: Robot) -> np.ndarray:
    L = robot.rod.length
    out = np.zeros(len(robot.tendons))
    for j, t in enumerate(robot.tendons):
        X = np.linspace(0.0, L, 2) if t.continuous else np.asarray(t.disks, float)
        path = t.offset(X, L) + X[:, None] * np.array([1.0, 0.0, 0.0])
        out[j] = np.linalg.norm(np.diff(path, axis=0), axis=1).sum()
    out.flags.writeable = False
    return out


#: a tension that alone would shorten the rod by more than this fraction where it is thinnest
#: (T / E·A) is not a reading
MAX_COMPRESSION = 0.5


def thinnest_area(robot: Robot, X: float) -> float:
    """The area (m²) of the thinnest section of the rod between its base and ``X`` (m): a
    force F along the rod at X stretches or shortens it by about F / E·A there."""
    rod = robot.rod
    knots = np.array([x for x, _ in rod.radius_knots])
    return float(rod.area(np.append(knots[knots <= X], X)).min())


def thinnest_sections(robot: Robot) -> dict[str, float]:
    """:func:`thinnest_area` up to each tendon's anchor, by tendon name."""
    return _thinnest_sections(robot.geometry)


@lru_cache(maxsize=64)
def _thinnest_sections(robot: Robot) -> dict[str, float]:
    return {t.name: thinnest_area(robot, t.disks[-1]) for t in robot.tendons}


def max_tension(robot: Robot, name: str, young_modulus=None):
    """The largest tension (N) a reading of tendon ``name`` may have: half the axial stiffness
    E·A of the thinnest section it spans, with ``young_modulus`` (an array: one per sample)
    where it is not the robot file's."""
    E = robot.rod.young_modulus if young_modulus is None else young_modulus
    return MAX_COMPRESSION * E * thinnest_sections(robot)[name]


#: Pa: a Young's modulus below this (softer than silicone rubbers, ~50 kPa and up) names
#: itself beside a tension the rod cannot bear (E typed in kPa or MPa?)
SOFTEST_RUBBER = 1e4


def outside_rod(what: str, X: float, length: float) -> str:
    """Why ``what`` = X (m) is not on a rod of ``length`` (m); a value 10 to 1000 rod lengths
    long (millimetres typed as metres) says that lengths are in metres."""
    hint = " (lengths are in metres)" if 10 * length < X <= 1000 * length else ""
    return f"{what} = {X:g} m is outside the rod [0, {length:g} m]{hint}"


def tension_error(robot: Robot, name: str, T: float, young_modulus: float | None = None
                  ) -> str | None:
    """Why tension ``T`` (N) of the robot's tendon ``name`` cannot be a reading, or None.
    ``young_modulus``: the rod's where it is not the robot file's (``math.inf`` where it is not
    known, as while it is fitted: no bound)."""
    if name not in robot.tendon_names:
        return f"tension {name}: no such tendon (robot has {', '.join(robot.tendon_names)})"
    if not math.isfinite(T):
        return f"tension {name} = {T}: not a finite number"
    if T < 0:
        return f"tension {name} = {T:g} N is negative (a tendon cannot push; slack is 0)"
    if T > (top := max_tension(robot, name, young_modulus)):
        E = robot.rod.young_modulus if young_modulus is None else young_modulus
        return (f"tension {name} = {T:g} N would shorten the rod by more than half where it is "
                f"thinnest {_in_stiffness('T', T, top)}: tensions are in newtons"
                + (f", and Young's modulus in Pa (E = {E:g} Pa here, softer than silicone "
                   f"rubbers)" if E < SOFTEST_RUBBER else ""))
    return None


def _in_stiffness(symbol: str, value: float, top: float) -> str:
    """A force beyond the rule's ``top`` against the stiffness E·A it is half of."""
    EA = top / MAX_COMPRESSION
    return f"({symbol} = {value / EA:.2g} E·A, E·A = {EA:.3g} N there)"


def max_force(robot: Robot, X: float, young_modulus=None):
    """The largest known point force (N) at ``X`` (m): as for a tension
    (:func:`max_tension`), half the axial stiffness E·A of the thinnest section between the
    base and X."""
    E = robot.rod.young_modulus if young_modulus is None else young_modulus
    return MAX_COMPRESSION * E * thinnest_area(robot, X)


def force_error(robot: Robot, what: str, X: float, force, young_modulus=None) -> str | None:
    """Why a known point force ``force`` (N, 3) at ``X`` (m) cannot be one, or None: over
    :func:`max_force` (a unit slip: gram-force typed as newtons). ``young_modulus`` as for
    :func:`tension_error`."""
    F = float(np.linalg.norm(force))
    if F > (top := max_force(robot, X, young_modulus)):
        return (f"{what} of {F:g} N is more than half the axial stiffness E·A of the rod "
                f"where it is thinnest {_in_stiffness('F', F, top)}: forces are in newtons")
    return None


def first_force_error(robot: Robot, what: str, X, forces, young_modulus
                      ) -> tuple[int, str] | None:
    """The first of n samples of one known point force, at ``X`` (n,) m with ``forces`` (n, 3)
    N and ``young_modulus`` (n,), that breaks :func:`force_error`'s rule, and why; or None."""
    X, E = np.broadcast_to(X, np.shape(young_modulus)), np.asarray(young_modulus, float)
    Xs, at = np.unique(X, return_inverse=True)
    top = np.array([max_force(robot, x, 1.0) for x in Xs])[at.reshape(-1)] * E
    bad = np.linalg.norm(np.broadcast_to(forces, (E.size, 3)), axis=1) > top
    if not bad.any():
        return None
    k = int(np.argmax(bad))
    return k, force_error(robot, what, X[k], np.broadcast_to(forces, (E.size, 3))[k], E[k])


def displacement_error(name: str, y: float, rest: float) -> str | None:
    """Why length change ``y`` (m) of a tendon ``rest`` m long cannot be a reading, or None."""
    if not math.isfinite(y):
        return f"displacement {name} = {y}: not a finite number"
    if abs(y) >= rest:
        way = "pulls in" if y < 0 else "pays out"
        return (f"displacement {name} = {y:g} m {way} more than the tendon's whole length "
                f"({rest:.3g} m; lengths are in metres)")
    return None


def marker_error(robot: Robot, name: str, xyz) -> str | None:
    """Why a measured position ``xyz`` (m, global) of marker ``name`` cannot be one, or None:
    finite, and within twice the rod's length (and the marker's offset) of its base: no marker
    gets farther."""
    p = np.asarray(xyz, float)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        return f"marker {name}: a position is 3 finite numbers, got {xyz!r}"
    d = float(np.linalg.norm(p - np.asarray(robot.base_position, float)))
    offset = [float(np.linalg.norm(m.offset)) for m in robot.markers if m.name == name]
    reach = 2 * robot.rod.length + (offset[0] if offset else 0.0)
    if d > reach:
        return (f"marker {name} at {d:.3g} m from the base, farther than it can be ({reach:.3g} "
                f"m, twice the rod's length and its offset): positions are in metres")
    return None


def tendon_vector(robot: Robot, values: Mapping[str, float] | None, what: str) -> np.ndarray:
    """Per-tendon values from a {name: value} mapping (tendons not named: 0); names and
    finiteness checked, nothing else."""
    if values is not None and not hasattr(values, "items"):  # a mapping (or a pandas Series)
        raise ValueError(f"{what}s: a mapping {{tendon: value}} such as {{'t1': 2.0}}, not a "
                         f"{type(values).__name__}")
    out = np.zeros(len(robot.tendons))
    for name, v in (values or {}).items():
        if name not in robot.tendon_names:
            raise ValueError(f"{what} {name}: no such tendon (robot has "
                             f"{', '.join(robot.tendon_names) or 'none'})")
        out[robot.tendon_names.index(name)] = finite(f"{what} {name}", v)
    return out


def tensions(robot: Robot, values: Mapping[str, float] | None,
             young_modulus: float | None = None) -> np.ndarray:
    """Tensions (N) per tendon by the rules of this module; tendons not named are slack.
    ``young_modulus``: as for :func:`tension_error`."""
    T = tendon_vector(robot, values, "tension")
    for name, v in zip(robot.tendon_names, T):
        if error := tension_error(robot, name, v, young_modulus):
            raise ValueError(error)
    return T


def displacements(robot: Robot, values: Mapping[str, float] | None,
                  rest: np.ndarray | None = None) -> np.ndarray:
    """Length changes (m) per tendon by the rules of this module; tendons not named: 0.
    ``rest``: the tendons' :func:`rest_lengths`, if known."""
    y = tendon_vector(robot, values, "displacement")
    rest = rest_lengths(robot) if rest is None else rest
    for name, v, length in zip(robot.tendon_names, y, rest):
        if name in (values or {}) and (error := displacement_error(name, v, length)):
            raise ValueError(error)
    return y


def readings(robot: Robot, displacements_: Mapping[str, float],
             tensions_: Mapping[str, float], rest: np.ndarray | None = None,
             young_modulus: float | None = None, measured: Collection[str] = ()
             ) -> tuple[np.ndarray, np.ndarray]:
    """``(T, y)`` per tendon of one reading: measured length changes ``displacements_`` (m)
    and tensions ``tensions_`` (N) by tendon name; every measured tendon needs its tension,
    and the tendons ``measured`` their length change. ``rest``: the tendons'
    :func:`rest_lengths`, if known; ``young_modulus``: as for :func:`tension_error`."""
    for what, given in (("displacement", displacements_), ("tension", tensions_)):
        if given is not None and (not hasattr(given, "items") or not all(
                n in robot.tendon_names for n, _ in given.items())):
            tendon_vector(robot, given, what)  # (says why)
    if absent := [n for n in measured if n not in displacements_]:
        raise ValueError(f"displacement {absent[0]}: missing: the tendon is measured")
    missing = [n for n in displacements_ if n not in (tensions_ or {})]
    if missing:
        raise ValueError(f"tension {missing[0]}: missing: the tendon's length change is "
                         f"measured, its tension must be too (a slack tendon is 0)")
    y = displacements(robot, displacements_, rest)
    return tensions(robot, tensions_, young_modulus), y


def per_sample(readings, what: str) -> list[Mapping[str, float]]:
    """A series' or a batch's ``readings`` of one kind (``what``: displacement or tension),
    one mapping a sample: a sequence of ``{tendon: value}`` as it is, or ``{tendon: (N,)
    values}`` cut into one a sample (a tendon's one value held in every sample); a ValueError
    naming both forms otherwise (e.g. a bare array, whose columns would have no tendon)."""
    forms = (f"{what}s: one {{tendon: value}} a sample (a list of them) or {{tendon: (N,) "
             f"values}}")
    if hasattr(readings, "items"):  # a tendon's one value holds for every sample
        cols = {}
        for name, v in readings.items():
            try:
                a = np.asarray(v, object if isinstance(v, (str, bytes)) else None)
            except ValueError:  # ragged
                raise ValueError(f"{forms}; {what} {name}: not (N,) values") from None
            if a.ndim > 1:
                raise ValueError(f"{forms}; {what} {name}: an array of shape {a.shape}")
            cols[name] = a.tolist()
        sizes = {len(c) for c in cols.values() if isinstance(c, list)}
        if not cols:
            return []
        if not sizes:
            raise ValueError(f"{forms}, not one value a tendon (a single reading is "
                             f"estimate()'s)")
        if len(sizes) > 1:
            raise ValueError(f"{forms}; the tendons' values differ in number (" + ", ".join(
                f"{k}: {len(c)}" for k, c in cols.items() if isinstance(c, list)) + ")")
        n = sizes.pop()
        cols = {k: c if isinstance(c, list) else [c] * n for k, c in cols.items()}
        return [dict(zip(cols, row)) for row in zip(*cols.values())]
    if isinstance(readings, (str, bytes)) or not hasattr(readings, "__len__"):
        raise ValueError(f"{forms}, not a {type(readings).__name__}")
    items = list(readings)
    if odd := [r for r in items if not hasattr(r, "items")]:
        raise ValueError(f"{forms}, not " + (
            f"an array of shape {np.shape(readings)}" if isinstance(readings, np.ndarray)
            else f"a {type(readings).__name__} of {type(odd[0]).__name__}"))
    return items


def many_readings(robot: Robot, displacements: Sequence[Mapping[str, float]],
                  tensions: Sequence[Mapping[str, float]], rest: np.ndarray | None = None,
                  young_modulus: float | Sequence[float | None] | None = None,
                  measured: Collection[str] = ()
                  ) -> tuple[np.ndarray, np.ndarray, dict[int, str]]:
    """:func:`readings` of n readings at once: ``(T, y)`` (n, n_t) and the reason every bad one
    breaks a rule, by index (its row of T and y zeros); ``young_modulus`` is one value or one
    per reading (None: the robot file's). The rules are checked on the arrays; a reading they
    catch is checked again by :func:`readings` alone, for its message."""
    n, names = len(tensions), robot.tendon_names
    if len(displacements) != n:
        raise ValueError(f"{len(displacements)} displacement and {n} tension readings (one of "
                         f"each per sample)")
    rest = rest_lengths(robot) if rest is None else rest
    E = np.array([robot.rod.young_modulus if e is None else e for e in np.broadcast_to(
        np.asarray(young_modulus, object), (n,))], float)

    def table(maps) -> np.ndarray:
        if any(isinstance(v, (bool, np.bool_)) for m in maps for v in m.values()):
            raise ValueError  # (each reading then says which)
        a = np.array([[m.get(name, 0.0) for name in names] for m in maps], float)
        if a.size and a.shape != (n, len(names)):  # values that are sequences
            raise ValueError
        return a.reshape(n, len(names))

    known = set(names)
    try:
        T, y = table(tensions), table(displacements)
        keys_ok = np.array([known.issuperset(d) and known.issuperset(t)
                            and all(name in d for name in measured) and all(name in t for name in d)
                            for d, t in zip(displacements, tensions)], bool).reshape(n)
    except (AttributeError, TypeError, ValueError):  # not mappings of numbers: one by one
        T, y, keys_ok = np.zeros((n, len(names))), np.zeros((n, len(names))), np.zeros(n, bool)
    top = np.array([max_tension(robot, name, 1.0) for name in names]) * E[:, None]
    with np.errstate(invalid="ignore"):
        ok = keys_ok & np.all(np.isfinite(T) & (T >= 0) & (T <= top), axis=1) & np.all(
            np.isfinite(y) & (np.abs(y) < rest), axis=1)
    errors = {}
    for k in np.flatnonzero(~ok).tolist():
        try:
            T[k], y[k] = readings(robot, displacements[k], tensions[k], rest, E[k], measured)
        except ValueError as exc:
            T[k], y[k], errors[k] = 0.0, 0.0, str(exc)
    return T, y, errors


#: the directions a tendon may slide through its guides
SLIDING = ("in", "out", "stuck")
#: a friction state this close to ±1 is sliding (in or out), not stuck
EDGE = 1e-9


#: a tendon's friction direction in a simulation: pulled in, paid out, or following its
#: tension history (the play operator of :mod:`tendonsense.sliding`)
SIMULATED_SLIDING = ("in", "out", "follow")


def sliding(robot: Robot, directions: Mapping[str, str] | None,
            allowed: tuple[str, ...] = SLIDING, default: str = "in") -> dict[str, str]:
    """Every tendon's sliding direction: ``in`` (pulled in: its tension fades from the actuator
    toward the anchor, eq. 10, the default), ``out`` (paid out: it grows toward the anchor) or
    ``stuck`` (anywhere between), or another of ``allowed``; a ValueError names an unknown
    tendon or direction."""
    out = dict.fromkeys(robot.tendon_names, default)
    for name, d in (directions or {}).items():
        if name not in out:
            raise ValueError(f"sliding {name}: no such tendon (robot has "
                             f"{', '.join(robot.tendon_names)})")
        if d not in allowed:
            raise ValueError(f"sliding {name}={d!r}: must be one of {', '.join(allowed)}")
        out[name] = d
    return out


def stuck_error(name: str, tension: float, what: str = "", friction: float | None = None
                ) -> str:
    """Why tendon ``name`` at ``tension`` (N), with its ``friction`` coefficient, cannot be
    stuck, or '': only a tendon under tension and with friction sticks in its guides (a slack
    or frictionless one has no friction band; a tension that is no tension is left to its own
    rule). ``what`` names the statement (``sliding NAME=stuck``)."""
    what = what or f"sliding {name}=stuck"
    if friction == 0:
        return (f"{what}: {name} has no friction (μ = 0): it slides freely in its guides, "
                f"with one tension along it, and cannot stick")
    return (f"{what}: {name} is slack (0 N): only a tendon under tension sticks (its friction "
            f"band is then between in and out)" if tension == 0 else "")


def stuck_located_error(name: str, what: str = "") -> str:
    """Why tendon ``name`` cannot be said stuck with a force of unknown location."""
    return (f"{what or f'sliding {name}=stuck'}: the range over a friction band is estimated "
            f"for forces at known points; a force of unknown location ('?' or 'A:B') is "
            f"searched with each tendon in or out: give its X, or in/out")


def check_stuck(robot: Robot, directions: Mapping[str, str] | None,
                tensions: Mapping[str, float], located: bool = False) -> None:
    """The rules of a reading's stuck tendons (:func:`stuck_error`; a tendon not given a
    tension is slack), and none with a force of unknown location (``located``: its range over
    the band is estimated at known points, as in a log): a ValueError naming the first."""
    stuck = [n for n, d in sliding(robot, directions).items() if d == "stuck"]
    for name in stuck:
        if error := stuck_error(name, float(tensions.get(name, 0.0)), friction=robot.tendons[
                robot.tendon_names.index(name)].friction):
            raise ValueError(error)
    if stuck and located:
        raise ValueError(stuck_located_error(stuck[0]))


def friction_signs(robot: Robot, directions: Mapping[str, str] | None,
                   stuck: float = 0.0) -> np.ndarray:
    """The factor of every tendon's Capstan exponent μφ for its sliding direction: +1 pulled
    in (``T_{i+1} = T_i exp(−μφ_i)``), −1 paid out (``T_{i+1} = T_i exp(+μφ_i)``), ``stuck``
    for a stuck one (a profile inside the band between the two)."""
    signs = {"in": 1.0, "out": -1.0, "stuck": stuck}
    return np.array([signs[d] for d in sliding(robot, directions).values()])


def _sequence(items, what: str, example: str) -> list:
    """``items`` as a list, or a ValueError naming ``what`` it should be (a string, a mapping, a
    single object or a one-pass iterator is not a list of them)."""
    if isinstance(items, (str, bytes, Mapping)) or not isinstance(items, Collection):
        raise ValueError(f"{what}: a list such as {example}, not a {type(items).__name__}")
    return list(items)


def force_pairs(point_forces) -> list:
    """``point_forces`` as a list of pairs ``(X, f)``, or a ValueError naming the first item
    that is not one (a single pair, a flat ``(X, fx, fy, fz)``)."""
    point_forces = _sequence(point_forces, "point forces", "[(X, (fx, fy, fz))]")
    if len(point_forces) == 2 and isinstance(point_forces[0], (int, float, np.number)):
        raise ValueError("point forces: a list of pairs such as [(X, (fx, fy, fz))], not one "
                         "pair")
    for i, load in enumerate(point_forces):
        if isinstance(load, (str, bytes)) or not hasattr(load, "__len__") or len(load) != 2:
            raise ValueError(f"point force {i + 1}: a pair (X, (fx, fy, fz)), got {load!r}")
    return point_forces


def check_point_forces(robot: Robot, point_forces: Sequence[PointForce], young_modulus=None):
    """Validated ``(X (n,), forces (n, 3))`` of known point forces (:func:`force_error`;
    ``young_modulus`` as for :func:`tension_error`)."""
    Xs, Fs = [], []
    for i, (X, f) in enumerate(force_pairs(point_forces)):
        X = finite(f"point force {i + 1} X", X)
        if not 0.0 <= X <= robot.rod.length:
            raise ValueError(f"point force {i + 1}: {outside_rod('X', X, robot.rod.length)}")
        f = np.asarray(f, float).reshape(-1)
        if f.size != 3 or not np.all(np.isfinite(f)):
            raise ValueError(f"point force {i + 1}: the force must be 3 finite numbers")
        if error := force_error(robot, f"point force {i + 1}", X, f, young_modulus):
            raise ValueError(error)
        Xs.append(X)
        Fs.append(f)
    return np.array(Xs, float), np.array(Fs, float).reshape(-1, 3)


@dataclass(frozen=True)
class PointForceUnknown:
    """A point force of unknown magnitude (N) along the global unit ``direction`` at ``X``.

    ``X`` is where it acts (m), or, for a force whose location is unknown too, ``None``
    (anywhere on the rod) or a range ``(A, B)``: the estimate then finds X as well
    (:attr:`located`), which takes one more measured tendon."""

    X: float | tuple[float, float] | None
    direction: tuple[float, float, float]

    def __post_init__(self):
        d = np.asarray(self.direction, float)
        if d.shape != (3,) or not np.all(np.isfinite(d)) or np.linalg.norm(d) == 0:
            raise ValueError(f"unknown force at X = {self.X}: direction must be 3 finite "
                             f"numbers, not all zero")
        if isinstance(self.X, (tuple, list)):
            if len(self.X) != 2:
                raise ValueError(f"unknown force: a range of X is two numbers, got {self.X!r}")
            a, b = (finite("unknown force X range", v) for v in self.X)
            if not a < b:
                raise ValueError(f"unknown force: the range of X must increase, got {a:g}:{b:g}")
            object.__setattr__(self, "X", (a, b))
        elif self.X is not None:
            object.__setattr__(self, "X", finite("unknown force X", self.X))
        object.__setattr__(self, "direction", tuple(d / np.linalg.norm(d)))

    @property
    def located(self) -> bool:
        """Whether X is unknown too."""
        return not isinstance(self.X, float)


@dataclass(frozen=True)
class GravityUnknown:
    """The unknown scale of the robot's gravity (1 = the robot file's acceleration)."""


@dataclass(frozen=True)
class Noise:
    """Sensor noise (1 σ) for the uncertainty band: lengths in m, tensions relative."""

    length: float = 1e-4
    tension: float = 0.025 / 3

    def __post_init__(self):
        length, tension = finite("length noise", self.length), finite("tension noise",
                                                                       self.tension)
        if length <= 0:
            raise ValueError(f"length noise: must be a positive number of metres, got {length:g}")
        if not tension > 0:
            raise ValueError(f"tension noise: must be a positive fraction (relative, 0.01 is "
                             f"1 %), got {tension:g}")
        if not tension < 1:
            raise ValueError(f"tension noise: {FRACTION}, got {tension:g}")
        object.__setattr__(self, "length", length)
        object.__setattr__(self, "tension", tension)


#: the rule for a relative noise (of the tensions), as the messages say it
FRACTION = "relative, must be a fraction under 1 (0.01 is 1 %)"


#: a length read-out noise is under this fraction of the shortest tendon's length
MAX_LENGTH_NOISE = 0.1


def length_noise_error(robot: Robot, what: str, sigma: float) -> str | None:
    """Why ``sigma`` (m) cannot be the standard deviation of a tendon length's read-out noise
    on ``robot``, or None: at least :data:`MAX_LENGTH_NOISE` of its shortest tendon's length is
    a unit slip (millimetres typed as metres)."""
    shortest = float(np.min(rest_lengths(robot))) if robot.tendons else math.inf
    if sigma >= MAX_LENGTH_NOISE * shortest:
        return (f"{what} {sigma:g} m is {sigma / shortest:.0%} of the shortest tendon's length "
                f"({shortest:.3g} m): lengths are in metres (0.1 mm = 0.0001)")
    return None


#: seconds a simulation may run past the last change of its loads (a rod settles within one)
SETTLED = 60.0


def last_change(times, values) -> float:
    """When a schedule (``values`` (k, …) at ``times`` (k,), linear between the rows, held
    before the first and after the last) last changes: the time of the last row that differs
    from the one before it, 0 if none (a row that holds the last value changes nothing)."""
    t = np.asarray(times, float)
    v = np.asarray(values, float).reshape(t.size, -1)
    moved = np.flatnonzero(np.any(v[1:] != v[:-1], axis=1))
    return float(t[moved[-1] + 1]) if moved.size else 0.0


def duration_error(what: str, duration: float, last: float) -> str | None:
    """Why a simulation cannot run ``duration`` s whose loads last change at ``last`` s, or
    None: more than :data:`SETTLED` s past it is a unit slip (3000 for 3 s ran 344 s)."""
    if duration > last + SETTLED:
        return (f"{what} {duration:g} s runs {duration - last:g} s past the last change of the "
                f"loads (at {last:g} s); a rod settles within a second of it: durations are in "
                f"seconds (at most {last + SETTLED:g} s here)")
    return None


def marker_noise_error(robot: Robot, what: str, sigma: float) -> str | None:
    """Why ``sigma`` (m) cannot be the standard deviation of a marker position's read-out
    noise on ``robot``, or None: a tenth of the rod's length or more is a unit slip."""
    if sigma >= robot.rod.length / 10:
        return (f"{what} {sigma:g} m is not under a tenth of the rod's length "
                f"({robot.rod.length:g} m): positions are in metres (0.5 mm = 0.0005)")
    return None


def check_noise(noise, robot: Robot | None = None) -> Noise:
    """``noise`` if it is a :class:`Noise` (and, with ``robot``, its length noise one a
    sensor of its tendons can have: :func:`length_noise_error`), or a ValueError saying what
    is expected."""
    if not isinstance(noise, Noise):
        raise ValueError(f"noise: a Noise(length=M, tension=FRACTION), not a "
                         f"{type(noise).__name__}")
    if robot is not None and (error := length_noise_error(robot, "noise: length", noise.length)):
        raise ValueError(error)
    return noise


#: default random walk of the unknown magnitudes in motion, per √s (N/√s for a force): a
#: force step followed to 90 % within 0.2 s on the prototype at τ = 0.3 s, 100 Hz, 0.1 mm and
#: 1 % noise (0.17 s; 0.20 s at 0.1, with 8 % less noise in the estimate)
WALK = 0.12


Unknown = PointForceUnknown | GravityUnknown


def check_unknowns(robot: Robot, measured: Sequence[str], unknowns: Sequence[Unknown]):
    """The counting and range rules of eq. 17 for ``unknowns`` estimated from the tendons
    ``measured``: a ValueError naming what is wrong."""
    unknowns = _sequence(unknowns, "unknowns", "[PointForceUnknown(…)]")
    for i, u in enumerate(unknowns, 1):
        if not isinstance(u, (PointForceUnknown, GravityUnknown)):
            raise ValueError(f"unknown {i}: a PointForceUnknown or GravityUnknown, got {u!r}")
    if not unknowns:
        raise ValueError("estimation needs at least one unknown load")
    measured = _sequence(measured, "measured tendons", "['t1']")
    if twice := [n for i, n in enumerate(measured) if n in measured[:i]]:
        raise ValueError(f"measured tendons: {twice[0]} listed twice (each tendon's length is "
                         f"one reading)")
    for name in measured:
        if name not in robot.tendon_names:
            raise ValueError(f"displacement {name}: no such tendon (robot has "
                             f"{', '.join(robot.tendon_names) or 'none'})")
    n_a, n_p = len(measured), len(unknowns)
    n_loc = sum(isinstance(u, PointForceUnknown) and u.located for u in unknowns)
    if n_a < n_p + n_loc:
        where = (f" and {n_loc} unknown location{'s' if n_loc > 1 else ''}" if n_loc else "")
        need = n_p + n_loc
        raise ValueError(f"{n_p} unknown load magnitude{'s' if n_p > 1 else ''}{where} "
                         f"need{'s' if n_p == 1 and not n_loc else ''} at least {need} "
                         f"tendon{'s' if need > 1 else ''} with measured length and tension; got "
                         f"{n_a} (n_a >= n_p{' + located' if n_loc else ''}, eq. 17)")
    if sum(isinstance(u, GravityUnknown) for u in unknowns) > 1:
        raise ValueError("gravity can be unknown only once")
    L = robot.rod.length
    for u in unknowns:
        if isinstance(u, PointForceUnknown):
            a, b = (0.0, L) if u.X is None else (u.X if u.located else (u.X, u.X))
            if not 0.0 <= a <= b <= L:
                raise ValueError("unknown force: " + (
                    outside_rod("X", a, L) if a == b else
                    f"the range {a:g}:{b:g} m is outside the rod [0, {L:g} m]"))
            if b == 0.0:
                raise ValueError("unknown force: at X = 0 it acts on the clamped base and moves "
                                 "nothing: the readings cannot tell its size")
        elif (robot.rod.density == 0 and not robot.masses) or not any(robot.gravity):
            raise ValueError("unknown gravity: the robot has no weight (" + (
                "its gravity's acceleration is 0" if not any(robot.gravity) else
                "its rod's density is 0 and it carries no mass") + ")")
    fixed = [(i, u) for i, u in enumerate(unknowns, 1)
             if isinstance(u, PointForceUnknown) and not u.located]
    for k, (i, u) in enumerate(fixed):
        for j, v in fixed[k + 1:]:
            d, e = np.asarray(u.direction, float), np.asarray(v.direction, float)
            if u.X == v.X and np.linalg.norm(np.cross(d, e)) <= 1e-9 * np.linalg.norm(d) * \
                    np.linalg.norm(e):
                raise ValueError(f"unknowns {i} and {j}: one force (X = {u.X:g} m, parallel "
                                 f"directions): their magnitudes cannot be told apart")


#: parameters :func:`~tendonsense.identification.identify` fits by name;
#: ``friction_<tendon>`` fits one tendon's μ
PARAMETERS = ("young_modulus", "density", "friction")
#: what :func:`~tendonsense.identification.identify` fits unless told
DEFAULT_PARAMETERS = ("young_modulus", "density")


def parameter_names(robot: Robot) -> tuple[str, ...]:
    """Every parameter :func:`~tendonsense.identification.identify` can fit for ``robot``."""
    return (*PARAMETERS, *(f"friction_{n}" for n in robot.tendon_names))


#: a fitted parameter's words and unit (with its leading space)
PARAMETER_WORDS = {"young_modulus": ("Young's modulus E", " Pa"),
                   "density": ("density ρ", " kg/m³"),
                   "friction": ("friction coefficient μ", ""),
                   "damping": ("damping η (Kelvin–Voigt)", " Pa·s")}


def parameter_words(name: str) -> tuple[str, str]:
    """(words, unit) of a parameter ``identify`` fits (``friction_<tendon>`` included)."""
    return PARAMETER_WORDS.get(name, (f"friction coefficient μ of tendon "
                                      f"{name.partition('_')[2]}", ""))


#: the longest integration step that resolves the damping, in relaxation times τ = 3η/E (a
#: step of τ/3 misses the prototype's length change by 2 %, τ/15 by 0.02 %)
STEP_PER_TAU = 0.2


#: the integration step of a simulation by default, s
MAX_STEP = 2e-3


class NoDampingWarning(UserWarning):
    """Estimation in motion on a robot without ``[rod] damping``: the filter's model is the
    quasi-static one (each sample a step toward the equilibrium), not a moving rod's."""


def warn_no_damping(robot, where: str = "", stacklevel: int = 2) -> None:
    """:class:`NoDampingWarning` where ``robot`` has no damping (``where``: e.g. " in every
    log"), pointing at the caller ``stacklevel`` frames up."""
    if robot.rod.damping <= 0:
        warnings.warn(f"the robot has no [rod] damping: estimation in motion filters the "
                      f"quasi-static model{where}, each sample a step toward the equilibrium "
                      f"(give [rod] damping, Pa·s, or fit it: identify --param damping)",
                      NoDampingWarning, stacklevel=stacklevel + 1)


def coarse_step(robot, max_step: float) -> str | None:
    """Why ``max_step`` is too long to follow the damped rod's relaxation (longer than
    :data:`STEP_PER_TAU` τ, τ = 3η/E), or None (or without damping)."""
    tau = robot.rod.relaxation_time
    if tau > 0 and max_step > STEP_PER_TAU * tau:
        return (f"a step of {max_step:g} s is longer than {STEP_PER_TAU:g} of the rod's "
                f"relaxation time (τ = 3η/E = {tau:.3g} s): the motion is resolved coarsely; "
                f"a step under {STEP_PER_TAU * tau:.3g} s follows it (--max-step; the default "
                f"is {MAX_STEP:g} s), if [rod] damping = {robot.rod.damping:g} is in Pa·s")
    return None
