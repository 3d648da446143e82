"""CSV files of readings — a log of tendon readings, calibration snapshots — checked by the
rules of :mod:`tendonsense.inputs`, and the estimation output written atomically. No JAX: a
file is checked before any solver starts (estimation over a log: :mod:`tendonsense.logs`)."""

from __future__ import annotations

import csv
import io
import math
import os
import secrets
import stat
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from .inputs import (SLIDING, Unknown, displacement_error, force_error, marker_error,
                     max_tension, outside_rod, rest_lengths, stuck_error,
                     stuck_located_error, tension_error)
from .result import SampleEstimate
from .robot import Robot, check_robot, value_error

AXES = ("x", "y", "z")


def _number(text: str) -> float:
    """The number in a CSV cell, NaN if it is not one."""
    try:
        return float(text)
    except ValueError:
        return math.nan


def _not_finite(col: str, text: str) -> str:
    """Why a cell that holds no finite number is refused: missing, not a number at all, or a
    number that is not finite (``nan``, ``inf``)."""
    if not text.strip():
        return f"column {col}: missing value"
    try:
        float(text)
    except ValueError:
        return f"column {col}: {text.strip()!r} is not a number"
    return f"column {col}: {text.strip()!r} is not a finite number"


class ReadingsError(ValueError):
    """A readings file that cannot be used at all (bad header, unreadable)."""


def _once(source, header: Sequence[str], error: type[Exception]) -> None:
    """No column of ``header`` twice (a dict of the row would keep one silently)."""
    twice = [h for k, h in enumerate(header) if h in header[:k]]
    if twice:
        raise error(f"{source}: column {twice[0]!r} appears twice")


def no_such(source, col: str, robot: Robot, kinds=("tension", "displacement", "sliding"),
            markers: bool = True) -> str | None:
    """The message for a column ``<kind>_<name>`` whose tendon (or, with ``markers``,
    ``marker_<name>_<axis>`` whose marker) the robot does not have, naming those it has; None
    for any other column."""
    kind, _, name = col.partition("_")
    if kind in kinds and name not in robot.tendon_names:
        return (f"{source}: column {col!r}: no tendon {name!r} in the robot (its tendons: "
                f"{', '.join(robot.tendon_names) or 'none'})")
    if markers and kind == "marker" and name[-2:] in ("_x", "_y", "_z") and \
            name[:-2] not in robot.marker_names:
        return (f"{source}: column {col!r}: no marker {name[:-2]!r} in the robot (its "
                f"markers: {', '.join(robot.marker_names) or 'none'})")
    return None


@dataclass(frozen=True)
class Sample:
    """One row of a readings file; ``error`` names the bad column of a row that is skipped."""

    row: int  # 1-based data row number (the header is row 0)
    time: float | None
    tensions: dict[str, float]
    displacements: dict[str, float]
    markers: dict[str, np.ndarray]
    error: str | None = None
    sliding: dict[str, str] = field(default_factory=dict)  # tendon -> in|out|stuck, if given


def read_csv_rows(path: Path, error: type[Exception]) -> list[list[str]]:
    """All rows of a CSV file (UTF-8, with or without the byte-order mark a spreadsheet
    writes); an unreadable file raises ``error`` naming it."""
    try:
        with open(path, newline="", encoding=CSV_ENCODING) as fh:
            return list(csv.reader(fh))
    except OSError as exc:
        raise error(f"{path}: cannot read ({exc.strerror})") from None
    except UnicodeDecodeError:
        raise error(f"{path}: {NOT_UTF8}") from None


#: how CSV files are read: UTF-8, a leading byte-order mark dropped
CSV_ENCODING = "utf-8-sig"
#: what a stream that is not UTF-8 is told (its bytes read as ``surrogateescape``)
NOT_UTF8 = "not UTF-8 text: save it as CSV in UTF-8"


def utf8(cells: Sequence[str]) -> bool:
    """Whether cells read with ``errors="surrogateescape"`` were UTF-8 (no escaped byte)."""
    text = "".join(cells)
    if text.isascii():
        return True
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


@dataclass(frozen=True)
class Columns:
    """The columns of a readings log: which tendons are measured, which markers given."""

    header: list[str]
    measured: list[str]
    markers: list[str]
    rest: np.ndarray = field(default_factory=lambda: np.zeros(0))  # tendons' lengths, m
    top: np.ndarray = field(default_factory=lambda: np.zeros(0))  # tendons' largest tensions, N


def check_separator(source, header: Sequence[str], error: type[Exception]) -> None:
    """A header read as one column that holds a semicolon, a tab or a bar (a spreadsheet's
    other CSV) raises ``error`` saying so, not that the one long column is unknown."""
    if len(header) == 1 and (sep := next((c for c in ";\t|" if c in header[0]), None)):
        raise error(f"{source}: header: columns are separated by commas, this one by "
                    f"{'tabs' if sep == chr(9) else repr(sep)} ({header[0].strip()[:40]!r}…)")


def parse_header(header: Sequence[str], robot: Robot, source) -> Columns:
    """Check the header of READINGS.csv: ``time`` (optional), ``tension_<name>``,
    ``displacement_<name>``, optional ``marker_<name>_x/_y/_z``."""
    header = [h.strip() for h in header]
    if not utf8(header):
        raise ReadingsError(f"{source}: header: {NOT_UTF8}")
    tendons, markers = robot.tendon_names, robot.marker_names
    check_separator(source, header, ReadingsError)
    _once(source, header, ReadingsError)
    measured = []
    for col in header:
        kind, _, name = col.partition("_")
        if col == "time":
            continue
        if why := no_such(source, col, robot):
            raise ReadingsError(why)
        if kind == "sliding":
            continue
        if kind in ("tension", "displacement"):
            if kind == "displacement":
                measured.append(name)
        elif kind == "marker" and name[-2:] in ("_x", "_y", "_z") and name[:-2] in markers:
            continue
        else:
            raise ReadingsError(f"{source}: column {col!r} is not time, tension_<tendon>, "
                                f"displacement_<tendon>, sliding_<tendon> or "
                                f"marker_<marker>_x/_y/_z")
    if not measured:
        raise ReadingsError(f"{source}: no displacement_<tendon> column")
    missing = [f"tension_{n}" for n in tendons if f"tension_{n}" not in header]
    if missing:
        raise ReadingsError(f"{source}: no column {', '.join(missing)}: every tendon's tension "
                            f"is a reading (a slack tendon is a column of zeros)")
    marker_names = [m for m in markers if f"marker_{m}_x" in header]
    for m in marker_names:
        for a in AXES:
            if f"marker_{m}_{a}" not in header:
                raise ReadingsError(f"{source}: marker {m!r} needs columns _x, _y and _z")
    return Columns(header, measured, marker_names, rest_lengths(robot),
                   np.array([max_tension(robot, name) for name in tendons]))


