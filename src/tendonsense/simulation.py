"""Forward dynamics over time (the manual's *The robot in motion*): tendon tensions and
known forces over time → the rod's motion and the readings a robot would log (``time``,
``tension_<name>``, ``displacement_<name>``, ``marker_<name>_x/_y/_z``), with read-out noise
when asked, so that an experiment can be rehearsed before it is run (:func:`simulate`)."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np

from . import inputs
from .dynamics import Schedule, integrator
from .forward import model_for
from .result import compact_repr, fields_json
from .robot import Robot
from .statics import shape_outputs

#: output samples per call of the compiled integrator (the last call padded)
CHUNK = 250

#: the default integration step, s (samples between steps are interpolated)
MAX_STEP = inputs.MAX_STEP

#: the friction state a direction sets (NaN: the tension history decides)
STATES = {"in": 1.0, "out": -1.0, "follow": np.nan}


@dataclass(frozen=True, eq=False)
class Simulation:
    """A simulated motion, one row per output time: ``q`` and ``v`` (q̇) ``(n, nq)``, the
    tensions (N), tendon length changes (m) and marker positions ``(n, 3)`` (global, m) by name;
    ``converged`` per sample (every step solved, the strain in the model's range); every
    tendon's friction state by name, its anchor's (+1 pulled in, −1 paid out, stuck between;
    the state is kept at every turn, :mod:`tendonsense.sliding`)."""

    time: np.ndarray
    q: np.ndarray
    v: np.ndarray
    tensions: dict[str, np.ndarray]
    displacements: dict[str, np.ndarray]
    markers: dict[str, np.ndarray]
    converged: np.ndarray
    friction_state: dict[str, np.ndarray]
    robot: Robot | None = field(default=None, repr=False)  # the robot simulated

    __repr__ = compact_repr
    to_json = fields_json

    @property
    def ok(self) -> bool:
        return bool(np.all(self.converged))

    def readings(self, noise_length: float = 0.0, noise_tension: float = 0.0,
                 seed: int | None = None) -> dict[str, np.ndarray]:
        """The readings log's columns (the manual's *Conventions and file formats*): Gaussian
        read-out noise of ``noise_length`` (m) on the length changes and ``noise_tension``
        (relative) on the tensions, none on the markers; a noisy tension below 0 reads 0 (a
        sensor of a slack tendon). A sample that did not converge reads NaN in its lengths
        and markers (its shape is not known)."""
        if inputs.finite("noise_length", noise_length) < 0:
            raise ValueError(f"noise_length: must be >= 0 m, got {noise_length:g}")
        if self.robot is not None and (
                error := inputs.length_noise_error(self.robot, "noise_length", noise_length)):
            raise ValueError(error)
        if not 0 <= inputs.finite("noise_tension", noise_tension) < 1:
            raise ValueError(f"noise_tension: {inputs.FRACTION}, got {noise_tension:g}")
        if seed is not None and not (isinstance(seed, (int, np.integer)) and seed >= 0):
            raise ValueError(f"seed: a whole number >= 0 or None, got {seed!r}")
        rng = np.random.default_rng(seed)
        cols = {"time": self.time}
        for n, T in self.tensions.items():
            noisy = T * (1 + noise_tension * rng.standard_normal(T.shape))
            cols[f"tension_{n}"] = np.maximum(noisy, 0.0)
        failed = ~np.asarray(self.converged, bool)
        for n, y in self.displacements.items():
            noisy = y + noise_length * rng.standard_normal(y.shape)
            cols[f"displacement_{n}"] = np.where(failed, np.nan, noisy)
        for n, p in self.markers.items():
            for i, a in enumerate("xyz"):
                cols[f"marker_{n}_{a}"] = np.where(failed, np.nan, p[:, i])
        return cols


def _is_series(e) -> bool:
    """``(times, values)``: a pair whose first item is a sequence of times."""
    return isinstance(e, tuple) and len(e) == 2 and np.ndim(e[0]) == 1


def _table(entries: Sequence, width: int, labels: Sequence[str]):
    """Merge per-column schedules into one table: each entry a constant (shape ``width``) or
    ``(times, values (k, width))``; linear between rows, held after the last. ``labels``
    name the entries in messages."""
    out, series = [], []
    for label, e in zip(labels, entries):
        if _is_series(e):
            t, v = np.asarray(e[0], float), np.asarray(e[1], float)
            if t.ndim != 1 or t.size == 0 or np.any(np.diff(t) <= 0) or not np.all(np.isfinite(t)):
                raise ValueError(f"{label}: the times must be finite and increasing")
            if v.size != t.size * width:
                raise ValueError(f"{label}: {t.size} times and {v.size // width} values (one "
                                 f"per time)")
            series.append((t, v.reshape(t.size, width)))
    grid = np.unique(np.concatenate([[0.0], *(t for t, _ in series)]))
    for e in entries:
        if _is_series(e):
            t, v = series.pop(0)
            out.append(np.stack([np.interp(grid, t, v[:, j]) for j in range(width)], axis=1))
        else:
            out.append(np.broadcast_to(np.asarray(e, float).reshape(width), (grid.size, width)))
    return grid, np.stack(out, axis=1) if out else np.zeros((grid.size, 0, width))


def simulate(robot: Robot, tensions: Mapping[str, float | tuple] | None = None,
             point_forces: Sequence = (), duration: float = 1.0, output_dt: float = 0.01,
             max_step: float = MAX_STEP, inertia: bool = True, q0=None,
             sliding: Mapping[str, str] | None = None, at=None) -> Simulation:
    """Forward dynamics from rest at ``q0`` (default the straight rod) at t = 0, gravity and
    the given loads acting from t = 0, sampled every ``output_dt`` s up to ``duration``.

    ``tensions``: {tendon: N} constant, or {tendon: (times, values)} linear between the rows
    and held after the last (tendons not named are slack); ``point_forces``: [(X, f)] with f
    a global force (N) or ``(times, forces (k, 3))``. TR-BDF2 steps of ``max_step`` s (halved
    where a solve fails; a warning where it is coarse for the rod's relaxation time,
    :func:`~tendonsense.inputs.coarse_step`); samples between steps by cubic Hermite
    interpolation of q and q̇.
    The last sample is at ``duration``, also where ``output_dt`` does not divide it.
    ``at``: sample at these times (s, increasing, in (0, duration]) instead of every
    ``output_dt`` (e.g. a log's own time stamps); without them, a ``duration`` more than a
    minute past the loads' last change is refused as a unit slip. ``inertia=False`` drops
    ``M q̈`` and ``C q̇`` (the quasi-static limit with damping; needs ``[rod] damping`` > 0).
    ``sliding`` {tendon: in|out|follow}: the sense of a tendon's friction; ``follow`` (the
    default) as the estimators take it: pulled in while its tension rises, stuck when it
    turns, paid out once it has fallen through the band (a tendon released); ``in`` is eq. 10
    as written whatever the tension does.

    >>> sim = simulate(robot, {"t1": ([0, 1, 2], [0.0, 3.0, 3.0])}, duration=3.0)
    >>> sim.markers["tip"][-1], sim.readings(noise_length=1e-4, seed=0)["displacement_t1"]
    """
    duration = inputs.finite("duration", duration)
    output_dt = inputs.finite("output_dt", output_dt)
    max_step = inputs.finite("max_step", max_step)
    if not (duration > 0 and output_dt > 0 and max_step > 0):
        raise ValueError("duration, output_dt and max_step must be > 0")
    if at is None and output_dt > duration:
        raise ValueError(f"output_dt {output_dt:g} s is longer than the duration {duration:g} s")
    if max_step > duration:
        raise ValueError(f"max_step {max_step:g} s is longer than the duration {duration:g} s")
    if coarse := inputs.coarse_step(robot, max_step):
        warnings.warn(coarse, stacklevel=2)
    if not inertia and robot.rod.damping <= 0:
        raise ValueError("without inertia the motion needs [rod] damping > 0 (with neither, "
                         "every instant is the static equilibrium: use solve)")
    names = robot.tendon_names
    tensions = dict(tensions or {})
    for name in tensions:
        if name not in names:
            raise ValueError(f"tension {name}: no such tendon (robot has {', '.join(names)})")
    T_entries = []
    for name in names:
        e = tensions.get(name, 0.0)
        values = np.asarray(e[1] if _is_series(e) else e, float)
        for v in values.ravel():
            if error := inputs.tension_error(robot, name, float(v)):
                raise ValueError(error)
        T_entries.append(e)
    T_times, T = _table(T_entries, 1, [f"tension {n}" for n in names])
    directions = inputs.sliding(robot, sliding, inputs.SIMULATED_SLIDING, "follow")
    X, F_entries = [], []
    for i, (x, f) in enumerate(point_forces):
        rows = np.asarray(f[1], float).reshape(-1, 3) if _is_series(f) else [f]
        if not len(rows) or not np.all(np.isfinite(rows)):
            raise ValueError(f"point force {i + 1}: the forces must be finite")
        for row in rows:  # every row of a schedule by the rule
            inputs.check_point_forces(robot, [(x, row)])
        X.append(float(x))
        F_entries.append(f)
    if not X:  # one zero force at the base: one program with and without point forces
        X, F_entries = [0.0], [np.zeros(3)]
    F_times, F = _table(F_entries, 3, [f"point force {i + 1}" for i in range(len(F_entries))])
    if at is None and (error := inputs.duration_error("duration", duration, max(
            inputs.last_change(T_times, T), inputs.last_change(F_times, F)))):
        raise ValueError(error)
    schedule = Schedule(T_times, T[:, :, 0], F_times, F, np.array(X, float),
                        np.asarray(robot.gravity, float),
                        np.array([STATES[d] for d in directions.values()]))

    model = model_for(robot)
    nq = model.nq
    q = np.zeros(nq) if q0 is None else inputs.start(q0, nq)
    if at is None:
        # (0.35, not k × 0.01 = 0.35000000000000003, in the readings' time column); the
        # last row at the duration, also where output_dt does not divide it
        times = np.round(np.arange(1, int(np.floor(duration / output_dt + 1e-9)) + 1)
                         * output_dt, 12)
        if times[-1] < duration - 1e-9 * output_dt:
            times = np.append(times, duration)
    else:
        times = np.asarray(at, float).reshape(-1)
        if (times.size == 0 or not np.all(np.isfinite(times)) or times[0] <= 0
                or np.any(np.diff(times) <= 0) or times[-1] > duration * (1 + 1e-12)):
            raise ValueError("at: the sample times must be finite, increasing and in "
                             "(0, duration]")
    start, run = integrator(model.structure, bool(inertia))
    state = start(q, np.float64(0.0), schedule, model.values)
    markers, _, y, fine = shape_outputs(model.structure, model.values, q)
    first = (q, np.asarray(state.v), markers, y, True, fine,
             np.asarray(state.band.s)[:, -1])  # a tendon's state: its anchor's
    parts = []
    for k in range(0, times.size, CHUNK):
        chunk = times[k:k + CHUNK]
        padded = np.concatenate([chunk, np.full(CHUNK - chunk.size, chunk[-1])])  # no steps
        state, out = run(state, padded, np.float64(max_step), schedule, model.values)
        parts.append([np.asarray(a)[:chunk.size] for a in out])
    qs, vs, mk, ys, ok, fine, states = (np.concatenate([[f], *(p[i] for p in parts)])
                                        for i, f in enumerate(first))
    t_all = np.concatenate([[0.0], times])
    return Simulation(
        t_all, qs, vs, {n: np.interp(t_all, T_times, T[:, j, 0]) for j, n in enumerate(names)},
        {n: ys[:, j] for j, n in enumerate(names)},
        {m: mk[:, i] for i, m in enumerate(robot.marker_names)}, ok & fine,
        {n: np.nan_to_num(states[:, j], nan=1.0) for j, n in enumerate(names)}, robot)

