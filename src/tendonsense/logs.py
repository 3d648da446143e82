"""Estimation over a log of readings (:mod:`tendonsense.readings`): a file on the compiled scan
of :mod:`tendonsense.tracking`, its rows handed over as chunks finish; a live stream sample by
sample (:class:`~tendonsense.online.OnlineEstimator`), its programs built before the first row
is read."""

from __future__ import annotations

import csv
import itertools
import math
import os
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from pathlib import Path
from typing import Callable, Iterator, Sequence

import numpy as np

from .estimation import Noise, Unknown, problem
from .inputs import WALK, check_unknowns
from .online import OnlineEstimator
from .problem import MISFIT, MISFIT_QUANTILE
from .readings import (SKIPPED_SHOWN, LagWatch, LogSummary, ReadingsError, ReleaseWatch,
                       Sample, check_units, has_time, lagging, located, motion_step_error,
                       output_header, output_row, output_rows, parse_header, parse_row,
                       read_readings, released_at_start, stuck_rows_error, time_back,
                       with_sliding, write_csv_atomic)
from .result import joined
from .robot import Robot
from .sliding import GIVEN, FrictionHistory, band_note, band_range
from .tendons import turns
from .tracking import SampleEstimate, series_chunks

#: samples per compiled scan of a file log
CHUNK = 100
#: chunks a file log's scan may run ahead of their stuck rows' ranges
AHEAD = 8
#: a stream's first rows that decide whether a column is in the wrong unit
UNIT_ROWS = 50
#: the fewest of them that decide whether a stream's time stamps are seconds (--dynamic)
STAMP_ROWS = 10


def estimate_chunks(robot: Robot, measured: Sequence[str], samples: Sequence[Sample],
                    unknowns: Sequence[Unknown], point_forces=(), noise: Noise = Noise(),
                    dynamic: bool = False, walk: float = WALK
                    ) -> Iterator[tuple[int, list[SampleEstimate]]]:
    """Estimate every good sample of a log in order, each warm-started from the last good one
    (:func:`~tendonsense.tracking.series_chunks`); yields ``(first, estimates)`` as chunks
    finish (with the friction history, each once its stuck rows have their range, computed
    while the scan goes on, up to :data:`AHEAD` chunks ahead); a sample the reader skipped is
    an estimate that did not converge, its note ``skipped: <why>``. ``dynamic``: over the
    samples' time stamps with the damped model (:class:`~tendonsense.filtering.MotionFilter`).
    A row saying a tendon is stuck is a ValueError with a force of unknown location."""
    prob = problem(robot, measured, unknowns, point_forces)
    if prob.located and (error := stuck_rows_error("the log", samples)):
        raise ValueError(error)
    if dynamic:
        if error := motion_step_error("the log", samples):
            raise ValueError(error)
        online = OnlineEstimator(prob, noise, dynamic=True, walk=walk)
        for first in range(0, len(samples), CHUNK):
            yield first, [_skipped(prob, s) if s.error else online.update(
                s.displacements, s.tensions, s.time, s.sliding)
                for s in samples[first:first + CHUNK]]
        return
    good = [k for k, s in enumerate(samples) if not s.error]
    out = [_skipped(prob, s) if s.error else None for s in samples]
    done = 0
    history = FrictionHistory(prob.model.values.friction, turns=turns(prob.model.values))
    follow = history.active and not prob.located
    names = robot.tendon_names
    said = [[samples[k].sliding.get(t, "") for t in names] for k in good]
    given = np.array([[GIVEN[d] for d in row] for row in said]).reshape(len(good), len(names))
    stuck = np.array([[d == "stuck" for d in row] for row in said]).reshape(given.shape)
    chunks = series_chunks(prob, [samples[k].displacements for k in good],
                           [samples[k].tensions for k in good], noise, CHUNK,
                           history=history if follow else None,
                           given=given if follow else None, stuck=stuck if follow else None)

    def place(first, estimates):  # -> the samples done with it (bad ones between included)
        nonlocal done
        for k, e in zip(good[first:first + len(estimates)], estimates):
            out[k] = e
        end = (good[first + len(estimates)] if first + len(estimates) < len(good)
               else len(samples))
        start, done = done, end
        return start, out[start:end]

    if not follow:
        for first, estimates in chunks:
            yield place(first, estimates)
    else:
        # a chunk's stuck rows' range on a second thread, while the scan goes on with the next
        # chunks (the compiled programs release the GIL: each takes a core)
        pool = ThreadPoolExecutor(1)
        pending: deque = deque()

        def handed(keep: int):  # the chunks whose ranges are done, in order, and the oldest
            # while more than ``keep`` wait; a range that failed raises, its chunk kept back
            while pending and (len(pending) > keep or pending[0][1].done()):
                first, ranged = pending[0]
                estimates = ranged.result()
                pending.popleft()
                yield place(first, estimates)

        try:
            ends: dict = {}  # each band end's last solution (_stuck_ranges)
            try:
                for first, estimates in chunks:
                    rows = [samples[k] for k in good[first:first + len(estimates)]]
                    pending.append((first, pool.submit(_stuck_ranges, prob, rows, estimates,
                                                       noise, first, ends)))
                    yield from handed(AHEAD)
            except Exception:  # the chunks scanned before a failure are still handed over
                yield from handed(0)
                raise
            yield from handed(0)
        finally:  # (stopped early: the ranges not started are dropped)
            pool.shutdown(cancel_futures=True)
    if done < len(samples):
        yield done, out[done:]