def parse_row(i: int, raw: Sequence[str], columns: Columns, robot: Robot) -> Sample:
    """One data row (1-based ``i``); a bad one is returned with ``error`` set."""
    header = columns.header
    values, sliding, error = {}, {}, None
    if [c.strip().lstrip("\ufeff") for c in raw] == list(header):
        error = "the header again (logs joined end to end?)"
    elif len(raw) != len(header):
        error = f"has {len(raw)} fields, the header has {len(header)}"
    elif not utf8(raw):
        error = NOT_UTF8
    else:
        for col, text in zip(header, raw):
            if col.startswith("sliding_"):  # an empty cell: the direction is not known here
                if not text.strip():
                    continue
                sliding[col[8:]] = text.strip().lower()
                if sliding[col[8:]] not in SLIDING:
                    error = (f"column {col}: {text.strip()!r} is not "
                             f"{', '.join(SLIDING[:-1])} or {SLIDING[-1]}")
                    break
                continue
            if col.startswith("marker_") and not text.strip():  # a frame the camera missed
                continue
            v = _number(text)
            if not math.isfinite(v):
                error = _not_finite(col, text)
                break
            kind, _, name = col.partition("_")
            if kind == "tension" and not 0 <= v <= columns.top[robot.tendon_names.index(name)]:
                error = tension_error(robot, name, v)
            elif kind == "displacement" and not abs(v) < (
                    rest := columns.rest[robot.tendon_names.index(name)]):
                error = displacement_error(name, v, rest)
            if error:
                break
            values[col] = v
    seen = [m for m in columns.markers if any(f"marker_{m}_{a}" in values for a in AXES)]
    for m in seen:
        if not error and (gone := [a for a in AXES if f"marker_{m}_{a}" not in values]):
            error = (f"column marker_{m}_{gone[0]}: missing value (a marker has its x, y and "
                     f"z, or none where the camera missed it)")
        if not error:
            error = marker_error(robot, m, [values[f"marker_{m}_{a}"] for a in AXES])
    for name, d in sliding.items():
        if d == "stuck" and not error:
            error = stuck_error(name, values.get(f"tension_{name}", 0.0),
                                f"column sliding_{name}: stuck", robot.tendons[
                                    robot.tendon_names.index(name)].friction)
    if error:  # its time stamp kept where it can be read
        t = _number(raw[header.index("time")]) if "time" in header and header.index(
            "time") < len(raw) else math.nan
        return Sample(i, t if math.isfinite(t) else None, {}, {}, {}, error)
    return Sample(
        i, values.get("time"),
        {n: values[f"tension_{n}"] for n in robot.tendon_names if f"tension_{n}" in values},
        {n: values[f"displacement_{n}"] for n in columns.measured},
        {m: np.array([values[f"marker_{m}_{a}"] for a in AXES]) for m in seen},
        sliding=sliding)


def read_readings(path: str | Path, robot: Robot) -> tuple[list[str], list[Sample]]:
    """Parse READINGS.csv (:func:`parse_header`, :func:`parse_row`). Returns (measured tendon
    names, samples)."""
    path, robot = Path(path), check_robot(robot)
    rows = read_csv_rows(path, ReadingsError)
    if not rows:
        raise ReadingsError(f"{path}: empty file, expected a header row")
    columns = parse_header(rows[0], robot, path)
    check_units(path, columns, robot, rows[1:])
    samples = [parse_row(i, raw, columns, robot) for i, raw in enumerate(rows[1:], start=1)
               if any(c.strip() for c in raw)]
    if not samples:
        raise ReadingsError(f"{path}: no data rows below the header")
    for name in robot.tendon_names:  # a column's slip, not a row's
        said = f"column sliding_{name}: stuck"
        slack = [s for s in samples if (s.error or "").startswith(said)]
        if len(slack) >= 3 and len(slack) > len(samples) / 2:
            raise ReadingsError(f"{path}: column sliding_{name}: {len(slack)} of "
                                f"{len(samples)} rows say stuck where {name} is slack (0 N): "
                                f"only a tendon under tension sticks")
    if error := time_order_error(path, samples):
        raise ReadingsError(error)
    return columns.measured, samples


def stuck_rows_error(source, samples: Sequence[Sample]) -> str | None:
    """Why a log whose rows say a tendon is stuck cannot be estimated with a force of unknown
    location (:func:`~tendonsense.inputs.stuck_located_error`, its first such row), or
    None."""
    for s in samples:
        name = next((n for n, d in s.sliding.items() if d == "stuck"), None)
        if name is not None and not s.error:
            return f"{source}: row {s.row}: " + stuck_located_error(
                name, f"column sliding_{name}: stuck")
    return None


def time_order_error(source, samples: Sequence[Sample]) -> str | None:
    """Why a log's rows are not in time order (a row stamped before the row before it, e.g.
    two logs joined), or None: its rows are estimated in their order, each tendon's friction
    following them."""
    rows = [s for s in samples if s.time is not None and not s.error]
    for a, b in zip(rows, rows[1:]):
        if back := time_back(b.time, a.time):
            return (f"{source}: row {b.row}: {back}: a log's rows must be in time order (each "
                    f"tendon's friction follows them); sort the rows or split the log")
    return None


def time_back(time: float, last: float | None, once: bool = False) -> str | None:
    """Why a row stamped ``time`` cannot follow one stamped ``last`` (None: it can); ``once``:
    nor have the same stamp (a motion's rule)."""
    if last is not None and time < last:
        return f"time {time:g} s is before the row before ({last:g} s)"
    if once and time == last:
        return f"time {time:g} s is the row before's: a motion's rows each have their own stamp"
    return None


