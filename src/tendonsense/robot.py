"""The robot description: immutable data loaded and validated from a TOML file.

Every bad value raises :class:`RobotFileError` with one line naming the key and the reason.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import re
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from .basis import DEFAULT_DEGREES, MODES
from .rod import Rod

#: a guide disk may hold its tendon at most this many local rod radii from the centre line
REACHABLE_RADIUS_FACTOR = 2.0
#: the longest rod a robot file may describe, m (a longer one is a length in millimetres)
MAX_LENGTH = 10.0
#: the softest Young's modulus, Pa, and the lightest density other than 0, kg/m³, a rod may
#: have (below them a value is in MPa or GPa, or in g/cm³)
MIN_YOUNG_MODULUS = 1e3
MIN_DENSITY = 10.0
#: the densest solid's density, kg/m³ (osmium): a denser rod is a unit slip or a fit to loads
#: in other units
MAX_DENSITY = 22_590.0
#: the largest friction coefficient of a tendon in its guides (a larger one is a percentage)
MAX_FRICTION = 2.0
#: the largest gravitational acceleration, m/s² (a larger one is in other units)
MAX_GRAVITY = 100.0
#: the most guide disks a tendon may pass (closer ones are routed continuously)
MAX_DISKS = 500
#: a tendon's or marker's name: it heads columns and is given as NAME=value
NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.\-]*")


def value_error(name: str, v: float) -> str | None:
    """Why ``v`` cannot be the robot's ``name`` (``young_modulus``, ``poisson_ratio``,
    ``density``, ``damping`` or a tendon's ``friction``), or None; ``v`` is finite."""
    if name == "young_modulus":
        return (f"must be > 0, got {v:g}" if v <= 0 else
                f"{v:g} Pa is softer than any material a rod is made of (under "
                f"{MIN_YOUNG_MODULUS:g} Pa; Young's modulus is in Pa: 1 MPa = 1e6)"
                if v < MIN_YOUNG_MODULUS else None)
    if name == "poisson_ratio":
        return None if -1 < v <= 0.5 else f"must be in (-1, 0.5], got {v:g}"
    if name == "density" and 0 < v < MIN_DENSITY:
        return (f"{v:g} kg/m³ is lighter than any solid (under {MIN_DENSITY:g} kg/m³; "
                f"densities are in kg/m³, water 1000; 0 leaves out the rod's weight)")
    if name == "density" and v > MAX_DENSITY:
        return (f"{v:g} kg/m³ is denser than any solid (osmium: {MAX_DENSITY:g} kg/m³; "
                f"densities are in kg/m³, water 1000)")
    if name == "friction" and v > MAX_FRICTION:
        return (f"{v:g} is more than any tendon's in its guides (at most {MAX_FRICTION:g}; "
                f"a coefficient such as 0.3, not a percentage)")
    return f"must be >= 0, got {v:g}" if v < 0 else None


class RobotFileError(ValueError):
    """A robot file that cannot be used; the message names the key and the reason."""


@dataclass(frozen=True)
class Tendon:
    """A tendon through guide disks at ``disks`` (material abscissae, the last one its anchor),
    or ``continuous``: along the whole rod at its offset (the limit of infinitely many disks;
    ``disks`` is then ``(0, L)``); offset ``d(X) = [0, y, z]`` linear in X from
    ``offset_base`` (X = 0) to ``offset_tip`` (X = L)."""

    name: str
    offset_base: tuple[float, float]
    offset_tip: tuple[float, float]
    friction: float
    disks: tuple[float, ...]
    continuous: bool = False

    def offset(self, X, length: float) -> np.ndarray:
        """Cross-section offset ``[0, y, z]`` at X, shape (n, 3)."""
        t = np.atleast_1d(np.asarray(X, float))[:, None] / length
        yz = (1 - t) * np.array(self.offset_base) + t * np.array(self.offset_tip)
        return np.concatenate([np.zeros((t.shape[0], 1)), yz], axis=1)


@dataclass(frozen=True)
class Marker:
    name: str
    X: float
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Mass:
    """A rigid lumped mass (kg) fixed to the rod at X, its centre at ``offset`` in the
    cross-section frame (a guide ring, a sensor, a gripper)."""

    name: str
    X: float
    mass: float
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Numerics:
    """Discretisation and solver settings (``[solver]`` table)."""

    intervals: int = 16  # uniform Magnus intervals before disks/markers/loads are merged in
    tolerance: float = 1e-10  # relative residual at convergence
    max_iterations: int = 60
    steps_per_element: int = 4  # uniform Magnus intervals per element of an elements basis