def _stuck_ranges(prob, rows: Sequence[Sample], estimates: list[SampleEstimate],
                  noise: Noise, first: int = 0, ends: dict | None = None
                  ) -> list[SampleEstimate]:
    """Estimates that followed their tendons' friction history
    (:class:`~tendonsense.sliding.FrictionHistory`), and where a tendon is stuck the range of
    the magnitudes over its band: the stuck rows estimated again as a series with each stuck
    tendon pulled in and paid out. ``ends``: each end's last solution and its row (numbered
    among the log's good rows, ``rows`` from ``first``), kept from one chunk to the next, so
    that an end goes on from the row before where a stretch of stuck rows runs on (else from
    the row's own estimate)."""
    ends = {} if ends is None else ends
    out = list(estimates)
    states = np.array([e.friction_state for e in out])
    stuck_of = np.array([[d == "stuck" for d in e.sliding] for e in out]).reshape(states.shape)
    stuck = [j for j in range(len(out)) if stuck_of[j].any() and out[j].converged]
    if not stuck:
        return out
    columns = np.flatnonzero(stuck_of[stuck].any(axis=0))
    corners = []
    for signs in itertools.product((-1.0, 1.0), repeat=len(columns)):
        key = (tuple(columns), signs)
        row, x = ends.get(key, (None, None))
        start = x if row == first + stuck[0] - 1 else out[stuck[0]].x
        s = states[stuck].copy()
        for c, sign in zip(columns, signs):
            s[:, c] = np.where(stuck_of[stuck, c], sign, s[:, c])
        got = []
        for _, chunk in series_chunks(prob, [rows[j].displacements for j in stuck],
                                      [rows[j].tensions for j in stuck], noise, CHUNK,
                                      start=start,
                                      history=FrictionHistory(
                                          prob.model.values.friction,
                                          turns=turns(prob.model.values)),
                                      given=s, persistent=False):
            got += chunk
        corners.append([e.magnitudes if e.converged else np.full(prob.n_magnitudes, np.nan)
                        for e in got])
        if got[-1].converged:
            ends[key] = (first + stuck[-1], got[-1].x)
    for i, j in enumerate(stuck):
        at_ends = [c[i] for c in corners]
        out[j] = replace(out[j], magnitude_range=band_range(out[j].magnitudes, at_ends),
                         note=joined(out[j].note, band_note(out[j].magnitudes, at_ends)))
    return out


def disagreeing(estimates: Sequence[SampleEstimate]) -> int:
    """How many of ``estimates`` say their readings disagree beyond their noise
    (:func:`~tendonsense.problem.misfit_notes`)."""
    return sum(MISFIT in e.note for e in estimates)


def chance(rows: int, p: float, q: float) -> int:
    """The ``q`` quantile of the binomial distribution of ``rows`` trials of probability
    ``p``: the fewest k with P(X ≤ k) ≥ q (its terms summed in log form: no SciPy, whose
    statistics take a second to import, at the end of every log)."""
    log_term, total = rows * math.log1p(-p), 0.0
    for k in range(rows + 1):
        total += math.exp(log_term)
        if total >= q:
            return k
        log_term += math.log((rows - k) / (k + 1) * p / (1 - p))
    return rows


