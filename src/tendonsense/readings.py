"""CSV files of tendon readings: reading a log, estimating over it, writing the
result atomically."""

from __future__ import annotations

import csv
import io
import math
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from .estimation import Noise, Unknown, problem
from .tracking import SampleEstimate
from .robot import Robot

AXES = ("x", "y", "z")


class ReadingsError(ValueError):
    """A readings file that cannot be used at all (bad header, unreadable)."""


@dataclass(frozen=True)
class Sample:
    """One row of a readings file; ``error`` names the bad column of a row that is skipped."""

    row: int  # 1-based data row number (the header is row 0)
    time: float | None
    tensions: dict[str, float]
    displacements: dict[str, float]
    markers: dict[str, np.ndarray]
    error: str | None = None


def read_csv_rows(path: Path, error: type[Exception]) -> list[list[str]]:
    """All rows of a CSV file; an unreadable file raises ``error`` naming it."""
    try:
        with open(path, newline="") as fh:
            return list(csv.reader(fh))
    except OSError as exc:
        raise error(f"{path}: cannot read ({exc.strerror})") from None


@dataclass(frozen=True)
class Columns:
    """The columns of a readings log: which tendons are measured, which markers given."""

    header: list[str]
    measured: list[str]
    markers: list[str]


def parse_header(header: Sequence[str], robot: Robot, source) -> Columns:
    """Check the header of READINGS.csv: ``time`` (optional), ``tension_<name>``,
    ``displacement_<name>``, optional ``marker_<name>_x/_y/_z``."""
    header = [h.strip() for h in header]
    tendons, markers = robot.tendon_names, robot.marker_names
    measured, seen = [], set()
    for col in header:
        if col in seen:
            raise ReadingsError(f"{source}: column {col!r} appears twice")
        seen.add(col)
        kind, _, name = col.partition("_")
        if col == "time":
            continue
        if kind in ("tension", "displacement"):
            if name not in tendons:
                raise ReadingsError(f"{source}: column {col!r}: no tendon {name!r} in the robot")
            if kind == "displacement":
                measured.append(name)
        elif kind == "marker" and name[-2:] in ("_x", "_y", "_z") and name[:-2] in markers:
            continue
        else:
            raise ReadingsError(f"{source}: column {col!r} is not time, tension_<tendon>, "
                                f"displacement_<tendon> or marker_<marker>_x/_y/_z")
    if not measured:
        raise ReadingsError(f"{source}: no displacement_<tendon> column")
    for name in measured:
        if f"tension_{name}" not in header:
            raise ReadingsError(f"{source}: displacement_{name} has no tension_{name} column")
    marker_names = [m for m in markers if f"marker_{m}_x" in header]
    for m in marker_names:
        for a in AXES:
            if f"marker_{m}_{a}" not in header:
                raise ReadingsError(f"{source}: marker {m!r} needs columns _x, _y and _z")
    return Columns(header, measured, marker_names)


def parse_row(i: int, raw: Sequence[str], columns: Columns, robot: Robot) -> Sample:
    """One data row (1-based ``i``); a bad one is returned with ``error`` set."""
    header = columns.header
    values, error = {}, None
    if len(raw) != len(header):
        error = f"has {len(raw)} fields, the header has {len(header)}"
    else:
        for col, text in zip(header, raw):
            try:
                v = float(text)
            except ValueError:
                v = math.nan
            if not math.isfinite(v):
                error = f"column {col}: {'missing' if not text.strip() else repr(text)} value"
                break
            if col.startswith("tension_") and v < 0:
                error = f"column {col}: negative tension {v:g} N (a tendon cannot push)"
                break
            values[col] = v
    if error:
        return Sample(i, None, {}, {}, {}, error)
    return Sample(
        i, values.get("time"),
        {n: values[f"tension_{n}"] for n in robot.tendon_names if f"tension_{n}" in values},
        {n: values[f"displacement_{n}"] for n in columns.measured},
        {m: np.array([values[f"marker_{m}_{a}"] for a in AXES]) for m in columns.markers})


def read_readings(path: str | Path, robot: Robot) -> tuple[list[str], list[Sample]]:
    """Parse READINGS.csv (:func:`parse_header`, :func:`parse_row`). Returns (measured tendon
    names, samples)."""
    path = Path(path)
    rows = read_csv_rows(path, ReadingsError)
    if not rows:
        raise ReadingsError(f"{path}: empty file, expected a header row")
    columns = parse_header(rows[0], robot, path)
    samples = [parse_row(i, raw, columns, robot) for i, raw in enumerate(rows[1:], start=1)
               if any(c.strip() for c in raw)]
    return columns.measured, samples