@dataclass(frozen=True)
class Robot:
    name: str
    rod: Rod
    strain: tuple[tuple[str, int], ...] = tuple(DEFAULT_DEGREES.items())
    gravity: tuple[float, float, float] = (0.0, 0.0, -9.81)
    base_position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    base_rotation: tuple[tuple[float, ...], ...] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    tendons: tuple[Tendon, ...] = ()
    markers: tuple[Marker, ...] = ()
    numerics: Numerics = Numerics()
    elements: tuple[float, ...] = ()  # interior element bounds; empty: the global basis
    masses: tuple[Mass, ...] = ()

    def __hash__(self) -> int:  # kept: a robot keys the caches consulted on every reading
        if (h := self.__dict__.get("_hash")) is None:
            h = self.__dict__["_hash"] = hash(tuple(getattr(self, f.name)
                                                    for f in dataclasses.fields(self)))
        return h

    def __getstate__(self) -> dict:  # a hash of str fields is per process: not sent on
        return {k: v for k, v in self.__dict__.items() if k not in ("_hash", "geometry")}

    @cached_property
    def geometry(self) -> "Robot":
        """This robot with its material values (Young's modulus, Poisson's ratio, density,
        damping, friction) at 0: what depends on its shape alone is keyed by it, so that
        robots that differ only in those values (:meth:`with_parameters`) share it."""
        return self.replace(
            rod=dataclasses.replace(self.rod, young_modulus=0.0, poisson_ratio=0.0,
                                    density=0.0, damping=0.0),
            tendons=tuple(dataclasses.replace(t, friction=0.0) for t in self.tendons))

    @cached_property
    def tendon_names(self) -> tuple[str, ...]:
        return tuple(t.name for t in self.tendons)

    @cached_property
    def marker_names(self) -> tuple[str, ...]:
        return tuple(m.name for m in self.markers)

    def replace(self, **changes) -> "Robot":
        return dataclasses.replace(self, **changes)

    def with_parameters(self, young_modulus=None, density=None, friction=None,
                        damping=None) -> "Robot":
        """A copy with other material parameters; ``friction`` is one μ for every tendon or a
        ``{tendon: μ}`` mapping for some of them. Each is checked as in a robot file
        (:func:`value_error`)."""
        if isinstance(friction, dict) and (odd := [k for k in friction
                                                   if k not in self.tendon_names]):
            raise ValueError(f"friction {odd[0]}: no such tendon (robot has "
                             f"{', '.join(self.tendon_names)})")
        mus = friction.values() if isinstance(friction, dict) else [friction]
        for k, v in (("young_modulus", young_modulus), ("density", density),
                     ("damping", damping), *(("friction", m) for m in mus)):
            if v is not None and (why := value_error(k, float(v))):
                raise ValueError(f"{k}: {why}")
        rod = self.rod
        if young_modulus is not None:
            rod = dataclasses.replace(rod, young_modulus=float(young_modulus))
        if damping is not None:
            rod = dataclasses.replace(rod, damping=float(damping))
        if density is not None:
            rod = dataclasses.replace(rod, density=float(density))
        tendons = self.tendons
        if friction is not None:
            mu = friction if isinstance(friction, dict) else {t.name: friction for t in tendons}
            tendons = tuple(dataclasses.replace(t, friction=float(mu.get(t.name, t.friction)))
                            for t in tendons)
        return dataclasses.replace(self, rod=rod, tendons=tendons)


# ----------------------------------------------------------------------------- loading

def check_robot(robot) -> Robot:
    """``robot`` if it is a :class:`Robot`, else a ValueError saying how to make one."""
    if not isinstance(robot, Robot):
        raise ValueError(f"robot: a Robot, such as tendonsense.load_robot(path), not a "
                         f"{type(robot).__name__}")
    return robot


