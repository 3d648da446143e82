"""Batches, Monte Carlo and many logs on a Dask cluster (the optional extra
``pip install "tendonsense[distributed]"``).

The work is cut into tasks that are each a compiled batch: a chunk of ``task_size`` forward
solves (:func:`solve_batch`) or independent readings (:func:`estimate_batch`), or one whole
log (:func:`estimate_logs`). A task carries the
robot, the numbers and file paths, never a compiled program: each worker compiles a program
once per robot structure, or loads it from the program cache (:mod:`tendonsense.settings`,
``TENDONSENSE_CACHE_DIR``; a shared folder when the cluster has one). Every function takes a
``distributed.Client`` (any cluster: :func:`cluster` makes a local one) or ``None``, which runs
the same tasks one after another in this process, with the same numbers. Inputs are checked
here, before anything is sent; a task whose worker dies is run again on another.

The solvers (and JAX) are imported where work is done: a process that only hands logs to
a cluster (:func:`estimate_logs`) never loads them.
"""

from __future__ import annotations

import os
import sys
import threading
import warnings
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Iterator, Mapping, Sequence

import numpy as np

from .inputs import (WALK, NoDampingWarning, Noise, Unknown, check_noise, check_point_forces,
                     check_unknowns, per_sample, tendon_vector, warn_no_damping)
from .readings import LogSummary, log_outputs
from .result import SampleEstimate
from .robot import Robot
from .settings import cache_dir, cache_limit_bytes, pin

if TYPE_CHECKING:
    from .tracking import BatchResult  # noqa: F401 (annotations)

#: how to install what this module needs
EXTRA = 'pip install "tendonsense[distributed]"'
#: forward solves per task: enough that a task's compiled batch dwarfs its scheduling
TASK_SIZE = 1000
#: times a task is run again after its worker died or it failed
RETRIES = 3
#: Dask's switch for a worker's statistical profiler, off on a local cluster (:func:`cluster`)
PROFILER = "distributed.worker.profile.enabled"
#: Dask's switch for how a local worker process starts (spawn, fork or forkserver)
START_METHOD = "distributed.worker.multiprocessing-method"

Progress = Callable[[int, int], None]


def _distributed():
    try:
        import distributed
    except ImportError:
        raise ImportError(f"running on a Dask cluster needs Dask's distributed scheduler: "
                          f"{EXTRA}") from None
    return distributed


@contextmanager
def cluster(workers: int = 2, scheduler: str | None = None,
            timeout: float = 10.0) -> Iterator[object]:
    """A ``distributed.Client``, closed on exit: connected to the running scheduler at
    ``scheduler`` (e.g. ``"tcp://10.0.0.5:8786"``; the cluster stays up), or else on a
    ``LocalCluster`` of ``workers`` worker processes of one thread each, which is shut down
    on exit with its processes. The local workers use this process's program cache folder,
    do not run Dask's statistical profiler (:data:`PROFILER`; on a cluster of your own, set
    it false in the workers' Dask config for the same gain) and, when there are no more of
    them than cores, each keeps to a core of its own (:func:`~tendonsense.settings.pin`: XLA's
    threads then never wait for an idle core to wake). On Linux, from a process of one thread
    that has not loaded JAX, the local workers are forked (they start with Dask already
    imported) unless Dask's config names a start method other than its default, spawn.

    >>> with cluster(2) as client:
    ...     out = solve_batch(client, robot, {"t1": np.full(2000, 2.0)})
    """
    distributed = _distributed()
    if scheduler is not None:
        try:
            client = distributed.Client(scheduler, timeout=timeout)
        except (OSError, ValueError) as exc:
            raise OSError(f"Dask scheduler {scheduler}: cannot connect ({exc})") from None
        with client:
            yield client
        return
    if workers < 1:
        raise ValueError(f"a local cluster needs at least one worker, not {workers}")
    import dask
    folder = cache_dir()
    # the workers' statistical profiler (a stack sample every 10 ms) slows a task of compiled
    # batches by about a fifth on two cores; the workers take this config
    config = {PROFILER: False}
    if (sys.platform.startswith("linux") and dask.config.get(START_METHOD) == "spawn"
            and "jax" not in sys.modules and threading.active_count() == 1):
        # forked from this process, a worker starts with Dask imported (0.08 s against
        # 0.45 s spawned, two workers on two cores); JAX's threads, or any other thread's
        # locks, would not survive a fork
        config[START_METHOD] = "fork"
    try:
        with dask.config.set(config):
            local = distributed.LocalCluster(
                n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                scheduler_kwargs={"dashboard_address": ":0"}, memory_limit=0,
                env={"TENDONSENSE_CACHE_DIR": "" if folder is None else str(folder),
                     "TENDONSENSE_CACHE_LIMIT": str(cache_limit_bytes() / 1e6)})
    except (RuntimeError, OSError) as exc:
        raise OSError(f"a local Dask cluster of {workers} workers did not start ({exc})") from None
    try:
        with distributed.Client(local) as client:
            cores = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
            if workers <= len(cores):
                client.register_plugin(_one_core_each(cores), name="tendonsense-pin")
            yield client
    finally:
        local.close()


