"""The paper's experiments (§V-B, Tables II–IV) re-run with our estimator.

Each row of the experiments CSV gives the tendon(s), their tension(s) and displacement(s), the
unknown (a point force along a global direction at ``force_X``, or gravity), the applied
magnitude and the paper's estimate. Multi-valued cells (several tendons, a 3-D force) are
separated by spaces or semicolons; a point force without a direction, or with
``unknown = point_force_3d``, is estimated as three components along global x, y, z.
"""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import inputs
from .inputs import GravityUnknown, PointForceUnknown
from .readings import CSV_ENCODING
from .robot import Robot

#: the columns every experiments table has (``force_X``, ``direction``, ``paper_estimate``
#: and others are optional)
COLUMNS = ("case", "tendon", "unknown", "tension_N", "displacement_m", "applied")


@dataclass(frozen=True)
class Experiment:
    """One row of the table: its readings (by tendon), unknowns and applied magnitudes."""

    case: str
    displacements: dict[str, float]
    tensions: dict[str, float]
    unknowns: list
    applied: np.ndarray
    paper: np.ndarray | None


@dataclass(frozen=True)
class ExperimentRow:
    case: str
    applied: np.ndarray
    ours: np.ndarray | None
    paper: np.ndarray | None
    converged: bool
    note: str = ""  # why the row has no estimate, or a remark on it

    def error(self, which: np.ndarray | None) -> float:
        if which is None:
            return float("nan")
        return float(np.linalg.norm(which - self.applied) / np.linalg.norm(self.applied))


def _numbers(text: str, column: str) -> list[float]:
    return [inputs.finite(column, t) for t in re.split(r"[\s;,]+", text.strip()) if t]


#: the unknowns a row may name
KINDS = ("point_force", "point_force_3d", "gravity")


def _unknowns(row: dict) -> list:
    kind = row["unknown"].strip().lower()
    if kind not in KINDS:
        raise ValueError(f"unknown {row['unknown']!r}: one of {', '.join(KINDS)}")
    if kind == "gravity":
        return [GravityUnknown()]
    if not (row.get("force_X") or "").strip():
        raise ValueError(f"unknown {row['unknown']!r}: a point force needs its force_X")
    X = inputs.finite("force_X", row["force_X"])
    d = _numbers(row.get("direction", "") or "", "direction")
    if kind == "point_force_3d" or not d:
        return [PointForceUnknown(X, tuple(e)) for e in np.eye(3)]
    if len(d) % 3:
        raise ValueError(f"direction {row['direction']!r} is not groups of 3 numbers")
    return [PointForceUnknown(X, tuple(d[i:i + 3])) for i in range(0, len(d), 3)]


def _experiment(row: dict, robot: Robot) -> Experiment:
    names = re.split(r"[\s;,+]+", row["tendon"].strip())
    if len(set(names)) < len(names):
        raise ValueError(f"tendon {row['tendon']!r}: a tendon named twice")
    T = _numbers(row["tension_N"], "tension_N")
    y = _numbers(row["displacement_m"], "displacement_m")
    if not (len(names) == len(T) == len(y)):
        raise ValueError(f"{len(names)} tendons, {len(T)} tensions, {len(y)} displacements")
    displacements, tensions = dict(zip(names, y)), dict(zip(names, T))
    inputs.readings(robot, displacements, tensions)  # the rules for every reading
    unknowns = _unknowns(row)
    inputs.check_unknowns(robot, names, unknowns)
    applied = np.array(_numbers(row["applied"], "applied"))
    if applied.size != len(unknowns):
        raise ValueError(f"{applied.size} applied magnitudes for {len(unknowns)} unknowns")
    paper = (row.get("paper_estimate") or "").strip()
    return Experiment(row["case"], displacements, tensions, unknowns, applied,
                      np.array(_numbers(paper, "paper_estimate")) if paper else None)


def read_experiments(path: str | Path, robot: Robot) -> list[Experiment]:
    """Every row of the experiments table at ``path``, checked against ``robot`` (no solve):
    a ValueError naming the file, the row and what is wrong."""
    try:
        with open(path, newline="", encoding=CSV_ENCODING) as fh:
            reader = csv.DictReader(fh, restval="")
            rows = list(reader)
            header = reader.fieldnames
    except OSError as exc:
        raise ValueError(f"{path}: cannot read ({exc.strerror})") from None
    except (csv.Error, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not a CSV table ({exc})") from None
    if not header:
        raise ValueError(f"{path}: empty file, expected a header row")
    missing = [c for c in COLUMNS if c not in header]
    if missing:
        raise ValueError(f"{path}: no column {missing[0]} (an experiments table has "
                         f"{', '.join(COLUMNS)}; force_X, direction and paper_estimate "
                         f"where they apply)")
    if not rows:
        raise ValueError(f"{path}: no data rows below the header")
    out = []
    for i, row in enumerate(rows, 1):
        try:
            out.append(_experiment(row, robot))
        except ValueError as exc:
            raise ValueError(f"{path}: row {i} (case {row['case']!r}): {exc}") from None
    return out


def run(robot: Robot, table: str | Path | list[Experiment], progress=None
        ) -> list[ExperimentRow]:
    """Estimate every row of the experiments ``table`` (a path, or its
    :func:`read_experiments`) with ``robot``'s settings (nothing per row)."""
    from .estimation import estimate
    rows = read_experiments(table, robot) if isinstance(table, (str, Path)) else table
    out = []
    for e in rows:
        res = estimate(robot, e.displacements, e.tensions, e.unknowns)
        out.append(ExperimentRow(e.case, e.applied, res.magnitudes if res.converged else None,
                                 e.paper, bool(res.converged), res.note))
        if progress is not None:
            progress(len(out), len(rows))
    return out


def summary(rows: list[ExperimentRow]) -> dict:
    ours = [e for r in rows if np.isfinite(e := r.error(r.ours))]
    paper = [r.error(r.paper) for r in rows if r.paper is not None]
    return {"rows": len(rows), "converged": sum(r.converged for r in rows),
            "mean_relative_error_ours": float(np.mean(ours)) if ours else float("nan"),
            "mean_relative_error_paper": float(np.mean(paper)) if paper else float("nan")}