def load_robot(path: str | Path) -> Robot:
    """Read and validate a robot file."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")  # (TOML is UTF-8; a BOM is not a key)
    except UnicodeDecodeError as exc:
        raise RobotFileError(f"{path}: not a robot file (TOML is UTF-8 text; byte "
                             f"{exc.start} is not: {exc.reason})") from None
    except OSError as exc:
        why = exc.strerror
        if path.is_symlink() and not path.exists():  # e.g. a folder copied without -L
            why = (f"a symbolic link to {os.readlink(path)}, which does not exist: a folder "
                   f"copied with `cp -r` keeps its links; `cp -rL` copies the files")
        raise RobotFileError(f"{path}: cannot read robot file ({why})") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise RobotFileError(f"{path}: not valid TOML ({exc})") from None
    return parse_robot(data, source=str(path), default_name=path.stem)


def _toml(v) -> str:
    """A value read from the file, spelled as in TOML (``true``, ``"soft"``, ``[1, 2]``)."""
    return json.dumps(v, default=str, ensure_ascii=False)


class _Reader:
    """Typed access to one TOML table with key paths in the error messages."""

    def __init__(self, table: Any, where: str, source: str):
        self.source, self.where = source, where
        if not isinstance(table, dict):
            self.fail("", "must be a table")
        self.table = table

    def fail(self, key: str, reason: str):
        name = f"{self.where}.{key}" if key and self.where else (key or self.where)
        raise RobotFileError(f"{self.source}: {name}: {reason}")

    def check_keys(self, allowed):
        for key in self.table:
            if key not in allowed:
                self.fail(key, f"unknown key (allowed: {', '.join(allowed)})")

    def has(self, key):
        return key in self.table

    def number(self, key, *, default=None, low=None, high=None, low_open=False):
        if key not in self.table:
            if default is None:
                self.fail(key, "missing")
            return default
        return self._number(key, self.table[key], low, high, low_open)

    def _number(self, key, v, low=None, high=None, low_open=False):
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            self.fail(key, f"must be a number, got {_toml(v)}")
        v = float(v)
        if not math.isfinite(v):
            self.fail(key, f"must be finite, got {v}")
        if low is not None and (v <= low if low_open else v < low):
            self.fail(key, f"must be {'>' if low_open else '>='} {low:g}, got {v:g}")
        if high is not None and v > high:
            self.fail(key, f"must be <= {high:g}, got {v:g}" + (
                " (lengths are in metres)" if key == "X" and v > 10 * high else ""))
        return v

    def integer(self, key, *, default=None, low=0, high=None):
        if key not in self.table:
            if default is None:
                self.fail(key, "missing")
            return default
        v = self.table[key]
        if isinstance(v, bool) or not isinstance(v, int):
            self.fail(key, f"must be a whole number, got {_toml(v)}")
        if v < low or (high is not None and v > high):
            self.fail(key, f"must be between {low} and {high}, got {v}" if high is not None
                      else f"must be >= {low}, got {v}")
        return v

    def vector(self, key, n, *, default=None):
        if key not in self.table:
            if default is None:
                self.fail(key, "missing")
            return default
        v = self.table[key]
        if not isinstance(v, list) or len(v) != n:
            self.fail(key, f"must be a list of {n} numbers, got {_toml(v)}")
        return tuple(self._number(key, x) for x in v)

    def name(self, key="name"):
        """A name that can head a column (``tension_<name>``) and be given on the command line
        (``--tension <name>=…``): letters, digits, ``_``, ``-`` and ``.``."""
        v = self.string(key)
        if not NAME.fullmatch(v):
            self.fail(key, f"{_toml(v)}: a name is letters, digits, '_', '-' and '.', not "
                           f"starting with '-' or '.' (it heads columns and is given as "
                           f"NAME=value)")
        return v

    def offset(self, key, length):
        """A point's offset (m, 3) from the rod's centre line, at most the rod's length."""
        v = self.vector(key, 3, default=(0.0, 0.0, 0.0))
        if np.linalg.norm(v) > length:
            self.fail(key, f"{_toml(list(v))} is {np.linalg.norm(v):g} m from the centre line, "
                           f"more than the rod is long ({length:g} m): offsets are in metres")
        return v

    def string(self, key, *, default=None):
        if key not in self.table:
            if default is None:
                self.fail(key, "missing")
            return default
        v = self.table[key]
        if not isinstance(v, str) or not v.strip():
            self.fail(key, f"must be a non-empty string, got {_toml(v)}")
        return v