def misfit_rows(n: int, rows: int) -> str:
    """A log's note that ``n`` of its ``rows`` rows disagree beyond their noise, or '' where
    chance explains as many (each row's test lets 1 − MISFIT_QUANTILE of rows through: a
    count within the binomial's MISFIT_QUANTILE quantile; the rows keep their notes)."""
    if n <= chance(rows, 1 - MISFIT_QUANTILE, MISFIT_QUANTILE):
        return ""
    return (f"{n} of {rows} rows: {MISFIT} (their note column says by how "
            f"much; is a tendon swapped or mislabelled, a force's X or direction wrong, a load "
            f"not given?)")


def _skipped(prob, s: Sample) -> SampleEstimate:
    """The estimate of a sample the reader skipped."""
    return SampleEstimate.failed(prob, f"skipped: {s.error}")


def estimate_readings(robot: Robot, measured: Sequence[str], samples: Sequence[Sample],
                      unknowns: Sequence[Unknown], point_forces=(), noise: Noise = Noise(),
                      progress: Callable[[int, int], None] | None = None,
                      dynamic: bool = False, walk: float = WALK
                      ) -> list[SampleEstimate]:
    """:func:`estimate_chunks`, collected (a sample the reader skipped: an estimate that did
    not converge, its note ``skipped: <why>``); ``progress(done, total)`` is called per
    chunk."""
    out: list[SampleEstimate] = []
    for first, estimates in estimate_chunks(robot, measured, samples, unknowns, point_forces,
                                            noise, dynamic, walk):
        out += estimates
        if progress:
            progress(first + len(estimates), len(samples))
    return out


def estimate_file(robot: Robot, log: str | Path, out: str | Path, unknowns: Sequence[Unknown],
                  point_forces=(), noise: Noise = Noise(), dynamic: bool = False,
                  walk: float = WALK) -> LogSummary:
    """Read the log ``log``, estimate every row (:func:`estimate_readings`) and write the
    estimates to ``out`` atomically, as ``estimate --readings LOG -o OUT`` does. A log that
    cannot be used (unreadable, a bad header, too few measured tendons for ``unknowns``) is
    not raised but returned as :attr:`LogSummary.error`, and nothing is written."""
    try:
        if Path(out).is_file() and Path(log).is_file() and os.path.samefile(out, log):
            raise ValueError(f"its output {out} is the log itself (it would be overwritten)")
        measured, samples = read_readings(log, robot)
        try:
            check_unknowns(robot, measured, unknowns)
        except ValueError as exc:
            raise ValueError(f"{log}: {exc}") from None
        if located(unknowns) and (error := stuck_rows_error(log, samples)):
            raise ValueError(error)
        if dynamic and not has_time(log):
            raise ReadingsError(f"{log}: no time column: estimation in motion (dynamic) "
                                f"needs each row's time stamp, s")
        if dynamic and (error := motion_step_error(log, samples)):
            raise ReadingsError(error)
        results = estimate_readings(robot, measured, samples, unknowns, point_forces, noise,
                                    dynamic=dynamic, walk=walk)
        write_csv_atomic(out, *output_rows(robot, samples, results, len(unknowns),
                                           located(unknowns), with_sliding(robot)))
    except (ValueError, OSError) as exc:
        msg = str(exc)
        return LogSummary(str(log), str(out),
                          error=msg if msg.startswith(str(log)) else f"{log}: {msg}")
    bad = [(s.row, s.error) for s in samples if s.error]
    return LogSummary(str(log), str(out), len(samples),
                      sum(r.converged for r in results), len(bad),
                      skipped_rows=tuple(bad[:SKIPPED_SHOWN]),
                      note=joined("" if located(unknowns) else released_at_start(
                          samples, robot, noise.tension),
                          "" if dynamic or located(unknowns) else lagging(
                              samples, robot, measured, noise.length),
                          misfit_rows(disagreeing(results), len(results))))


def online_estimator(robot: Robot, measured: Sequence[str], unknowns: Sequence[Unknown],
                     point_forces=(), noise: Noise = Noise(), rescue_budget=None,
                     dynamic: bool = False, walk: float = WALK) -> OnlineEstimator:
    """An :class:`OnlineEstimator` whose programs are built (or loaded from the disk cache)
    now, so that its first reading is answered at full speed."""
    online = OnlineEstimator(problem(robot, measured, unknowns, point_forces), noise,
                             rescue_budget=rescue_budget, dynamic=dynamic, walk=walk)
    online.prepare()
    return online


#: a streamed row whose line has no line break: the input ended within it
CUT = "the input ended within this row (no line break after it): a reading cut short"


