"""One result object for every problem, in the spirit of scipy's ``OptimizeResult``, and
the lighter one of a sample in a series."""

from __future__ import annotations

import dataclasses
import functools
import os
import sys
import warnings
from dataclasses import dataclass, field

import numpy as np


def _short(v) -> str:
    """``v`` in a line: an array of more than six numbers by its shape, numbers to 6 digits."""
    if isinstance(v, np.ndarray) or hasattr(v, "__array__") and hasattr(v, "shape"):
        a = np.asarray(v)
        if a.size > 6:
            return f"<array {a.shape}>"
        if a.ndim == 0:
            return _short(a.item())
        return np.array2string(a, precision=6, separator=", ")
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k!r}: {_short(x)}" for k, x in v.items()) + "}"
    if isinstance(v, (list, tuple)) and len(v) > 6:
        return f"<{type(v).__name__} of {len(v)}>"
    if isinstance(v, (float, np.floating)):
        return f"{float(v):.6g}"
    if hasattr(v, "tendon_names") and hasattr(v, "rod"):  # a Robot: by its name
        return f"<Robot {v.name!r}>"
    return repr(v)


def joined(*notes) -> str:
    """Notes joined by "; ", the empty ones (or None, False) left out."""
    return "; ".join(filter(None, notes))


def compact_repr(self) -> str:
    """A result's fields in a notebook's echo: long arrays by their shape."""
    return (f"{type(self).__name__}(" + ", ".join(
        f"{f.name}={_short(getattr(self, f.name))}" for f in dataclasses.fields(self) if f.repr)
        + ")")


class NotConvergedWarning(UserWarning):
    """A solve or an estimate of the Python API (:func:`~tendonsense.forward.solve`,
    :func:`~tendonsense.forward.forward_kinematics`, :func:`~tendonsense.estimation.estimate`)
    that found no solution: its :class:`Result` holds the solver's last iterate
    (``converged`` False, :attr:`Result.note` says why), no shape the robot holds."""


def warns_if_not_converged(fn):
    """``fn`` (returning a :class:`Result`) warning :class:`NotConvergedWarning` where the
    result did not converge and the caller is outside this package (whose own callers say it
    their way: the command line's NOT CONVERGED, a table's column)."""
    @functools.wraps(fn)
    def said(*args, **kwargs):
        result = fn(*args, **kwargs)
        caller = os.path.dirname(sys._getframe(1).f_code.co_filename)
        if not result.converged and caller != os.path.dirname(__file__):
            warnings.warn(f"{fn.__name__} did not converge: {result.note or 'no reason given'}"
                          f"; its result is the solver's last iterate, no solution "
                          f"(result.converged is False)", NotConvergedWarning, stacklevel=2)
        return result
    return said


@dataclass(frozen=True, eq=False)
class Result:
    """Solution of a forward-statics, forward-kinematics or estimation problem.

    Lengths in metres, forces in newtons, all positions in the global frame.
    """

    q: np.ndarray  # generalized coordinates (eq. 5)
    tensions: dict[str, float]  # N, tension at the actuator of every tendon
    displacements: dict[str, float]  # m, tendon length changes y (eq. 9)
    markers: dict[str, np.ndarray]  # marker positions
    backbone: np.ndarray  # (n, 3) centre line from base to tip
    converged: bool
    iterations: int
    residual: float  # relative residual norm at the returned q
    magnitudes: np.ndarray | None = None  # estimation: unknown load magnitudes, in order
    sigma: np.ndarray | None = None  # estimation: 1-σ band of the magnitudes
    sensitivity: dict[str, np.ndarray] | None = None  # ∂magnitudes/∂measurement
    extra: dict = field(default_factory=dict)

    __repr__ = compact_repr

    @property
    def note(self) -> str:
        """Why the result is no solution, or a remark on it ('' if none)."""
        return self.extra.get("note") or ""

    @property
    def magnitude_range(self) -> np.ndarray:
        """An estimate with a stuck tendon: (n, 2) ``[low, high]`` of each magnitude over its
        friction band (±inf where open), ``magnitudes`` being at the band's middle; (0, 2)
        otherwise (as :attr:`SampleEstimate.magnitude_range`)."""
        band = self.extra.get("magnitude_range")
        return np.zeros((0, 2)) if band is None else np.asarray(band, float).reshape(-1, 2)

    def to_json(self) -> dict:
        """The documented JSON keys (plus uncertainty for estimates) as plain JSON types."""
        out = {}
        if self.magnitudes is not None:
            out["magnitudes"] = _plain(self.magnitudes)
        out.update(
            q=_plain(self.q), tensions=_plain(self.tensions),
            displacements=_plain(self.displacements), markers=_plain(self.markers),
            backbone=_plain(self.backbone), converged=bool(self.converged),
            iterations=int(self.iterations), residual=_plain(float(self.residual)))
        if self.sigma is not None:
            out["sigma"] = _plain(self.sigma)
        if self.sensitivity is not None:
            out["sensitivity"] = _plain(self.sensitivity)
        out.update(_plain(self.extra))
        return out