def parse_robot(data: dict, source: str = "robot", default_name: str = "robot") -> Robot:
    """Validate a parsed robot-file dictionary and build a :class:`Robot`."""
    top = _Reader(data, "", source)
    top.check_keys(("name", "rod", "strain", "gravity", "base", "tendon", "marker", "mass",
                    "solver"))
    name = top.string("name", default=default_name)

    if not top.has("rod"):
        top.fail("rod", "missing table")
    rod = _parse_rod(_Reader(data["rod"], "rod", source))
    L = rod.length

    strain = dict(DEFAULT_DEGREES)
    elements_raw = None
    if top.has("strain"):
        s = _Reader(data["strain"], "strain", source)
        s.check_keys((*MODES, "elements"))
        strain = {m: s.integer(m, high=20) for m in MODES if s.has(m)}
        if not strain:
            s.fail("", "must name at least one strain mode")
        elements_raw = s.table.get("elements")

    gravity = (0.0, 0.0, -9.81)
    if top.has("gravity"):
        g = _Reader(data["gravity"], "gravity", source)
        g.check_keys(("acceleration",))
        gravity = g.vector("acceleration", 3)
        if np.linalg.norm(gravity) > MAX_GRAVITY:
            g.fail("acceleration", f"{np.linalg.norm(gravity):g} m/s² is more than "
                                   f"{MAX_GRAVITY:g} m/s² (accelerations are in m/s²: 9.81)")

    base_position, base_rotation = (0.0, 0.0, 0.0), tuple(map(tuple, np.eye(3).tolist()))
    if top.has("base"):
        b = _Reader(data["base"], "base", source)
        b.check_keys(("position", "rotation"))
        base_position = b.vector("position", 3, default=base_position)
        if b.has("rotation"):
            rows = data["base"]["rotation"]
            if not isinstance(rows, list) or len(rows) != 3:
                b.fail("rotation", "must be 3 rows of 3 numbers")
            base_rotation = tuple(_Reader({"rotation": r}, "base", source).vector("rotation", 3)
                                  for r in rows)
            R = np.array(base_rotation)
            if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
                b.fail("rotation", "must be a rotation matrix (orthonormal rows, determinant +1)")

    tendons = [_parse_tendon(r, rod) for r in _tables(data, "tendon", top)]
    _unique([t.name for t in tendons], "tendon", top)

    markers = []
    for r in _tables(data, "marker", top):
        r.check_keys(("name", "X", "offset"))
        markers.append(Marker(r.name(), r.number("X", low=0.0, high=L), r.offset("offset", L)))
    _unique([m.name for m in markers], "marker", top)

    masses = []
    for r in _tables(data, "mass", top):
        r.check_keys(("name", "X", "mass", "offset"))
        masses.append(Mass(r.string("name"), r.number("X", low=0.0, high=L),
                           r.number("mass", low=0.0, low_open=True), r.offset("offset", L)))
    _unique([m.name for m in masses], "mass", top)

    numerics = Numerics()
    if top.has("solver"):
        s = _Reader(data["solver"], "solver", source)
        s.check_keys(("intervals", "tolerance", "max_iterations", "steps_per_element"))
        numerics = Numerics(
            intervals=s.integer("intervals", default=numerics.intervals, low=2, high=1000),
            tolerance=s.number("tolerance", default=numerics.tolerance, low=0.0, high=1e-3,
                               low_open=True),
            max_iterations=s.integer("max_iterations", default=numerics.max_iterations, low=1,
                                     high=10000),
            steps_per_element=s.integer("steps_per_element",
                                        default=numerics.steps_per_element, low=1, high=100))
    elements = ()
    if elements_raw is not None:
        elements = _parse_elements(_Reader(data["strain"], "strain", source), elements_raw, L,
                                   tendons)
    return Robot(name, rod, tuple(strain.items()), gravity, base_position, base_rotation, tuple(tendons),
                 tuple(markers), numerics, elements, tuple(masses))


def _parse_elements(r: _Reader, raw, L: float, tendons) -> tuple[float, ...]:
    """``elements = "disks"`` (between consecutive disks of any tendon) or a list of X strictly
    inside (0, L): the interior element bounds."""
    if raw == "disks":
        inner = sorted({x for t in tendons for x in t.disks if 1e-9 * L < x < L * (1 - 1e-9)})
        if not inner:
            r.fail("elements", '"disks": no disk lies strictly inside the rod')
        return tuple(inner)
    if not isinstance(raw, list) or not raw:
        r.fail("elements", f'must be "disks" or a list of X inside (0, {L:g}), got {_toml(raw)}')
    X = tuple(r._number("elements", x) for x in raw)
    outside = [x for x in X if not 0.0 < x < L]
    if outside:
        r.fail("elements", f"every element bound must lie strictly inside (0, {L:g}), got "
                           f"{outside[0]:g}")
    if any(b <= a for a, b in zip(X, X[1:])):
        r.fail("elements", "element bounds must be strictly increasing")
    return X


def _tables(data: dict, key: str, top: _Reader) -> list[_Reader]:
    """A reader for every table of the array of tables ``[[key]]``."""
    raw = data.get(key, [])
    if not isinstance(raw, list):
        top.fail(key, f"must be an array of tables ([[{key}]])")
    def named(i, t):  # "tendon[0] (t1)": the index, and the name where the entry has one
        name = t.get("name") if isinstance(t, dict) else None
        return f"{key}[{i}]" + (f" ({name.strip()})" if isinstance(name, str)
                                and name.strip() else "")

    return [_Reader(t, named(i, t), top.source) for i, t in enumerate(raw)]


def _unique(names, what, reader):
    seen = set()
    for n in names:
        if n in seen:
            reader.fail(what, f"two {what}{'es' if what.endswith('s') else 's'} are named "
                              f"{n!r}")
        seen.add(n)