class _Lines:
    """The lines of a stream, and whether the last one read ended with a line break."""

    def __init__(self, lines):
        self.lines, self.ended = iter(lines), True

    def __iter__(self):
        return self

    def __next__(self) -> str:
        line = next(self.lines)
        self.ended = line.endswith(("\n", "\r"))
        return line


def stream_readings(robot: Robot, lines, out, unknowns: Sequence[Unknown], point_forces=(),
                    noise: Noise = Noise(), source="<stdin>", on_skip=None,
                    on_sample=None, dynamic: bool = False, walk: float = WALK,
                    on_note=None) -> tuple[int, int]:
    """Live estimation: read READINGS.csv lines from ``lines`` (an iterable of text lines) and
    write each output row to ``out`` as soon as it is estimated, flushed; then call
    ``on_sample(sample, estimate or None)`` (e.g. a :class:`~tendonsense.view.Viewer`'s push).
    A column whose first :data:`UNIT_ROWS` rows say it is in the wrong unit (as a file's rows,
    :func:`~tendonsense.readings.check_units`) stops the stream with a ReadingsError.
    The estimator's programs are built after the header, before the first row is read.
    Returns (rows, converged). Ends at the end of the input; the caller handles an interrupt
    (every row written so far is complete). ``dynamic``: with the damped model over the rows'
    time stamps (the log needs a ``time`` column). ``on_note(note)``: a stream estimated at
    rest that moves a damped robot faster than its shape follows is said once
    (:class:`~tendonsense.readings.LagWatch`), and so is a tendon released from its first
    row (:class:`~tendonsense.readings.ReleaseWatch`). Where the header ends with a line
    break, a row without one (the input cut within it) is skipped (:data:`CUT`)."""
    lines = _Lines(lines)
    reader = csv.reader(lines)
    try:
        header = next(reader)
    except StopIteration:
        raise ReadingsError(f"{source}: no header row") from None
    ends = lines.ended  # lines that end with a line break: one without is a cut row
    columns = parse_header(header, robot, source)
    if dynamic and "time" not in columns.header:
        raise ReadingsError(f"{source}: no time column: estimation in motion (--dynamic) "
                            f"needs each row's time stamp, s")
    writer = csv.writer(out, lineterminator="\n")
    with_shape = bool(columns.markers)
    follow = with_sliding(robot)
    writer.writerow(output_header(robot, len(unknowns), with_shape, located(unknowns), follow))
    out.flush()
    online = online_estimator(robot, columns.measured, unknowns, point_forces, noise,
                              dynamic=dynamic, walk=walk)
    rows = good = 0
    watch = LagWatch(robot, columns.measured, noise.length) if on_note and not (
        dynamic or located(unknowns)) else None
    release = ReleaseWatch(robot, noise.tension) if on_note and not located(unknowns) else None
    last = None  # the last good row's time
    first: list[list[str]] = []
    timed: list[Sample] = []  # in motion: the first rows' good samples, for their stamps
    for i, raw in enumerate(reader, start=1):
        if not any(c.strip() for c in raw):
            continue
        if len(first) < UNIT_ROWS:  # a column in the wrong unit stops the stream, as a file
            first.append(raw)
            check_units(f"{source} (its first {len(first)} rows)", columns, robot, first)
        s = parse_row(i, raw, columns, robot)
        if ends and not lines.ended and not s.error:
            s = replace(s, tensions={}, displacements={}, markers={}, error=CUT)
        if not s.error and s.time is not None:  # rows in time order (a file's rule)
            if back := time_back(s.time, last, once=dynamic):
                s = replace(s, error=back)
            else:
                last = s.time
                if dynamic and len(timed) < UNIT_ROWS:  # stamps in seconds, as a file's
                    timed.append(s)  # (decided on STAMP_ROWS at least: a pause at the start)
                    if len(timed) >= STAMP_ROWS and (error := motion_step_error(
                            f"{source} (its first {len(timed)} rows)", timed,
                            " (a static stream is estimated without --dynamic)")):
                        raise ReadingsError(error)
        for said in (watch, release):
            if said is not None and (note := said(s)):
                on_note(note)
        r = None if s.error else online.update(s.displacements, s.tensions, s.time, s.sliding)
        if r is None and on_skip:
            on_skip(s)
        writer.writerow(output_row(robot, s, r, len(unknowns), with_shape, located(unknowns),
                                   follow))
        out.flush()
        if on_sample is not None:
            on_sample(s, r)
        rows, good = rows + 1, good + bool(r is not None and r.converged)
    return rows, good