def check_units(path, columns: Columns, robot: Robot, rows):
    """A length column most of whose rows change the tendon by more than its whole length, a
    tension column most of whose rows would crush the rod, or a marker most of whose rows are
    farther from the base than it can be, is in the wrong unit; a sliding column most of whose
    rows are no direction is in another vocabulary: the log is refused (its rows would each
    be skipped, or worse, the few that pass estimated)."""
    def values(col):
        k = columns.header.index(col)
        v = np.array([_number(r[k]) for r in rows if len(r) == len(columns.header)])
        return v[np.isfinite(v)]

    for name in robot.tendon_names:
        if f"tension_{name}" not in columns.header:
            continue
        v = values(f"tension_{name}")
        over = v[(v >= 0) & (v > columns.top[robot.tendon_names.index(name)])]
        if over.size >= 3 and over.size > v.size / 2:
            raise ReadingsError(f"{path}: column tension_{name}: {over.size} of {v.size} rows "
                                f"break the rule for a tension, such as "
                                f"{tension_error(robot, name, float(over[0]))}")
    for col in (c for c in columns.header if c.startswith("sliding_")):
        k = columns.header.index(col)
        words = [r[k].strip().lower() for r in rows if len(r) == len(columns.header)]
        bad = [w for w in words if w and w not in SLIDING]
        if len(bad) >= 3 and len(bad) > len(words) / 2:
            raise ReadingsError(f"{path}: column {col}: {len(bad)} of {len(words)} rows are "
                                f"not {', '.join(SLIDING[:-1])} or {SLIDING[-1]} (such as "
                                f"{bad[0]!r})")
    for name in columns.measured:
        rest = columns.rest[robot.tendon_names.index(name)]
        v = values(f"displacement_{name}")
        over = int(np.count_nonzero(np.abs(v) >= rest))
        if over >= 3 and over > v.size / 2:
            raise ReadingsError(
                f"{path}: column displacement_{name}: {over} of {v.size} rows change the "
                f"tendon by more than its whole length ({rest:.3g} m): lengths are in metres")
    for m in columns.markers:
        k = [columns.header.index(f"marker_{m}_{a}") for a in AXES]
        read = [p for p in ([_number(r[j]) for j in k] for r in rows
                            if len(r) == len(columns.header)) if np.all(np.isfinite(p))]
        why = [e for e in (marker_error(robot, m, p) for p in read) if e]
        if len(why) >= 3 and len(why) > len(read) / 2:
            raise ReadingsError(f"{path}: marker {m}: {len(why)} of {len(read)} rows are "
                                f"off the robot, such as: {why[0]}")


#: rows of a log in motion are less than this far apart (median, s): as far, a rod settles
#: between them (the damped prototype within 0.1 s), and time stamps so far apart are taken
#: to be in another unit (a 1 kHz log stamped in ms: 1 apart)
MAX_MOTION_STEP = 1.0


def motion_step_error(source, samples: Sequence[Sample],
                      static: str = " (a static log is estimated without --dynamic)"
                      ) -> str | None:
    """Why the time stamps of ``samples`` cannot be those of a motion, or None: a row whose
    stamp is not after the row before's, or rows :data:`MAX_MOTION_STEP` or more apart (the
    median); ``static`` says what to do with a log that is no motion."""
    rows = [s for s in samples if s.time is not None and not s.error]
    t = np.array([s.time for s in rows], float)
    if np.any(np.diff(t) <= 0):
        k = int(np.argmax(np.diff(t) <= 0)) + 1
        return (f"{source}: row {rows[k].row}: time {t[k]:g} s does not follow the row before "
                f"({t[k - 1]:g} s): a motion's rows must be in time order, each stamp once")
    step = float(np.median(np.diff(t))) if t.size > 1 else 0.0
    if step >= MAX_MOTION_STEP:
        return (f"{source}: rows {step:g} s apart (the median): a rod settles within a second, "
                f"so the time stamps are not seconds (milliseconds?) or the log is not a "
                f"motion{static}")
    return None


def has_time(path: str | Path) -> bool:
    """Whether a readings log's header has a ``time`` column (False for a file that is not
    text: its reading says why)."""
    try:
        with open(path, newline="", encoding=CSV_ENCODING) as fh:
            return "time" in [c.strip() for c in next(csv.reader(fh), [])]
    except UnicodeDecodeError:
        return False


def log_outputs(logs: Sequence[str | Path], out_dir: str | Path) -> list[Path]:
    """The output file of each of many logs: ``out_dir`` / the log's own name. A ValueError
    if two logs share a name or an output would overwrite a log."""
    outs = [Path(out_dir) / Path(log).name for log in logs]
    seen: dict[Path, str | Path] = {}
    for log, out in zip(logs, outs):
        if out in seen:
            raise ValueError(f"{seen[out]} and {log}: two logs of the same name would write "
                             f"the same output {out}")
        seen[out] = log
    inputs = {Path(log).resolve() for log in logs}
    for log, out in zip(logs, outs):
        if out.resolve() in inputs:
            raise ValueError(f"{log}: its output {out} would overwrite a log (choose another "
                             f"output folder)")
    return outs


DESCRIPTIVE = ("source", "note", "comment", "time", "id", "name")


class SnapshotError(ValueError):
    """Snapshots that cannot identify what was asked; the message says why."""


@dataclass(frozen=True)
class Snapshot:
    """One static pose: tensions (N, per tendon), an optional known global point load, and
    what was measured: marker positions (m, global) and/or tendon length changes (m); the
    direction a tendon was sliding when it was taken (in or out; in if not said)."""

    tensions: dict[str, float]
    markers: dict[str, np.ndarray] = field(default_factory=dict)
    load: tuple[float, tuple[float, float, float]] | None = None
    displacements: dict[str, float] = field(default_factory=dict)
    sliding: dict[str, str] = field(default_factory=dict)