def _one_core_each(cores: list[int]):
    """A worker plugin that keeps local worker ``k`` (its name) on ``cores[k]``, also when
    the nanny starts it again."""
    distributed = _distributed()

    class OneCoreEach(distributed.WorkerPlugin):
        def setup(self, worker):
            pin({cores[int(worker.name) % len(cores)]})

    return OneCoreEach()


def _run(client, fn, tasks: Sequence[tuple], progress: Progress | None):
    """``fn(*task)`` for each task, in order: on ``client``'s workers (retried if one dies)
    or, without a client, here one after another. An exception of a task is returned as its
    result."""
    n = len(tasks)
    if client is None:
        out = []
        for task in tasks:
            try:
                out.append(fn(*task))
            except Exception as exc:
                out.append(exc)
            if progress:
                progress(len(out), n)
        return out
    distributed = _distributed()
    futures = [client.submit(fn, *task, retries=RETRIES, pure=False) for task in tasks]
    index = {f.key: i for i, f in enumerate(futures)}
    out: list = [None] * n
    try:
        for done, future in enumerate(distributed.as_completed(futures), start=1):
            try:
                out[index[future.key]] = future.result()
            except Exception as exc:
                out[index[future.key]] = exc
            if progress:
                progress(done, n)
    finally:
        client.cancel([f for f in futures if not f.done()])
    return out


# ----------------------------------------------------------------------------- forward batches