def _parse_rod(r: _Reader) -> Rod:
    r.check_keys(("length", "radius", "young_modulus", "poisson_ratio", "density",
                  "disk_radius", "damping"))
    L = r.number("length", low=0.0, low_open=True)
    if L > MAX_LENGTH:
        r.fail("length", f"{L:g} m is longer than any rod this models ({MAX_LENGTH:g} m; "
                         f"lengths are in metres)")
    if not r.has("radius"):
        r.fail("radius", "missing")
    raw = r.table["radius"]
    if not isinstance(raw, list) or len(raw) < 2:
        r.fail("radius", "must be [base, tip] or a list of [X, r] pairs")
    if all(isinstance(p, list) for p in raw):
        knots = [_Reader({"radius": p}, "rod", r.source).vector("radius", 2) for p in raw]
        X = [k[0] for k in knots]
        if abs(X[0]) > 1e-12 or abs(X[-1] - L) > 1e-9 * max(L, 1):
            r.fail("radius", f"[X, r] pairs must run from X = 0 to X = length = {L:g}")
        if any(b <= a for a, b in zip(X, X[1:])):
            r.fail("radius", "X of the [X, r] pairs must be strictly increasing")
        knots = [(x, rr) for x, rr in knots]
        knots[-1] = (L, knots[-1][1])
    else:
        rb, rt = r.vector("radius", 2)
        knots = [(0.0, rb), (L, rt)]
    if any(rr <= 0 for _, rr in knots):
        bad = next(rr for _, rr in knots if rr <= 0)
        r.fail("radius", f"every radius must be > 0, got {bad:g}")
    widest = max(rr for _, rr in knots)
    if widest > L / 2:
        r.fail("radius", f"{widest:g} m is more than half the rod's length ({L:g} m): the "
                         f"model is a slender rod (lengths are in metres)")
    disk_radius = r.number("disk_radius", low=0.0, low_open=True) if r.has("disk_radius") else None
    if disk_radius is not None and disk_radius < widest:
        r.fail("disk_radius", f"spacer disks ({disk_radius:g} m) must be at least as wide as "
                              f"the rod ({widest:g} m)")
    if disk_radius is not None and disk_radius > L / 2:
        r.fail("disk_radius", f"{disk_radius:g} m is more than half the rod's length ({L:g} m): "
                              f"spacer disks of a slender rod (lengths are in metres)")
    material = {k: r.number(k, default=0.0 if k == "damping" else None)
                for k in ("young_modulus", "poisson_ratio", "density", "damping")}
    for k, v in material.items():
        if why := value_error(k, v):
            r.fail(k, why)
    return Rod(L, tuple(knots), material["young_modulus"], material["poisson_ratio"],
               material["density"], disk_radius, material["damping"])


def _parse_tendon(r: _Reader, rod: Rod) -> Tendon:
    r.check_keys(("name", "offset_base", "offset_tip", "friction", "disks"))
    name = r.name()
    ob, ot = r.vector("offset_base", 2), r.vector("offset_tip", 2)
    mu = r.number("friction", default=0.0)
    if why := value_error("friction", mu):
        r.fail("friction", why)
    if not r.has("disks"):
        r.fail("disks", "missing (a count, or a list of X)")
    raw = r.table["disks"]
    L = rod.length
    continuous = raw == "continuous"
    if continuous:
        disks = (0.0, L)
    elif isinstance(raw, int) and not isinstance(raw, bool):
        if not 2 <= raw <= MAX_DISKS:
            r.fail("disks", f"must be at least 2 disks, got {raw}" if raw < 2 else
                   f'{raw} disks, more than {MAX_DISKS} (disks = "continuous" is the limit of '
                   f'many closely spaced disks)')
        disks = tuple(np.linspace(0.0, L, raw).tolist())
    elif isinstance(raw, list):
        if len(raw) < 2:
            r.fail("disks", "must list at least 2 disk positions")
        disks = tuple(r._number("disks", x) for x in raw)
        outside = [x for x in disks if x < 0 or x > L * (1 + 1e-12)]
        if outside:
            r.fail("disks", f"every disk X must lie in [0, {L:g}], got {outside[0]:g}")
        if any(b <= a for a, b in zip(disks, disks[1:])):
            r.fail("disks", "disk positions must be strictly increasing")
    else:
        r.fail("disks", f'must be a count, a list of X or "continuous", got {_toml(raw)}')
    if len(disks) > MAX_DISKS:
        r.fail("disks", f'{len(disks)} disks, more than {MAX_DISKS} (disks = "continuous" is '
                        f'the limit of many closely spaced disks)')
    t = Tendon(name, ob, ot, mu, disks, continuous)
    _check_reach(r, t, rod)
    return t


