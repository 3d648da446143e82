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

from .estimation import GravityUnknown, PointForceUnknown, estimate
from .robot import Robot


@dataclass(frozen=True)
class ExperimentRow:
    case: str
    applied: np.ndarray
    ours: np.ndarray | None
    paper: np.ndarray | None
    converged: bool

    def error(self, which: np.ndarray | None) -> float:
        if which is None:
            return float("nan")
        return float(np.linalg.norm(which - self.applied) / np.linalg.norm(self.applied))


def _numbers(text: str) -> list[float]:
    return [float(t) for t in re.split(r"[\s;,]+", text.strip()) if t]


def _unknowns(row: dict) -> list:
    kind = row["unknown"].strip().lower()
    if kind == "gravity":
        return [GravityUnknown()]
    X = float(row["force_X"])
    d = _numbers(row.get("direction", "") or "")
    if "3d" in kind.replace("-", "") or not d:
        return [PointForceUnknown(X, tuple(e)) for e in np.eye(3)]
    if len(d) % 3:
        raise ValueError(f"direction {row['direction']!r} is not groups of 3 numbers")
    return [PointForceUnknown(X, tuple(d[i:i + 3])) for i in range(0, len(d), 3)]


def run(robot: Robot, path: str | Path, progress=None) -> list[ExperimentRow]:
    """Estimate every row of the experiments CSV with ``robot``'s settings (nothing per row)."""
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    out = []
    for row in rows:
        names = re.split(r"[\s;,+]+", row["tendon"].strip())
        T, y = _numbers(row["tension_N"]), _numbers(row["displacement_m"])
        if not (len(names) == len(T) == len(y)):
            raise ValueError(f"case {row['case']}: {len(names)} tendons, {len(T)} tensions, "
                             f"{len(y)} displacements")
        unknowns = _unknowns(row)
        res = estimate(robot, dict(zip(names, y)), dict(zip(names, T)), unknowns)
        applied = np.array(_numbers(row["applied"]))
        paper = row.get("paper_estimate", "").strip()
        out.append(ExperimentRow(
            row["case"], applied, res.magnitudes if res.converged else None,
            np.array(_numbers(paper)) if paper else None, bool(res.converged)))
        if progress is not None:
            progress(len(out), len(rows))
    return out


def summary(rows: list[ExperimentRow]) -> dict:
    ours = [r.error(r.ours) for r in rows]
    paper = [r.error(r.paper) for r in rows if r.paper is not None]
    return {"rows": len(rows), "converged": sum(r.converged for r in rows),
            "mean_relative_error_ours": float(np.nanmean(ours)) if rows else float("nan"),
            "mean_relative_error_paper": float(np.mean(paper)) if paper else float("nan")}