def read_snapshots(path: str | Path, robot: Robot, young_modulus: float | None = None
                   ) -> list[Snapshot]:
    """SNAPSHOTS.csv: one row per static snapshot (tensions, an optional known load, marker
    positions and/or tendon length changes, and optionally the direction each tendon was
    sliding: ``sliding_<tendon>`` in or out). ``young_modulus`` bounds the tensions
    (:func:`~tendonsense.inputs.tension_error`; ``math.inf`` while it is fitted)."""
    path = Path(path)
    raw = read_csv_rows(path, SnapshotError)
    header = raw[0] if raw else []
    check_separator(path, header, SnapshotError)
    _once(path, header, SnapshotError)
    rows = [dict(zip(header, r + [""] * (len(header) - len(r))))
            for r in raw[1:] if any(c.strip() for c in r)]
    if not rows:
        raise SnapshotError(f"{path}: no snapshot rows")
    load_cols = ("load_X", "load_fx", "load_fy", "load_fz")
    markers = [m for m in robot.marker_names if f"marker_{m}_x" in header]
    measured = [n for n in robot.tendon_names if f"displacement_{n}" in header]
    for col in header:
        kind, _, name = col.partition("_")
        ok = (col in DESCRIPTIVE or col in load_cols
              or (kind in ("tension", "displacement", "sliding")
                  and name in robot.tendon_names)
              or (kind == "marker" and name[:-2] in markers and name[-2:] in ("_x", "_y", "_z")))
        if not ok:
            raise SnapshotError(no_such(path, col, robot) or (
                f"{path}: column {col!r} is not tension_<tendon>, displacement_<tendon>, "
                f"sliding_<tendon>, load_X/_fx/_fy/_fz or marker_<marker>_x/_y/_z"))
    missing = [f"tension_{n}" for n in robot.tendon_names if f"tension_{n}" not in header]
    if missing:
        raise SnapshotError(f"{path}: no column {', '.join(missing)}: every tendon's tension "
                            f"is a reading (a slack tendon is a column of zeros)")
    rest = rest_lengths(robot)
    if not markers and not measured:
        raise SnapshotError(f"{path}: no marker_<name>_x/_y/_z or displacement_<tendon> "
                            f"columns: nothing to fit to")
    out = []
    for i, row in enumerate(rows, start=1):
        def num(col, required=True):
            text = (row.get(col) or "").strip()
            if not text:
                if required:
                    why = (" (a value is needed: a slack tendon's tension is 0)"
                           if col.startswith("tension_") else "")
                    raise SnapshotError(f"{path}: snapshot row {i}: {col} is empty{why}")
                return None
            v = _number(text)
            if not math.isfinite(v):
                raise SnapshotError(f"{path}: snapshot row {i}: column {col}: {text!r} is "
                                    f"not a finite number")
            return v
        tensions = {n: num(f"tension_{n}") for n in robot.tendon_names}
        lengths = {n: v for n in measured
                   if (v := num(f"displacement_{n}", required=False)) is not None}
        for error in ([tension_error(robot, n, v, young_modulus) for n, v in tensions.items()]
                      + [displacement_error(n, v, rest[robot.tendon_names.index(n)])
                         for n, v in lengths.items()]):
            if error:
                raise SnapshotError(f"{path}: snapshot row {i}: {error}")
        pos = {}
        for m in markers:  # a marker is measured in a row when any of its cells is filled
            cols = [f"marker_{m}_{a}" for a in "xyz"]
            if any((row.get(c) or "").strip() for c in cols):
                pos[m] = np.array([num(c) for c in cols])
                if error := marker_error(robot, m, pos[m]):
                    raise SnapshotError(f"{path}: snapshot row {i}: {error}")
        if not pos and not lengths:
            raise SnapshotError(f"{path}: snapshot row {i}: no marker position and no tendon "
                                f"displacement: nothing measured")
        load_vals = [num(c, required=False) if c in row else None for c in load_cols]
        if all(v is None for v in load_vals):
            load = None
        elif any(v is None for v in load_vals):
            raise SnapshotError(f"{path}: snapshot row {i}: a load needs load_X, load_fx, "
                                f"load_fy and load_fz")
        else:
            if not 0 <= load_vals[0] <= robot.rod.length:
                raise SnapshotError(f"{path}: snapshot row {i}: "
                                    f"{outside_rod('load_X', load_vals[0], robot.rod.length)}")
            load = (load_vals[0], tuple(load_vals[1:]))
            if error := force_error(robot, "the load", *load, young_modulus):
                raise SnapshotError(f"{path}: snapshot row {i}: {error}")
        sliding = {}
        for n in robot.tendon_names:
            word = (row.get(f"sliding_{n}") or "").strip().lower()
            if word and word not in ("in", "out"):
                why = ("a stuck tendon's friction is not known: leave the snapshot out"
                       if word == "stuck" else "a snapshot's tendon is pulled in or paid out")
                raise SnapshotError(f"{path}: snapshot row {i}: column sliding_{n}: {word!r} "
                                    f"is not in or out ({why})")
            if word:
                sliding[n] = word
        out.append(Snapshot(tensions, pos, load, lengths, sliding))
    return out


def located(unknowns: Sequence[Unknown]) -> tuple[int, ...]:
    """Indices of the unknowns whose X is unknown too."""
    return tuple(i for i, u in enumerate(unknowns) if getattr(u, "located", False))


def output_header(robot: Robot, n_unknowns: int, with_shape: bool,
                  located: Sequence[int] = (), sliding: bool = False) -> list[str]:
    """Columns of OUT.csv (uncertainty included; ``located``: indices of located unknowns;
    ``sliding``: each tendon's friction direction and, where one is stuck, the range of the
    magnitudes)."""
    return (["row", "time"] + [f"magnitude_{i + 1}" for i in range(n_unknowns)]
            + [f"sigma_{i + 1}" for i in range(n_unknowns)]
            + [f"location{s}_{i + 1}" for i in located for s in ("", "_sigma")]
            + ([f"sliding_{t}" for t in robot.tendon_names]
               + [f"magnitude_{b}_{i + 1}" for i in range(n_unknowns) for b in ("low", "high")]
               if sliding else [])
            + [f"marker_{m}_{a}" for m in robot.marker_names for a in AXES] + ["converged"]
            + (["shape_rmse"] if with_shape else []) + ["note"])


def output_row(robot: Robot, s: Sample, r: SampleEstimate | None, n_unknowns: int,
               with_shape: bool, located: Sequence[int] = (), sliding: bool = False) -> list:
    """One row of OUT.csv for sample ``s`` and its estimate ``r`` (None: skipped)."""
    markers = robot.marker_names
    t = "" if s.time is None else repr(s.time)
    n_sliding = (len(robot.tendon_names) + 2 * n_unknowns) if sliding else 0
    blank = [""] * (2 * n_unknowns + 2 * len(located) + n_sliding + 3 * len(markers))
    if r is None:
        return ([s.row, t] + blank + ["false"] + ([""] if with_shape else [])
                + [f"skipped: {s.error}"])
    if not r.converged:
        return ([s.row, t] + blank + ["false"] + ([""] if with_shape else [])
                + [r.note or "did not converge"])
    row = [s.row, t] + [repr(float(v)) for v in r.magnitudes] + \
          [repr(float(v)) for v in r.sigma]
    row += [repr(float(v)) for k in range(len(located))
            for v in (r.locations[k], r.location_sigma[k])]
    if sliding:
        row += list(r.sliding) if r.sliding else ["in"] * len(robot.tendon_names)
        row += ([repr(float(v)) if not np.isnan(v) else "" for v in r.magnitude_range.ravel()]
                if len(r.magnitude_range) else [""] * (2 * n_unknowns))
    row += [repr(float(v)) for m in markers for v in r.markers[m]]
    row.append("true")
    if with_shape:
        row.append(repr(shape_rmse(r, s.markers)) if s.markers else "")
    row.append(r.note)
    return row