def task_chunks(n: int, task_size: int = TASK_SIZE) -> list[np.ndarray]:
    """The samples of each task: ``n`` samples cut into consecutive chunks of at most
    ``task_size`` (as equal as can be)."""
    if task_size < 1:
        raise ValueError(f"task_size must be at least 1, not {task_size}")
    return np.array_split(np.arange(n), max(1, -(-n // task_size)))


def solve_chunk(robot: Robot, T: np.ndarray, X: np.ndarray, F: np.ndarray,
                values: Mapping[str, np.ndarray], sliding: Mapping[str, str] | None = None,
                stability: bool = False, settle: bool = False) -> BatchResult:
    """One task of :func:`solve_batch`: :func:`tendonsense.tracking.solve_batch` over
    tensions ``T`` (n, n_t), point forces at ``X`` (n, n_p) of ``F`` (n, n_p, 3), the
    varied ``values``, the tendons' ``sliding``, whether to check ``stability`` and to
    ``settle``, on one thread."""
    from .tracking import solve_batch as solve_local
    forces = [(X[:, i], F[:, i]) for i in range(X.shape[1])]
    return solve_local(robot, T, forces, dict(values), workers=1, sliding=sliding,
                       stability=stability, settle=settle)


def solve_batch(client, robot: Robot, tensions, point_forces: Sequence = (),
                values: Mapping[str, object] | None = None, task_size: int = TASK_SIZE,
                progress: Progress | None = None, sliding: Mapping[str, str] | None = None,
                stability: bool = False, settle: bool = False) -> BatchResult:
    """:func:`tendonsense.tracking.solve_batch` over a cluster (``client``; ``None``: this
    process): the same arguments, checked here; the batch ordered along its first principal
    direction and cut into chunks of ``task_size`` samples (:func:`task_chunks`), each chunk a
    task (:func:`solve_chunk`), the results put back in the input order. ``progress(done, total)`` is called per chunk.

    Each chunk is solved on its own (its samples warm-started from each other, the first
    from the straight rod), so the result is exactly that of :func:`solve_chunk` on each
    chunk here in turn, whichever worker ran it; it agrees with one
    :func:`~tendonsense.tracking.solve_batch` over the whole batch to the solver's
    tolerance.

    >>> E, mu = rng.normal(1e6, 5e4, 20000), rng.uniform(0.3, 0.5, 20000)
    >>> out = solve_batch(client, robot, {"t1": rng.uniform(1, 3, 20000)},
    ...                   values={"young_modulus": E, "friction": mu})
    """
    from .forward import model_for
    from .tracking import BatchResult, batch_inputs, principal_order, signed_friction
    base = model_for(robot).values
    T, X, F, varied = batch_inputs(robot, base, tensions, point_forces, values)
    n = T.shape[0]
    if n == 0:
        raise ValueError("batch: no samples")
    signed_friction(robot, base, varied, n, sliding)  # its rules, before anything is sent
    if settle and not stability:
        raise ValueError("batch: settle needs the stability check (stability=True)")
    # neighbours along the batch's first principal direction share a task, so that each
    # warm-starts the next as in one process
    order = principal_order(np.concatenate(
        [T, X, F.reshape(n, -1), *(v.reshape(n, -1) for v in varied.values())], axis=1))
    chunks = [order[c] for c in task_chunks(n, task_size)]
    tasks = [(robot, T[c], X[c], F[c], {k: np.ascontiguousarray(v[c]) for k, v in varied.items()},
              dict(sliding or {}), stability, settle) for c in chunks]
    parts = _run(client, solve_chunk, tasks, progress)
    for part in parts:
        if isinstance(part, Exception):
            raise part

    def back(pieces):  # the chunks' rows in the input order
        out = np.empty((n, *pieces[0].shape[1:]), pieces[0].dtype)
        for c, piece in zip(chunks, pieces):
            out[c] = piece
        return out

    return BatchResult(
        back([p.q for p in parts]),
        {m: back([p.markers[m] for p in parts]) for m in robot.marker_names},
        {t: back([p.displacements[t] for p in parts]) for t in robot.tendon_names},
        back([p.converged for p in parts]), back([p.iterations for p in parts]),
        back([p.notes for p in parts]),
        back([p.unstable for p in parts]) if stability else None)


def estimate_chunk(robot: Robot, measured: Sequence[str], unknowns: Sequence[Unknown],
                   point_forces, noise: Noise, displacements, tensions,
                   values: Mapping[str, np.ndarray]) -> list[SampleEstimate]:
    """One task of :func:`estimate_batch`: the problem set up on the worker, then
    :func:`tendonsense.tracking.estimate_batch` over the chunk's readings on one thread."""
    from .estimation import problem
    from .tracking import estimate_batch as estimate_here
    prob = problem(robot, measured, unknowns, point_forces)
    return estimate_here(prob, displacements, tensions, noise, workers=1, values=dict(values))


def estimate_batch(client, robot: Robot, measured: Sequence[str], unknowns: Sequence[Unknown],
                   displacements: Sequence[Mapping[str, float]],
                   tensions: Sequence[Mapping[str, float]], point_forces=(),
                   noise: Noise = Noise(), values: Mapping[str, object] | None = None,
                   task_size: int = TASK_SIZE,
                   progress: Progress | None = None) -> list[SampleEstimate]:
    """:func:`tendonsense.tracking.estimate_batch` over a cluster (``client``; ``None``:
    this process): independent readings of the tendons ``measured`` ({tendon: m} and
    {tendon: N} per sample, or {tendon: (N,) values}), each with its own ``values`` if given,
    estimated for
    ``unknowns``; cut into chunks of ``task_size`` readings (:func:`task_chunks`), each chunk
    a task (:func:`estimate_chunk`), returned in the input order. The same numbers as
    :func:`estimate_chunk` on each chunk here; checked here before anything is sent.

    >>> est = estimate_batch(client, robot, ["t1"], [PointForceUnknown(0.25, (0, 0, -1))],
    ...                      [{"t1": -0.005}] * 5000, [{"t1": 2.1}] * 5000,
    ...                      values={"friction": rng.uniform(0.3, 0.5, 5000)})
    """
    from .estimation import problem
    from .tracking import varied_values
    prob = problem(robot, measured, unknowns, point_forces)
    displacements = per_sample(displacements, "displacement")
    tensions = per_sample(tensions, "tension")
    n = len(displacements)
    if n == 0 or len(tensions) != n:
        raise ValueError(f"batch: {n} displacement and {len(tensions)} tension readings (one "
                         f"of each per sample, at least one)")
    for y, t in zip(displacements, tensions):
        tendon_vector(robot, y, "displacement")
        tendon_vector(robot, t, "tension")
    varied = varied_values(prob.model.values, values, n)
    tasks = [(robot, list(measured), list(unknowns), list(point_forces), noise,
              [displacements[k] for k in c], [tensions[k] for k in c],
              {k: np.ascontiguousarray(v[c]) for k, v in varied.items()})
             for c in task_chunks(n, task_size)]
    parts = _run(client, estimate_chunk, tasks, progress)
    for part in parts:
        if isinstance(part, Exception):
            raise part
    return [e for part in parts for e in part]


# ---------------------------------------------------------------------------------- many logs

def _estimate_file(*task) -> LogSummary:
    """One task of :func:`estimate_logs`: :func:`tendonsense.logs.estimate_file`, imported
    on the worker."""
    from .logs import estimate_file
    with warnings.catch_warnings():  # (said once by :func:`estimate_logs`)
        warnings.simplefilter("ignore", NoDampingWarning)
        return estimate_file(*task)


def estimate_logs(client, robot: Robot, logs: Sequence[str | Path], out_dir: str | Path,
                  unknowns: Sequence[Unknown], point_forces=(), noise: Noise = Noise(),
                  dynamic: bool = False, walk: float = WALK,
                  progress: Progress | None = None) -> list[LogSummary]:
    """Estimate many logs, one task per log (``client``; ``None``: here, one after
    another): each task reads its log, estimates every row and writes the estimates
    atomically to ``out_dir`` under the log's own name
    (:func:`tendonsense.logs.estimate_file`, the same numbers and file as ``estimate
    --readings LOG -o OUT``). Returns a :class:`~tendonsense.readings.LogSummary` per log, in
    order; a log that cannot be used is one with ``error`` set, naming it, and the others
    go on. ``progress(done, total)`` is called per log.

    Checked here before anything is sent (a ValueError): the unknowns and known forces
    against the robot, the noise, that the output folder exists and is writable, that no two
    logs write the same output and none overwrites a log. The log files must be readable,
    and ``out_dir`` writable, by the workers (a shared folder on a cluster of machines).
    """
    if isinstance(logs, (str, Path)):
        raise ValueError(f"estimate_logs: logs is a list of paths, such as [{str(logs)!r}] "
                         f"(a pattern's matches: sorted(glob.glob(...))), not one path")
    if not logs:
        raise ValueError("estimate_logs: no logs")
    check_point_forces(robot, point_forces)
    check_unknowns(robot, robot.tendon_names, unknowns)
    check_noise(noise, robot)
    out_dir = Path(out_dir)
    if not out_dir.is_dir():
        raise ValueError(f"{out_dir}: no such folder")
    if not os.access(out_dir, os.W_OK):
        raise ValueError(f"{out_dir}: the folder is not writable")
    outs = log_outputs(logs, out_dir)
    if dynamic:
        warn_no_damping(robot, " in every log")
    tasks = [(robot, str(log), str(out), list(unknowns), list(point_forces), noise, dynamic,
              walk) for log, out in zip(logs, outs)]
    return [LogSummary(str(log), str(out), error=f"{log}: {r}") if isinstance(r, Exception)
            else r for log, out, r in zip(logs, outs, _run(client, _estimate_file, tasks,
                                                             progress))]