def estimate_readings(robot: Robot, measured: Sequence[str], samples: Sequence[Sample],
                      unknowns: Sequence[Unknown], point_forces=(), noise: Noise = Noise(),
                      progress=None) -> list[SampleEstimate | None]:
    """Estimate every good sample of a log in order, each warm-started from the last good
    one (:class:`tendonsense.online.OnlineEstimator`); a bad sample gives None.
    ``progress(done, total)`` is called as samples complete."""
    from .online import OnlineEstimator
    from .tracking import RESCUE_BUDGET
    online = OnlineEstimator(problem(robot, measured, unknowns, point_forces), noise,
                             rescue_budget=RESCUE_BUDGET)  # the same result on any machine
    out = []
    for k, s in enumerate(samples):
        out.append(None if s.error else online.update(s.displacements, s.tensions))
        if progress and (k % 100 == 99 or k == len(samples) - 1):
            progress(k + 1, len(samples))
    return out


def stream_readings(robot: Robot, lines, out, unknowns: Sequence[Unknown], point_forces=(),
                    noise: Noise = Noise(), source="<stdin>", on_skip=None,
                    on_sample=None) -> tuple[int, int]:
    """Live estimation: read READINGS.csv lines from ``lines`` (an iterable of text lines) and
    write each output row to ``out`` as soon as it is estimated, flushed; then call
    ``on_sample(sample, estimate or None)`` (e.g. a :class:`~tendonsense.view.Viewer`'s push).
    Returns (rows, converged). Ends at the end of the input; the caller handles an interrupt
    (every row written so far is complete)."""
    from .online import OnlineEstimator
    reader = csv.reader(lines)
    try:
        header = next(reader)
    except StopIteration:
        raise ReadingsError(f"{source}: no header row") from None
    columns = parse_header(header, robot, source)
    online = OnlineEstimator(problem(robot, columns.measured, unknowns, point_forces), noise)
    writer = csv.writer(out)
    with_shape = bool(columns.markers)
    writer.writerow(output_header(robot, len(unknowns), with_shape, located(unknowns)))
    out.flush()
    rows = good = 0
    for i, raw in enumerate(reader, start=1):
        if not any(c.strip() for c in raw):
            continue
        s = parse_row(i, raw, columns, robot)
        r = None if s.error else online.update(s.displacements, s.tensions)
        if r is None and on_skip:
            on_skip(s)
        writer.writerow(output_row(robot, s, r, len(unknowns), with_shape, located(unknowns)))
        out.flush()
        if on_sample is not None:
            on_sample(s, r)
        rows, good = rows + 1, good + bool(r is not None and r.converged)
    return rows, good


def located(unknowns: Sequence[Unknown]) -> tuple[int, ...]:
    """Indices of the unknowns whose X is unknown too."""
    return tuple(i for i, u in enumerate(unknowns) if getattr(u, "located", False))


def output_header(robot: Robot, n_unknowns: int, with_shape: bool,
                  located: Sequence[int] = ()) -> list[str]:
    """Columns of OUT.csv (uncertainty included; ``located``: indices of located unknowns)."""
    return (["row", "time"] + [f"magnitude_{i + 1}" for i in range(n_unknowns)]
            + [f"sigma_{i + 1}" for i in range(n_unknowns)]
            + [f"location{s}_{i + 1}" for i in located for s in ("", "_sigma")]
            + [f"marker_{m}_{a}" for m in robot.marker_names for a in AXES] + ["converged"]
            + (["shape_rmse"] if with_shape else []) + ["note"])


def output_row(robot: Robot, s: Sample, r: SampleEstimate | None, n_unknowns: int,
               with_shape: bool, located: Sequence[int] = ()) -> list:
    """One row of OUT.csv for sample ``s`` and its estimate ``r`` (None: skipped)."""
    markers = robot.marker_names
    t = "" if s.time is None else repr(s.time)
    blank = [""] * (2 * n_unknowns + 2 * len(located) + 3 * len(markers))
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
    row += [repr(float(v)) for m in markers for v in r.markers[m]]
    row.append("true")
    if with_shape:
        row.append(repr(shape_rmse(r, s.markers)) if s.markers else "")
    row.append(r.note)
    return row


def output_rows(robot: Robot, samples, results, n_unknowns: int, located: Sequence[int] = ()):
    """Header and rows of OUT.csv."""
    with_shape = any(s.markers for s in samples)
    return (output_header(robot, n_unknowns, with_shape, located),
            [output_row(robot, s, r, n_unknowns, with_shape, located)
             for s, r in zip(samples, results)])


def shape_rmse(result, measured: dict[str, np.ndarray]) -> float:
    """Root-mean-square distance (m) between estimated and measured markers."""
    d = [np.sum((result.markers[m] - p) ** 2) for m, p in measured.items()]
    return float(np.sqrt(np.mean(d)))


def write_csv_atomic(path: str | Path, header, rows):
    """Write a CSV atomically (see :func:`write_text_atomic`)."""
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(header)
    w.writerows(rows)
    write_text_atomic(path, buf.getvalue())


def write_text_atomic(path: str | Path, text: str):
    """Write next to the destination and move into place: a reader never sees a partial
    file, and a failed run leaves none."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "w", newline="") as fh:
            fh.write(text)
        os.replace(tmp, path)
    except BaseException:
        os.unlink(tmp)
        raise