def output_rows(robot: Robot, samples, results, n_unknowns: int, located: Sequence[int] = (),
                sliding: bool = False):
    """Header and rows of OUT.csv."""
    with_shape = any(s.markers for s in samples)
    return (output_header(robot, n_unknowns, with_shape, located, sliding),
            [output_row(robot, s, r, n_unknowns, with_shape, located, sliding)
             for s, r in zip(samples, results)])


def with_sliding(robot: Robot) -> bool:
    """Whether OUT.csv has the ``sliding_<tendon>`` and range columns: the robot has friction
    (a row whose tendons are all pulled in says ``in``)."""
    return any(t.friction > 0 for t in robot.tendons)


#: a fall of ln T this large (or three times the tension noise, the larger) from a log's
#: first row, before any such rise, is a log that starts with a release
RELEASE_AT_START = 0.05


def released_at_start(samples: Sequence[Sample], robot: Robot, tension_noise: float = 0.0
                      ) -> str:
    """A note where a tendon's tension falls from a log's first row before it rises (by
    :data:`RELEASE_AT_START` in ln T, or three times the relative ``tension_noise``, the
    larger): the friction history takes every tendon as pulled in at the first row, right
    after a pull (or a hold after one), not during a release. A tendon whose first tension is
    under a tenth of the log's largest (a slack one's sensor offset), or whose direction the
    first row gives, is not looked at."""
    good = [s for s in samples if not s.error and s.tensions]
    if not with_sliding(robot) or len(good) < 2:
        return ""
    step = max(RELEASE_AT_START, 3 * tension_noise)
    top = max(max(s.tensions.values(), default=0.0) for s in good)
    for t in robot.tendons:
        T = np.array([s.tensions.get(t.name, 0.0) for s in good])
        if t.friction <= 0 or not T[0] > 0.1 * top or good[0].sliding.get(t.name):
            continue
        moved = np.flatnonzero(np.abs(np.log(np.maximum(T, 1e-300) / T[0])) > step)
        if moved.size and T[moved[0]] < T[0]:
            k = moved[0]
            return _release_note(t.name, T[0], good[0].row, T[k], good[k].row)
    return ""


def _release_note(name: str, first: float, row: int, fallen: float, at: int) -> str:
    return (f"{name}'s tension falls from the log's first row ({first:.4g} N at row {row}, "
            f"{fallen:.4g} N at row {at}): the friction history takes {name} as pulled in at "
            f"the first row, as after a pull or a hold after one; if the log starts during a "
            f"release, its rows until {name} has fallen through its friction band read the "
            f"friction of a pull (start the log before the release)")


class ReleaseWatch:
    """:func:`released_at_start` for a stream, row by row: each tendon with friction is
    watched from the first good row until its tension first moves by the step, and the note
    given once, at the row where it has fallen (a tendon whose first tension is under a tenth
    of the largest so far then is not looked at). Call it with each sample; it returns the
    note, or ''."""

    def __init__(self, robot: Robot, tension_noise: float = 0.0):
        self.step = max(RELEASE_AT_START, 3 * tension_noise)
        self.open = [t.name for t in robot.tendons if t.friction > 0] if with_sliding(
            robot) else []
        self.first: Sample | None = None
        self.top = 0.0

    def __call__(self, sample: Sample) -> str:
        if not self.open or sample.error or not sample.tensions:
            return ""
        self.top = max(self.top, *sample.tensions.values())
        if self.first is None:
            self.first = sample
            self.open = [n for n in self.open if not sample.sliding.get(n)]
            return ""
        for name in list(self.open):
            T0, T = self.first.tensions.get(name, 0.0), sample.tensions.get(name, 0.0)
            if T0 > 0 and abs(np.log(max(T, 1e-300) / T0)) <= self.step:
                continue  # (not moved yet)
            self.open.remove(name)
            if T < T0 and T0 > 0.1 * self.top:
                self.open = []
                return _release_note(name, T0, self.first.row, T, sample.row)
        return ""


#: a damped robot's shape lags its readings by about τ ẏ (τ = 3η/E): a file log estimated
#: at rest is noted where that lag of a measured length exceeds this many length noises
LAG_NOTE = 2.0


def _slopes(t: np.ndarray, v: np.ndarray, w: int, block: int = 4096) -> np.ndarray:
    """Least-squares slopes of ``v`` (N, k) against ``t`` (N,) over every ``w`` consecutive
    rows (N − w + 1, k): windowed sums of cumulative sums, ``block`` windows at a time, each
    block centred on its own means (so that the sums stay small); NaN over a window whose
    stamps span no time (one stamp repeated)."""
    def window(x):  # sums over each window
        c = np.concatenate([np.zeros((1, x.shape[1])), np.cumsum(x, axis=0)])
        return c[w:] - c[:-w]

    out = []
    for a in range(0, t.size - w + 1, block):
        tb, vb = t[a:a + block + w - 1], v[a:a + block + w - 1]
        tb, vb = (tb - tb.mean())[:, None], vb - vb.mean(axis=0)
        st, sv, stt = window(tb), window(vb), window(tb * tb)
        spread = w * stt - st * st  # (a window of one repeated stamp: none, no slope)
        with np.errstate(divide="ignore", invalid="ignore"):
            out.append(np.where(spread > 1e-9 * w * stt, (w * window(tb * vb) - st * sv)
                                / spread, np.nan))
    return np.concatenate(out)


def lag_window(tau: float, dt: float) -> int:
    """The rows over which :func:`lagging` fits a length's rate, at a step of ``dt``: the
    fewest (at least 3) whose fitted slope's noise, σ √(12 / (w (w² − 1))) / Δt, times ``tau``
    is at most a third of the length noise σ."""
    w = 3
    while w * (w * w - 1) < 108 * (tau / dt) ** 2:
        w += 1
    return w