def fields_json(self) -> dict:
    """A result's shown fields as plain JSON types (arrays as lists, NaN and infinity as
    null), for ``json.dump``."""
    return {f.name: _plain(getattr(self, f.name)) for f in dataclasses.fields(self) if f.repr}


def _plain(v):
    if isinstance(v, dict):
        return {k: _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    if isinstance(v, np.ndarray) and v.dtype.kind in "USObiu":  # notes, flags, counts
        return _plain(v.tolist())
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (int, np.integer)):
        return int(v)
    if isinstance(v, np.ndarray) or hasattr(v, "__array__"):
        a = np.asarray(v, float)
        return a.tolist() if np.isfinite(a).all() else _plain(a.tolist())
    if isinstance(v, (float, np.floating)):
        return float(v) if np.isfinite(v) else None  # JSON has no NaN or infinity
    return v


@dataclass(frozen=True, eq=False)
class SampleEstimate:
    """One sample of a series: magnitudes with their 1-σ band, markers (global, m). A sample
    that is no estimate (``converged`` False) has not-a-number magnitudes, bands and located
    X, whatever its solver reached (its ``x`` keeps the last iterate, its ``note`` why)."""

    magnitudes: np.ndarray
    sigma: np.ndarray
    markers: dict[str, np.ndarray]
    converged: bool
    iterations: int
    x: np.ndarray
    note: str = ""  # why a sample is not converged, or a remark on it (e.g. confounded)
    locations: np.ndarray = field(default_factory=lambda: np.zeros(0))  # located forces' X, m
    location_sigma: np.ndarray = field(default_factory=lambda: np.zeros(0))
    # per tendon (its anchor's), ±1
    friction_state: np.ndarray = field(default_factory=lambda: np.zeros(0))
    sliding: tuple[str, ...] = ()  # per tendon: in, out or stuck; empty: not followed (in)
    magnitude_range: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # if stuck

    __repr__ = compact_repr
    to_json = fields_json

    def __post_init__(self):
        if not self.converged:  # (a list of them reads as numbers no more)
            for name in ("magnitudes", "sigma", "locations", "location_sigma",
                         "magnitude_range"):
                object.__setattr__(self, name, np.full(np.shape(getattr(self, name)), np.nan))

    @staticmethod
    def of(r: Result) -> "SampleEstimate":
        """A single estimate (:class:`Result`, e.g. a series' sample solved on its own) as a
        sample of a series."""
        note = r.note or ("" if r.converged else "did not converge")
        located = [k for k, v in enumerate(r.extra.get("locations", [])) if v is not None]
        return SampleEstimate(np.asarray(r.magnitudes), np.asarray(r.sigma), dict(r.markers),
                              bool(r.converged), int(r.iterations), np.asarray(r.extra["x"]),
                              note, np.array([r.extra["locations"][k] for k in located]),
                              np.array([r.extra["location_sigma"][k] for k in located]))

    @staticmethod
    def failed(prob, note: str, x=None, iterations: int = 0) -> "SampleEstimate":
        """A sample of the :class:`~tendonsense.problem.Problem` ``prob`` that has no estimate
        (not-a-number magnitudes and markers)."""
        nan = np.full(prob.n_magnitudes, np.nan)
        x = np.full(prob.model.nq + prob.n_z, np.nan) if x is None else x
        loc = np.full(len(prob.located), np.nan)
        return SampleEstimate(nan, nan.copy(), {m: np.full(3, np.nan)
                                                for m in prob.robot.marker_names},
                              False, iterations, x, note, loc, loc.copy())