def _check_reach(r: _Reader, t: Tendon, rod: Rod):
    """A tendon's offset must lie on the spacer disks (``rod.disk_radius``) or, without them,
    within :data:`REACHABLE_RADIUS_FACTOR` local rod radii (a tendon inside the body)."""
    L = rod.length
    X = np.linspace(0.0, L, 201) if t.continuous else np.array(t.disks)
    offset = np.linalg.norm(t.offset(X, L), axis=1)
    limit = (np.full_like(X, rod.disk_radius) if rod.disk_radius is not None
             else REACHABLE_RADIUS_FACTOR * rod.radius(X))
    worst = int(np.argmax(offset / limit))
    if offset[worst] <= limit[worst] * (1 + 1e-12):
        return
    key = "offset_base" if offset[0] / limit[0] >= offset[-1] / limit[-1] else "offset_tip"
    varies = np.ptp(offset / limit) > 1e-9 * offset[worst] / limit[worst]
    where = f" at X = {X[worst]:g} m" if varies else ""
    if rod.disk_radius is not None:
        r.fail(key, f"tendon {t.name!r} sits {offset[worst]:g} m from the centre line{where}, "
                    f"beyond the spacer disks (rod.disk_radius = {rod.disk_radius:g} m)")
    r.fail(key, f"tendon {t.name!r} sits {offset[worst]:g} m from the centre line{where}, "
                f"outside the reachable radius of a tendon inside the body "
                f"({REACHABLE_RADIUS_FACTOR:g} rod radii = {limit[worst]:g} m); for spacer disks "
                f"wider than the rod, set rod.disk_radius")


# ----------------------------------------------------------------------------- writing

def robot_to_toml(robot: Robot) -> str:
    """Serialise a robot back to the robot-file format."""
    f = repr
    rod = robot.rod
    lines = [f"name = {_q(robot.name)}", "", "[rod]", f"length = {f(rod.length)}"]
    if len(rod.radius_knots) == 2:
        lines.append(f"radius = [{f(rod.radius_knots[0][1])}, {f(rod.radius_knots[1][1])}]")
    else:
        lines.append("radius = [" + ", ".join(f"[{f(x)}, {f(r)}]" for x, r in rod.radius_knots) + "]")
    lines += [f"young_modulus = {f(rod.young_modulus)}", f"poisson_ratio = {f(rod.poisson_ratio)}",
              f"density = {f(rod.density)}"]
    if rod.disk_radius is not None:
        lines.append(f"disk_radius = {f(rod.disk_radius)}")
    if rod.damping:
        lines.append(f"damping = {f(rod.damping)}")
    lines += ["", "[strain]"]
    lines += [f"{m} = {d}" for m, d in robot.strain]
    if robot.elements:
        lines.append(f"elements = {_vec(robot.elements)}")
    lines += ["", "[gravity]", f"acceleration = {_vec(robot.gravity)}", "", "[base]",
              f"position = {_vec(robot.base_position)}",
              "rotation = [" + ", ".join(_vec(r) for r in robot.base_rotation) + "]", "",
              "[solver]", f"intervals = {robot.numerics.intervals}",
              f"tolerance = {f(robot.numerics.tolerance)}",
              f"max_iterations = {robot.numerics.max_iterations}",
              f"steps_per_element = {robot.numerics.steps_per_element}"]
    for t in robot.tendons:
        lines += ["", "[[tendon]]", f"name = {_q(t.name)}", f"offset_base = {_vec(t.offset_base)}",
                  f"offset_tip = {_vec(t.offset_tip)}", f"friction = {f(t.friction)}",
                  'disks = "continuous"' if t.continuous else f"disks = {_vec(t.disks)}"]
    for m in robot.markers:
        lines += ["", "[[marker]]", f"name = {_q(m.name)}", f"X = {f(m.X)}", f"offset = {_vec(m.offset)}"]
    for m in robot.masses:
        lines += ["", "[[mass]]", f"name = {_q(m.name)}", f"X = {f(m.X)}", f"mass = {f(m.mass)}",
                  f"offset = {_vec(m.offset)}"]
    return "\n".join(lines) + "\n"


def _vec(v) -> str:
    return "[" + ", ".join(repr(float(x)) for x in v) + "]"