def _lag_note(tau: float, name: str, lag: float, length_noise: float, row: int,
              by: str, where: str) -> str:
    """The words of :func:`lagging`'s and :class:`LagWatch`'s note."""
    return (f"the robot moves: with its damping (τ = 3η/E = {tau:.3g} s) the shape lags the "
            f"readings, {name}'s length by {by}{lag * 1e3:.3g} mm (τ × its rate, at row {row}: "
            f"{lag / length_noise:.3g} times the length noise{where}): an estimate at rest "
            f"reads that lag as a force there (estimate in motion: --dynamic)")


def lagging(samples: Sequence[Sample], robot: Robot, measured: Sequence[str],
            length_noise: float) -> str:
    """A note where a log, estimated at rest, moves a damped robot faster than its shape
    follows: the shape lags the readings by about τ = 3η/E, so that a measured length is
    short of its equilibrium by τ|ẏ| and the estimate reads that as a force (eq. 7 holds at
    rest only). ẏ is each measured length change's rate, fitted over :func:`lag_window` rows
    (at their median time step); noted where τ|ẏ| exceeds :data:`LAG_NOTE` length noises.
    Nothing without time stamps or damping, nor where the rows are more than τ apart (the
    rod settles between them: τ|ẏ| is no longer its lag). A stream: :class:`LagWatch`."""
    tau = robot.rod.relaxation_time
    good = [s for s in samples if not s.error and s.time is not None]
    if tau <= 0 or len(good) < 3 or not measured:
        return ""
    t = np.array([s.time for s in good])
    dt = np.median(np.diff(t))
    if not 0 < dt <= tau or not np.all(np.diff(t) >= 0):  # (a stamp repeated: kept)
        return ""
    w = lag_window(tau, dt)
    if w > len(good):
        return ""
    y = np.array([[s.displacements[n] for n in measured] for s in good])
    lag = np.nan_to_num(tau * np.abs(_slopes(t, y, w)) / length_noise)
    over = np.flatnonzero(lag.max(axis=1) > LAG_NOTE)
    if not over.size:
        return ""
    k, j = np.unravel_index(np.argmax(lag), lag.shape)
    rows = [good[i + w // 2].row for i in (over[0], over[-1], k)]
    return _lag_note(tau, measured[j], lag[k, j] * length_noise, length_noise, rows[2],
                     "up to ", f"; more than {LAG_NOTE:g} times on {over.size} rows between "
                     f"rows {rows[0]} and {rows[1]}")


#: a stream's first time-stamped rows whose median step sets :class:`LagWatch`'s window
LAG_ROWS = 10


class LagWatch:
    """:func:`lagging` for a stream, row by row: each measured length's rate fitted over the
    last :func:`lag_window` rows (at the median step of the first :data:`LAG_ROWS` rows), and
    the note given once, at the first row where τ|ẏ| exceeds :data:`LAG_NOTE` length noises
    (the last row of the file's first such window); none once a time stamp goes back (as
    the file's). Call it with each sample; it returns the note, or ''."""

    def __init__(self, robot: Robot, measured: Sequence[str], length_noise: float):
        self.tau, self.measured = robot.rod.relaxation_time, list(measured)
        self.noise = length_noise
        self.rows: list[tuple[float, list[float], int]] = []
        self.window = 0  # rows of the fit, once the first rows have set it
        self.done = self.tau <= 0 or not self.measured

    def __call__(self, sample: Sample) -> str:
        if self.done or sample.error or sample.time is None:
            return ""
        if self.rows and not sample.time >= self.rows[-1][0]:
            self.done = True  # stamps that go back (as :func:`lagging`: no note)
            return ""
        self.rows.append((sample.time, [sample.displacements[n] for n in self.measured],
                          sample.row))
        if not self.window:
            if len(self.rows) < LAG_ROWS:
                return ""
            dt = float(np.median(np.diff([r[0] for r in self.rows])))
            if not 0 < dt <= self.tau:
                self.done = True  # the rod settles between rows (or stamps are not seconds)
                return ""
            self.window = lag_window(self.tau, dt)
        if len(self.rows) < self.window:
            return ""
        # every window ending at a row not yet looked at (the first rows': once)
        t = np.array([r[0] for r in self.rows])
        y = np.array([r[1] for r in self.rows])
        lag = np.nan_to_num(self.tau * np.abs(_slopes(t, y, self.window)))
        ends = [r[2] for r in self.rows[self.window - 1:]]  # each window's last row
        del self.rows[:1 - self.window]
        over = np.flatnonzero(lag.max(axis=1) > LAG_NOTE * self.noise)
        if not over.size:
            return ""
        i, self.done = over[0], True
        j = int(np.argmax(lag[i]))
        return _lag_note(self.tau, self.measured[j], lag[i, j], self.noise, ends[i], "",
                         "; said once")


def shape_rmse(result, measured: dict[str, np.ndarray]) -> float:
    """Root-mean-square distance (m) between estimated and measured markers."""
    d = [np.sum((result.markers[m] - p) ** 2) for m, p in measured.items()]
    return float(np.sqrt(np.mean(d)))


def write_csv_atomic(path: str | Path, header, rows):
    """Write a CSV atomically (see :func:`write_text_atomic`)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    w.writerows(rows)
    write_text_atomic(path, buf.getvalue())


def write_bytes_atomic(path: str | Path, data: bytes):
    """:func:`write_text_atomic` for bytes (a figure)."""
    with AtomicText(path) as out:
        out.buffer.write(data)
        out.commit()


def write_text_atomic(path: str | Path, text: str):
    """Write next to the destination and move into place: a reader never sees a partial
    file, and a failed run leaves none."""
    with AtomicText(path) as out:
        out.write(text)
        out.commit()


def special(path: Path) -> bool:
    """Whether ``path`` is there and neither a regular file nor a folder: a device or a named
    pipe, written into, never replaced."""
    try:
        mode = path.stat().st_mode
    except OSError:
        return False
    return not (stat.S_ISREG(mode) or stat.S_ISDIR(mode))


def beside(path: Path) -> tuple[int, str]:
    """A new hidden file next to ``path``, open for writing: (descriptor, name). Made with
    the permissions of the file it replaces, or of a file the user creates (0o666 less the
    umask), which it keeps when it is moved into place (:func:`tempfile.mkstemp` would make
    it private)."""
    for _ in range(100):
        tmp = str(path.parent / f".{path.name}.{secrets.token_hex(4)}")
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:
            continue
        try:
            os.fchmod(fd, path.stat().st_mode & 0o7777)
        except (OSError, AttributeError):  # no file there yet (or no fchmod): as made
            pass
        return fd, tmp
    raise FileExistsError(f"{path}: no free name beside it")


class AtomicText(io.TextIOWrapper):
    """A text file (UTF-8; bytes through its ``buffer``) written next to ``path`` and moved
    into place by :meth:`commit`; closed without a commit, it leaves nothing. Errors name
    ``path``, not the hidden file. A symbolic link is written through: its target is replaced
    (the link kept; ``/dev/stdout`` sent to a file writes that file). Where ``path`` is a
    device or a named pipe (``/dev/null``, a FIFO a program reads), the text is kept in memory
    and written into it by :meth:`commit` (moved into place, a file would replace it)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.target = Path(os.path.realpath(self.path))
        self.tmp = None
        if special(self.target):
            super().__init__(io.BytesIO(), encoding="utf-8", newline="")
        else:
            try:
                fd, self.tmp = beside(self.target)
            except OSError as exc:
                raise OSError(f"{path}: cannot write ({exc.strerror})") from None
            super().__init__(os.fdopen(fd, "wb"), encoding="utf-8", newline="")
        self.committed = False

    def commit(self):
        self.flush()
        try:
            if self.tmp is None:
                with open(self.target, "wb") as out:
                    out.write(self.buffer.getvalue())
            else:
                os.replace(self.tmp, self.target)
        except OSError as exc:
            raise OSError(f"{self.path}: cannot write ({exc.strerror})") from None
        self.committed = True

    def close(self):
        super().close()
        if not self.committed and self.tmp is not None and os.path.exists(self.tmp):
            os.unlink(self.tmp)

    def __exit__(self, *exc):
        self.close()



#: the values a parameter set may give (checked by :func:`~tendonsense.robot.value_error`)
SET_VALUES = ("young_modulus", "poisson_ratio", "density", "friction")
LOAD_COLUMNS = ("load_X", "load_fx", "load_fy", "load_fz")


@dataclass(frozen=True)
class ParameterSets:
    """SETS.csv (:func:`read_parameter_sets`): one forward solve per row, as the arguments of
    :func:`~tendonsense.tracking.solve_batch`, and the file's own cells (trimmed) to write back."""

    header: list[str]
    rows: list[list[str]]
    tensions: np.ndarray  # (N, n_t), tendons in file order; a tendon not given is slack
    values: dict[str, np.ndarray]  # {name: (N,)}; friction (N, n_t)
    loads: list[tuple[np.ndarray, np.ndarray]]  # [] or [(X (N,), f (N, 3))]


def read_parameter_sets(path: str | Path, robot: Robot) -> ParameterSets:
    """SETS.csv: one parameter set per row, for a sweep or a Monte Carlo. Columns (any,
    besides descriptive ones such as ``id`` or ``note``): ``tension_<tendon>`` (N, a tendon
    without a column is slack), ``young_modulus`` (Pa), ``poisson_ratio``, ``density``
    (kg/m³), ``friction`` (one μ for every tendon), ``friction_<tendon>`` (that tendon's μ),
    and a known point load ``load_X``, ``load_fx``, ``load_fy``, ``load_fz`` (m, N, global).
    A value not given is the robot file's. Every cell is checked; an error names the row and
    the column."""
    path = Path(path)
    raw = read_csv_rows(path, ReadingsError)
    header = [h.strip() for h in raw[0]] if raw else []
    check_separator(path, header, ReadingsError)
    rows = [r for r in raw[1:] if any(c.strip() for c in r)]
    if not rows:
        raise ReadingsError(f"{path}: no parameter sets (a header row, then one row per set)")
    tendons = robot.tendon_names
    numeric = []
    for col in header:
        kind, _, name = col.partition("_")
        if col in SET_VALUES or col in LOAD_COLUMNS or (
                kind in ("tension", "friction") and name in tendons):
            numeric.append(col)
        elif col not in DESCRIPTIVE:
            raise ReadingsError(no_such(path, col, robot, ("tension", "friction"), False) or
                f"{path}: column {col!r} is not tension_<tendon>, young_modulus, "
                f"poisson_ratio, density, friction, friction_<tendon>, load_X/_fx/_fy/_fz or "
                f"descriptive ({', '.join(DESCRIPTIVE)})")
    _once(path, header, ReadingsError)
    load = [c for c in LOAD_COLUMNS if c in header]
    if load and len(load) < 4:
        raise ReadingsError(f"{path}: a known load needs load_X, load_fx, load_fy and load_fz")
    data = np.empty((len(rows), len(numeric)))
    for i, row in enumerate(rows):
        if len(row) != len(header):
            raise ReadingsError(f"{path}: set {i + 1}: {len(row)} fields, the header has "
                                f"{len(header)}")
        # the set's own modulus bounds its tensions (a bad one is refused by its column)
        E = _number(row[header.index("young_modulus")]) if "young_modulus" in header else None
        E = E if E is None or (math.isfinite(E) and not value_error("young_modulus", E)) \
            else None
        for j, col in enumerate(numeric):
            text = row[header.index(col)].strip()
            v = _number(text)
            if not math.isfinite(v):
                raise ReadingsError(f"{path}: set {i + 1}: column {col}: {text!r} is not a "
                                    f"finite number")
            kind, _, name = col.partition("_")
            why = value_error("friction" if kind == "friction" else col, v) if (
                col in SET_VALUES or kind == "friction") else None
            error = (tension_error(robot, name, v, E) if kind == "tension" else
                     f"{col}: {why}" if why else
                     outside_rod("load_X", v, robot.rod.length)
                     if col == "load_X" and not 0 <= v <= robot.rod.length else None)
            if error:
                raise ReadingsError(f"{path}: set {i + 1}: {error}")
            data[i, j] = v
        if load and (error := force_error(robot, "the load", *_load_of(data[i], numeric), E)):
            raise ReadingsError(f"{path}: set {i + 1}: {error}")
    column = {c: data[:, j] for j, c in enumerate(numeric)}
    n = len(rows)
    T = np.stack([column.get(f"tension_{t}", np.zeros(n)) for t in tendons], axis=1)
    values = {k: column[k] for k in ("young_modulus", "poisson_ratio", "density") if k in column}
    if any(c == "friction" or c.startswith("friction_") for c in column):
        mu = np.tile([t.friction for t in robot.tendons], (n, 1)).astype(float)
        if "friction" in column:
            mu[:] = column["friction"][:, None]
        for j, t in enumerate(tendons):
            if f"friction_{t}" in column:
                mu[:, j] = column[f"friction_{t}"]
        values["friction"] = mu
    loads = ([(column["load_X"], np.stack([column[c] for c in LOAD_COLUMNS[1:]], axis=1))]
             if load else [])
    return ParameterSets(header, [[c.strip() for c in r] for r in rows], T, values, loads)


def _load_of(values, columns) -> tuple[float, list[float]]:
    """``(X, (fx, fy, fz))`` of a row's load columns."""
    X, *F = (values[columns.index(c)] for c in LOAD_COLUMNS)
    return X, F


def sweep_rows(robot: Robot, sets: ParameterSets, result, point_forces=(),
               sliding: Mapping[str, str] | None = None) -> tuple[list[str], list[list]]:
    """Header and rows of a sweep's RESULTS.csv: each set's own cells, the inputs of every set
    given apart from the table (``point_forces`` [(X, (fx, fy, fz))] as
    ``point_force_<k>_X/_fx/_fy/_fz``, m and N; ``sliding`` {tendon: direction} as
    ``sliding_<tendon>``), then its markers (``marker_<name>_x/_y/_z``, m), its tendons' length
    changes (``displacement_<tendon>``, m), ``converged``, ``unstable`` (true where the set's
    equilibrium is one the rod would leave; blank where not converged or not checked) and
    ``solver_note``, why a set is no solution or is unstable (a
    :class:`~tendonsense.tracking.BatchResult` ``result``)."""
    given = [(f"point_force_{k}_{c}", repr(float(v)))
             for k, (X, f) in enumerate(point_forces, start=1)
             for c, v in zip(("X", "fx", "fy", "fz"), (X, *f))]
    given += [(f"sliding_{t}", d) for t, d in (sliding or {}).items()]
    header = (sets.header + [c for c, _ in given]
              + [f"marker_{m}_{a}" for m in robot.marker_names for a in AXES]
              + [f"displacement_{t}" for t in robot.tendon_names]
              + ["converged", "unstable", "solver_note"])
    rows = []
    for k, cells in enumerate(sets.rows):
        ok = bool(result.converged[k])
        out = [repr(float(v)) if ok else "" for m in robot.marker_names
               for v in result.markers[m][k]]
        out += [repr(float(result.displacements[t][k])) if ok else ""
                for t in robot.tendon_names]
        shaky = "" if result.unstable is None or not ok else (
            "true" if result.unstable[k] else "false")
        rows.append(cells + [v for _, v in given] + out
                    + ["true" if ok else "false", shaky, result.notes[k]])
    return header, rows


def read_tension_schedule(path: str | Path,
                          robot: Robot) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Tensions over time for :func:`~tendonsense.simulation.simulate`: a CSV with ``time``
    (s, increasing) and ``tension_<name>`` for some tendons; {name: (times, tensions)}.
    Every value is checked by the rules of :mod:`tendonsense.inputs`. Descriptive columns
    (:data:`DESCRIPTIVE`) and a readings log's other columns (``displacement_``,
    ``sliding_``, ``marker_``) are not read: a recorded log's own tensions can be simulated."""
    path = Path(path)
    rows = read_csv_rows(path, ReadingsError)
    if not rows:
        raise ReadingsError(f"{path}: empty file (expected a header with time and "
                            f"tension_<tendon> columns)")
    header = [h.strip() for h in rows[0]]
    check_separator(path, header, ReadingsError)
    names = [h.removeprefix("tension_") for h in header if h.startswith("tension_")]
    for col in header:
        if col in DESCRIPTIVE or (col.startswith("tension_") and col[8:] in robot.tendon_names):
            continue
        kind, _, name = col.partition("_")
        if not (error := no_such(path, col, robot)) and (
                kind in ("displacement", "sliding") and name in robot.tendon_names
                or kind == "marker" and name[-2:] in ("_x", "_y", "_z")):
            continue
        raise ReadingsError(error or f"{path}: column {col!r}: not time, tension_<tendon>, "
                                     f"a readings log's column or descriptive "
                                     f"({', '.join(DESCRIPTIVE)})")
    if "time" not in header or not names:
        raise ReadingsError(f"{path}: needs a time column and at least one tension_<tendon>")
    _once(path, header, ReadingsError)
    if len(rows) < 2:
        raise ReadingsError(f"{path}: no rows after the header")
    used = [j for j, col in enumerate(header) if col == "time" or col.startswith("tension_")]
    data = np.full((len(rows) - 1, len(header)), np.nan)
    for i, raw in enumerate(rows[1:], start=1):
        if len(raw) != len(header):
            raise ReadingsError(f"{path}: row {i}: {len(raw)} values for {len(header)} columns")
        for j in used:
            col, text = header[j], raw[j]
            try:
                data[i - 1, j] = float(text)
            except ValueError:
                raise ReadingsError(f"{path}: row {i}, {col}: not a number: {text!r}") from None
            if not math.isfinite(data[i - 1, j]):
                raise ReadingsError(f"{path}: row {i}, {col}: not a finite number")
            if col != "time" and (error := tension_error(robot, col[8:], data[i - 1, j])):
                raise ReadingsError(f"{path}: row {i}: {error}")
    t = data[:, header.index("time")]
    if t[0] < 0:
        raise ReadingsError(f"{path}: row 1: time {t[0]:g} s: the schedule starts at >= 0 s")
    if (back := np.flatnonzero(np.diff(t) <= 0)).size:
        k = int(back[0]) + 1
        raise ReadingsError(f"{path}: row {k + 1}: time {t[k]:g} s is not after row {k}'s "
                            f"{t[k - 1]:g} s (times increase from row to row)")
    return {n: (t, data[:, header.index(f"tension_{n}")]) for n in names}


#: skipped rows a :class:`LogSummary` names (the rest are counted)
SKIPPED_SHOWN = 20


@dataclass(frozen=True)
class LogSummary:
    """What became of one log of many (:func:`tendonsense.logs.estimate_file`): its rows' counts, or why it
    could not be estimated (``error``, naming the log; then nothing was written)."""

    log: str
    output: str
    samples: int = 0
    converged: int = 0
    skipped: int = 0
    error: str | None = None
    #: the first :data:`SKIPPED_SHOWN` skipped rows: (row, why)
    skipped_rows: tuple[tuple[int, str], ...] = ()
    #: e.g. that the log starts with a release (:func:`released_at_start`)
    note: str = ""

    def to_json(self) -> dict:
        return {"log": self.log, "output": None if self.error else self.output,
                "samples": self.samples, "converged": self.converged, "skipped": self.skipped,
                "error": self.error, "note": self.note}
