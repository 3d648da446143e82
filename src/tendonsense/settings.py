"""Process-wide settings, applied before JAX starts: float64 on the CPU, and where compiled
programs are kept. Importing this module does not import JAX."""

from __future__ import annotations

import os
import sys
import threading
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator


def cache_dir() -> Path | None:
    """``TENDONSENSE_CACHE_DIR`` (an empty value: no cache), else ``~/.cache/tendonsense``."""
    path = os.environ.get("TENDONSENSE_CACHE_DIR")
    if path is None:
        base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
        path = os.path.join(base, "tendonsense")
    return Path(path) if path else None


#: the most the kept programs (``cache_dir()/programs``) may take by default, in bytes
CACHE_LIMIT = 2 * 1024**3

#: the most the kept programs may take, in bytes, in this process (None: the default of
#: :func:`cache_limit_bytes`): when a new one would take them over it, the least recently
#: used go (programs of other versions of this package or of robots not run for a while; a
#: program loaded again counts as used). A robot's programs take some 10-40 MB.
cache_limit: int | None = None


def cache_limit_bytes() -> int:
    """:data:`cache_limit` if set, else ``TENDONSENSE_CACHE_LIMIT`` (megabytes, e.g. ``500``;
    a local cluster's workers take it too), else :data:`CACHE_LIMIT`; a value that is not a
    number of megabytes is said on standard error once and the default kept."""
    if cache_limit is not None:
        return int(cache_limit)
    raw = os.environ.get("TENDONSENSE_CACHE_LIMIT", "").strip()
    if not raw:
        return CACHE_LIMIT
    try:
        mb = float(raw)
    except ValueError:
        mb = -1.0
    if 0 <= mb < float("inf"):
        return int(mb * 1e6)
    _say_once(f"tendonsense: TENDONSENSE_CACHE_LIMIT={raw!r} is not a number of megabytes: "
              f"programs are kept within {CACHE_LIMIT / 1024**3:g} GiB")
    return CACHE_LIMIT


_SAID: set[str] = set()


def _say_once(message: str) -> None:
    if message not in _SAID:
        _SAID.add(message)
        print(message, file=sys.stderr)


#: called once, with a message, when this process first compiles a program where no kept
#: one could be loaded (:mod:`tendonsense.compiled`): the command line prints it on a terminal,
#: so that a first run's wait is not taken for a hang
on_first_compile: Callable[[str], None] | None = None


def jax_options() -> dict[str, object]:
    """JAX's options for this package: float64 on the CPU, and XLA's compilation cache off:
    compiled programs are kept in ``cache_dir()/programs`` by :mod:`tendonsense.compiled`,
    and an executable XLA's cache has loaded cannot be kept again."""
    return {"jax_enable_x64": True, "jax_platforms": "cpu", "jax_enable_compilation_cache": False}


def compiler_options() -> dict[str, object]:
    """XLA's options for every compiled program: loop fusions by XLA's classic CPU emitter,
    not its newer MLIR fusion emitters, with which the paper's prototype's Newton program
    compiles in 13–15 s instead of 8 s and runs no faster (jax 0.10.2, 2 cores). An XLA that
    does not know an option compiles without it."""
    return {"xla_cpu_use_fusion_emitters": False}


def pin(cpus) -> set[int]:
    """Keep every thread of this process on the cores ``cpus`` (e.g. ``{1}``); threads made
    later inherit it. XLA runs parts of a compiled program on its own pool of threads, and a
    core that sits idle can take milliseconds to wake (on a virtual machine, 5–20 ms): a
    live estimator pinned to one core answers every sample in its usual time. Unlike
    ``os.sched_setaffinity(0, …)``, which moves the calling thread only, this moves XLA's
    threads too. A program is compiled on the cores the process had before (:func:`unpinned`).
    Linux only. Returns the cores."""
    global _PINNED
    cpus = {int(c) for c in cpus}
    if not hasattr(os, "sched_setaffinity"):
        raise OSError("pinning to cores needs Linux (os.sched_setaffinity)")
    n = os.cpu_count() or 1
    if not cpus or not cpus <= set(range(n)):
        raise ValueError(f"cores {sorted(cpus)}: this machine's cores are 0 to {n - 1}")
    with _PIN_LOCK:
        before = os.sched_getaffinity(0) if _PINNED is None else _PINNED[0]
        _move_threads(cpus)
        _PINNED = (before, cpus)
    return cpus


#: (the cores before :func:`pin`, the cores pinned to), or None; changed under the lock
_PINNED: tuple[set[int], set[int]] | None = None
_PIN_LOCK = threading.RLock()


def _move_threads(cpus: set[int]) -> None:
    for tid in os.listdir("/proc/self/task"):
        try:
            os.sched_setaffinity(int(tid), cpus)
        except ProcessLookupError:  # a thread that has ended since
            pass


@contextmanager
def unpinned() -> Iterator[None]:
    """Inside, a process kept to some cores (:func:`pin`) runs on the cores it had before,
    every thread of it: XLA compiles a program on several threads (start-up, not the hot
    path), e.g. while the other workers of a local cluster wait for that program (one core
    each). Where those cores are no longer the process's to take, it stays pinned."""
    with _PIN_LOCK:
        if _PINNED is None:
            yield
            return
        try:
            _move_threads(_PINNED[0])
        except OSError:  # e.g. a core taken away since (EINVAL): compile where pinned
            pass
        try:
            yield
        finally:
            _move_threads(_PINNED[1])  # threads made inside too


#: the variables by which OpenBLAS takes its number of threads, the first set winning
BLAS_THREADS = ("OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS", "OMP_NUM_THREADS")


def configure() -> None:
    """Apply :func:`jax_options`: through the environment when JAX is not imported yet (so
    that importing this package costs no JAX start-up), else on JAX's live configuration.
    Eigen and OpenBLAS run single-threaded unless ``XLA_FLAGS`` or ``OPENBLAS_NUM_THREADS``
    (``GOTO_NUM_THREADS``, ``OMP_NUM_THREADS``) say otherwise: set them before importing
    this package. The BLAS setting holds for every OpenBLAS loaded after the import (NumPy's
    if NumPy was not imported yet) and for child processes."""
    # small matrices: Eigen's thread pool costs more than it saves
    if "xla_cpu_multi_thread_eigen" not in os.environ.get("XLA_FLAGS", ""):
        os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "")
                                   + " --xla_cpu_multi_thread_eigen=false").strip()
    # and so do OpenBLAS's threads (behind JAX's LU), which spin for work between calls and
    # take a core from the caller: read when SciPy's OpenBLAS loads (at the first program
    # that factors a matrix)
    if not any(v in os.environ for v in BLAS_THREADS):
        os.environ["OPENBLAS_NUM_THREADS"] = "1"
    options = jax_options()
    if "jax" in sys.modules:
        import jax
        for name, value in options.items():
            jax.config.update(name, value)
    else:
        for name, value in options.items():
            os.environ[name.upper()] = str(value).lower() if isinstance(value, bool) else str(value)