def _q(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'


#: the first line of the header :func:`fitted_toml` writes, as the ``identify`` command words it
FITTED_HEADER_MARK = "# fitted by tendonsense identify"


def fitted_toml(text: str, fitted: Robot, header: Sequence[str]) -> str:
    """The robot file ``text`` with the values of ``fitted`` written in place: ``[rod]``
    ``young_modulus``, ``density``, ``poisson_ratio``, ``damping`` and each ``[[tendon]]``'s
    ``friction``
    (matched by the tendon's ``name``) become ``repr(float(value))``; every other byte -- keys,
    comments (also a trailing one on a rewritten line, kept at its column when it was
    aligned), blank lines, order -- stays as it was. A value already equal to the fitted one
    keeps its spelling. A key the file leaves out is added after the last key line of its
    table unless the fitted value is the loader's default (friction and damping 0). ``header`` lines go
    on top as ``# `` comments and a blank line, replacing the block of an earlier fit (comment
    lines from a first line starting with :data:`FITTED_HEADER_MARK`).

    The result is checked: it parses to the original file's data with exactly those values
    changed. Raises :class:`RobotFileError` when ``text`` is not valid TOML, when its tendons
    are not those of ``fitted``, or when a value cannot be rewritten in place (e.g. one given
    in an inline table).
    """
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise RobotFileError(f"robot file: not valid TOML ({exc})") from None
    nl = "\r\n" if "\r\n" in text else "\n"

    # the values to write: key path -> (value, the loader's default or None)
    rod = fitted.rod
    wanted: dict[tuple, tuple[float, float | None]] = {
        ("rod", "young_modulus"): (rod.young_modulus, None),
        ("rod", "poisson_ratio"): (rod.poisson_ratio, None),
        ("rod", "density"): (rod.density, None),
        ("rod", "damping"): (rod.damping, 0.0)}
    entries = data.get("tendon", [])
    if not isinstance(entries, list) or not all(isinstance(e, dict) for e in entries):
        raise RobotFileError("robot file: tendon: must be an array of tables ([[tendon]])")
    in_file = [e.get("name") for e in entries]
    by_name = {t.name: t for t in fitted.tendons}
    if sorted(map(str, in_file)) != sorted(by_name) or len(set(in_file)) != len(in_file):
        raise RobotFileError(f"robot file: its tendons {in_file} are not those of the fitted "
                             f"robot {sorted(by_name)}")
    for i, name in enumerate(in_file):
        wanted[("tendon", i, "friction")] = (by_name[name].friction, 0.0)  # as _parse_tendon

    def lookup(tree, path):
        for k in path:
            if isinstance(tree, dict) and k in tree or isinstance(tree, list) and isinstance(
                    k, int) and k < len(tree):
                tree = tree[k]
            else:
                return None
        return tree

    def same(old, value):
        return isinstance(old, (int, float)) and not isinstance(old, bool) and old == float(value)

    try:
        stmts = _toml_statements(text)
    except (IndexError, ValueError):
        raise RobotFileError("robot file: cannot follow its layout to rewrite it in place") from None
    keys = [st for st in stmts if st["kind"] == "key"]
    n = len(text)
    edits = []  # (start, end, replacement) in the original text
    for path, (value, default) in wanted.items():
        value = float(value)
        if not math.isfinite(value):
            raise RobotFileError(f"fitted {'.'.join(map(str, path))} is {value}")
        new = repr(value)
        old = lookup(data, path)
        if old is not None:
            if same(old, value):
                continue  # unchanged: keep the file's spelling
            here = [st for st in keys if st["path"] == path]
            if len(here) != 1:
                raise RobotFileError(f"robot file: cannot rewrite {'.'.join(map(str, path))} "
                                     f"in place (not a key line of its own)")
            st = here[0]
            vs, ve = st["value"]
            after = ve
            while after < n and text[after] == " ":
                after += 1
            if after < n and text[after] == "#" and after - ve >= 2:  # keep the comment column
                edits.append((vs, after, new + " " * max(2, after - vs - len(new))))
            else:
                edits.append((vs, ve, new))
            continue
        if default is not None and value == default:
            continue  # the loader's default: no line needed
        table, key = path[:-1], path[-1]
        # the last key line inside that table, written where the new key can follow it
        at = [st for st in keys
              if st["path"][:len(table)] == table and table[:len(st["table"])] == st["table"]]
        if at:
            st = at[-1]
            rel = path[len(st["table"]):]
            indent = st["indent"]
        else:
            at = [st for st in stmts if st["kind"] == "table" and st["table"] == table]
            if not at:
                raise RobotFileError(f"robot file: no table to add {'.'.join(map(str, path))} to")
            st, rel, indent = at[-1], (key,), ""
        line = indent + ".".join(k if k and all(c in _BARE_KEY for c in k) else _q(k)
                                 for k in rel) + " = " + new
        end = st["end"]
        edits.append((end, end, line + nl if text[end - 1:end] == "\n" else nl + line))

    out, pos = [], 0
    for start, end, rep in sorted(edits, key=lambda e: e[0]):
        out += [text[pos:start], rep]
        pos = end
    body = "".join(out) + text[pos:]

    # an earlier fit's header: its comment lines and the blank line after them
    pos = 0
    if body.startswith(FITTED_HEADER_MARK):
        while pos < len(body) and body[pos:].lstrip(" \t").startswith("#"):
            eol = body.find("\n", pos)
            pos = len(body) if eol < 0 else eol + 1
        eol = body.find("\n", pos)
        if eol >= 0 and not body[pos:eol].strip():
            pos = eol + 1
    body = body[pos:]
    lines = []
    for item in header:
        for part in str(item).splitlines() or [""]:
            part = "".join(c if c == "\t" or (ord(c) >= 0x20 and c != "\x7f") else "?"
                           for c in part).rstrip()
            lines.append("# " + part if part else "#")
    result = (nl.join(lines) + nl + nl + body) if lines else body

    expected = tomllib.loads(text)  # a fresh copy of the original data
    for path, (value, default) in wanted.items():
        old = lookup(expected, path)
        if old is None and default is not None and float(value) == default:
            continue
        if old is not None and same(old, value):
            continue
        lookup(expected, path[:-1])[path[-1]] = float(value)
    try:
        got = tomllib.loads(result)
    except tomllib.TOMLDecodeError:
        got = None
    if got != expected:
        raise RobotFileError("robot file: rewriting it in place did not give the fitted values "
                             "(an unusual layout); write it with robot_to_toml instead")
    return result


_BARE_KEY = frozenset("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789_-")


def _toml_statements(s: str) -> list[dict]:
    """The statements of valid TOML text ``s`` in order, each a dict: ``kind`` ("key", "table",
    "blank" or "comment"), ``start`` and ``end`` (offsets of its first character and past its
    line end), ``table`` (the path of the table it is in or opens: keys, and for an array of
    tables the index of the entry, e.g. ``("tendon", 2)``); a key line also has ``path`` (the
    full key path), ``value`` (the offsets of its value) and ``indent``."""
    n = len(s)

    def ws(i):
        while i < n and s[i] in " \t":
            i += 1
        return i

    def gap(i):  # whitespace, newlines and comments (inside arrays)
        while True:
            i = ws(i)
            if i < n and s[i] == "#":
                while i < n and s[i] != "\n":
                    i += 1
            if i < n and s[i] in "\r\n":
                i += 1
            else:
                return i

    def line_end(i):
        i = ws(i)
        if i < n and s[i] == "#":
            while i < n and s[i] != "\n":
                i += 1
        if i < n and s[i] == "\r":
            i += 1
        if i < n and s[i] == "\n":
            return i + 1
        if i < n:
            raise ValueError(f"unexpected {s[i]!r} at offset {i}")
        return i

    def string_end(i):
        q = s[i]
        if s.startswith(q * 3, i):
            j = i + 3
            while True:
                if q == '"' and s[j] == "\\":
                    j += 2
                elif s[j] == q:
                    k = j
                    while k < n and s[k] == q:
                        k += 1
                    if k - j >= 3:
                        return k
                    j = k
                else:
                    j += 1
        j = i + 1
        while s[j] != q:
            j += 2 if q == '"' and s[j] == "\\" else 1
        return j + 1

    def key(i):
        parts = []
        while True:
            i = ws(i)
            if s[i] in "\"'":
                j = string_end(i)
                parts.append(next(iter(tomllib.loads(s[i:j] + " = 0"))))
            else:
                j = i
                while j < n and s[j] in _BARE_KEY:
                    j += 1
                if j == i:
                    raise ValueError(f"no key at offset {i}")
                parts.append(s[i:j])
            i = ws(j)
            if i < n and s[i] == ".":
                i += 1
            else:
                return tuple(parts), i

    def value(i):
        c = s[i]
        if c in "\"'":
            return string_end(i)
        if c in "[{":
            close, i = "]" if c == "[" else "}", i + 1
            while True:
                i = gap(i)
                if s[i] == close:
                    return i + 1
                if close == "}":
                    i = ws(key(i)[1])
                    if s[i] != "=":
                        raise ValueError(f"no '=' at offset {i}")
                    i = gap(i + 1)
                i = gap(value(i))
                if s[i] == ",":
                    i += 1
        j = i
        while j < n and s[j] not in " \t\r\n,]}#":
            j += 1
        word = s[i:j]  # a local date and time may use a space: 1979-05-27 07:32:00
        if (len(word) == 10 and word[4] == word[7] == "-" and s[j:j + 1] == " "
                and s[j + 1:j + 2].isdigit()):
            j += 1
            while j < n and s[j] not in " \t\r\n,]}#":
                j += 1
        return j

    out, table, counts, i = [], (), {}, 0
    while i < n:
        j = ws(i)
        if j >= n or s[j] in "\r\n#":
            end = line_end(j)
            out.append(dict(kind="comment" if j < n and s[j] == "#" else "blank", start=i,
                            end=end, table=table))
        elif s[j] == "[":
            array = s.startswith("[[", j)
            path, k = key(j + (2 if array else 1))
            close = "]]" if array else "]"
            if not s.startswith(close, k):
                raise ValueError(f"no {close!r} at offset {k}")
            if array:
                counts[path] = counts.get(path, 0) + 1
                table = path + (counts[path] - 1,)
            else:
                table = path
            end = line_end(k + len(close))
            out.append(dict(kind="table", start=i, end=end, table=table))
        else:
            path, k = key(j)
            if s[k] != "=":
                raise ValueError(f"no '=' at offset {k}")
            vs = ws(k + 1)
            ve = value(vs)
            end = line_end(ve)
            out.append(dict(kind="key", start=i, end=end, table=table, path=table + path,
                            value=(vs, ve), indent=s[i:j]))
        i = end
    return out
