"""Compiled programs kept between runs: a program is traced and compiled once per robot
structure and argument signature, its executable serialised into the cache directory
(:mod:`tendonsense.settings`), and later processes load the executable instead of tracing,
lowering and compiling it again. A kept program is keyed by its name, the structure, the
argument signature, the machine (platform and CPU), XLA's flags and a hash of this package's
source (the compiler options of :func:`~tendonsense.settings.compiler_options` included) and
of the JAX version, so that an edited model never runs a stale program; a process that needs
a program another is compiling waits for it. The kept programs take at most
:func:`settings.cache_limit_bytes <tendonsense.settings.cache_limit_bytes>` bytes: the
least recently used go first. Without a cache directory, or if an executable
cannot be kept, it is compiled in this process alone, with the same options.
"""

from __future__ import annotations

import hashlib
import os
import pickle
import platform
import tempfile
import threading
import weakref
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager, suppress
from functools import lru_cache, wraps
from pathlib import Path

import jax
import numpy as np

from . import settings
from .settings import cache_dir, compiler_options, unpinned


@lru_cache(maxsize=1)
def _source_hash() -> str:
    """This package's source, the JAX version, XLA's flags and the machine the executables
    run on."""
    h = hashlib.sha256(f"{jax.__version__}|{os.environ.get('XLA_FLAGS', '')}|"
                       f"{platform.machine()}|{_cpu_flags()}".encode())
    for f in sorted(Path(__file__).parent.glob("*.py")):
        h.update(f.read_bytes())
    return h.hexdigest()[:16]


def _cpu_flags() -> str:
    """The CPU's feature flags (an executable may use any of them), where the OS tells."""
    try:
        with open("/proc/cpuinfo") as fh:
            return next((line for line in fh if line.startswith(("flags", "Features"))), "")
    except OSError:
        return platform.processor()


#: held while a program compiles: XLA's serialisation of an executable into the compilation
#: cache is not safe from two threads at once (batches solve on two threads)
_COMPILING = threading.RLock()


class Program:
    """``jax.jit(fn)`` whose executables are kept on disk between runs (see module doc)."""

    def __init__(self, fn, name: str, key):
        self.fn, self.name, self.key = fn, name, repr(key)

        @wraps(fn)
        def own(*args):  # a lowering of its own (JAX caches them by function): stripped
            return fn(*args)  # in place (:func:`_strip_locations`), it is no one else's

        self.jitted = jax.jit(own)
        self.loaded: dict[tuple, object] = {}
        self._loading: dict[tuple, Future] = {}  # (:meth:`preload`)
        self._last = None  # the executable of the last call
        _PROGRAMS.add(self)

    def __call__(self, *args):
        # the last call's executable first: it checks its arguments itself (in C++) and
        # refuses other shapes, dtypes and trees with a TypeError (a weak-typed scalar and a
        # strong one of the same dtype run alike), where the signature here costs ~1 µs per
        # leaf; a hot loop that alternates two signatures pays both (keep one)
        last = self._last
        if last is not None:
            try:
                return last(*args)
            except TypeError:
                pass
        self._last = call = self.executable(*args)
        return call(*args)

    def executable(self, *args):
        """The executable for arguments of the shapes and dtypes of ``args`` (loaded or
        compiled now)."""
        signature = _signature(args)
        call = self.loaded.get(signature)
        if call is None:
            loading = self._loading.pop(signature, None)
            call = None if loading is None else loading.result()
            if call is None:
                with _COMPILING:
                    call = self.loaded.get(signature)
                    if call is None:
                        call = self._load(signature, args)
            self.loaded[signature] = call
        return call

    def preload(self, *args) -> None:
        """Begin loading the kept executable for arguments of the kinds of ``args`` on another
        thread, while this one goes on (e.g. loads and runs the program before it); a call
        waits for it. For a program's first executable only (a process's first contact), and
        nothing where it is not kept (a call compiles it)."""
        if self.loaded or self._loading:
            return
        signature = _signature(args)
        path = self._path(signature)
        if path is not None and path.exists():
            try:
                self._loading[signature] = _loader().submit(_kept, path)
            except RuntimeError:  # the interpreter is shutting down: the call loads it
                pass

    def _path(self, signature: tuple) -> Path | None:
        """Where the executable for ``signature`` is kept (None: no cache directory)."""
        root = cache_dir()
        if root is None:
            return None
        tree, leaves = signature
        described = ",".join(f"{shape}:{dtype}:{weak}" for shape, dtype, weak in leaves)
        digest = hashlib.sha256(f"{self.name}|{self.key}|{tree}|{described}|{_source_hash()}"
                                .encode()).hexdigest()[:32]
        return root / "programs" / f"{self.name}-{digest}.exe"

    def _load(self, signature: tuple, args):
        """The kept executable for ``signature``, or a new one compiled and kept."""
        path = self._path(signature)
        if path is None:
            return _compile(self.jitted, args)
        kept = _kept(path)
        if kept is not None:
            return kept
        with _compiling_elsewhere(path):  # another process compiling it: wait, then load
            kept = _kept(path)
            if kept is not None:
                return kept
            compiled = _compile(self.jitted, args)
            try:
                _write_atomic(path, _serialize(compiled))
            except Exception:  # an executable that cannot be kept still runs
                pass
            else:
                _evict(path.parent, settings.cache_limit_bytes(), keep=path)
        return compiled


def _compile(jitted, args):
    """``jitted`` lowered for ``args`` and compiled with this package's compiler options, or
    without them where this XLA does not have them."""
    _announce()
    lowered = jitted.lower(*args)
    _strip_locations(lowered)
    with unpinned():  # XLA's code generation on several threads
        try:
            return lowered.compile(compiler_options())
        except jax.errors.JaxRuntimeError as e:
            if "No such compile option" not in str(e):
                raise
            return lowered.compile()


def _strip_locations(lowered) -> None:
    """Drop the lowered module's source locations and operation names (in place): XLA keeps
    them as metadata on every instruction, a third of a kept executable and of what loading
    one parses; the program is the same without them (the log follower of the paper's
    prototype: 3.9 → 2.5 MB, loaded in 0.46 s instead of 0.52 s; compiled in about the same
    time). Where this JAX offers no module to change, nothing is dropped."""
    try:
        from jax.extend.mlir import passmanager
        module = lowered.compiler_ir("stablehlo")
        with module.context:
            passmanager.PassManager.parse("builtin.module(strip-debuginfo)").run(
                module.operation)
    except Exception:  # compiled as it was lowered
        pass


_ANNOUNCED = False


def _announce() -> None:
    """Tell :data:`settings.on_first_compile <tendonsense.settings.on_first_compile>`, once
    a process, that programs are being compiled."""
    global _ANNOUNCED
    hook = settings.on_first_compile
    if hook is None or _ANNOUNCED:
        return
    _ANNOUNCED = True
    root = cache_dir()
    kept = (f"once for this robot's structure on this machine, then kept in {root / 'programs'}"
            if root else "every run: TENDONSENSE_CACHE_DIR is empty, so none are kept")
    hook(f"tendonsense: compiling the programs this run needs (5-30 s; {kept})")


@lru_cache(maxsize=1)
def _loader() -> ThreadPoolExecutor:
    """The thread that loads executables ahead of their first call (:meth:`Program.preload`;
    loading one, in XLA, leaves the other core to this process's main thread)."""
    return ThreadPoolExecutor(1, thread_name_prefix="tendonsense-load")


#: every program of this process, for :func:`release`
_PROGRAMS: weakref.WeakSet[Program] = weakref.WeakSet()


def release() -> None:
    """Drop every program's executables from memory (they load again from disk when next
    called), e.g. with :func:`jax.clear_caches` in a process that has run very many."""
    with _COMPILING:
        for program in list(_PROGRAMS):
            program.loaded.clear()
            program._loading.clear()
            program._last = None


def _kept(path: Path):
    """The executable kept at ``path``, or None (none kept yet, or unreadable); marked as used
    (its modification time: :func:`_evict` removes the least recently used first)."""
    try:
        kept = _deserialize(path.read_bytes())
    except Exception:
        return None
    with suppress(OSError):
        os.utime(path)
    return kept


def _evict(folder: Path, limit: int, keep: Path | None = None) -> None:
    """The least recently used executables in ``folder`` removed until those left take at most
    ``limit`` bytes; ``keep`` stays (the one just written). Another process may be loading,
    writing or evicting at the same time: a file used or written again since it was listed
    stays, one gone already counts as removed, and lock files are left (a process may hold
    one)."""
    kept = []
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return
    for e in entries:
        if e.name.endswith(".exe"):
            with suppress(OSError):  # (removed since it was listed)
                st = e.stat()
                kept.append((st.st_mtime, st.st_size, Path(e.path)))
    total = sum(size for _, size, _ in kept)
    for mtime, size, path in sorted(kept):
        if total <= limit:
            break
        if path == keep:
            continue
        try:
            if path.stat().st_mtime != mtime:  # used or written again meanwhile
                continue
            path.unlink()
        except FileNotFoundError:
            pass
        except OSError:
            continue
        total -= size


def _serialize(compiled) -> bytes:
    """The executable and whether it calls LAPACK (most do not: :mod:`tendonsense.linalg`)."""
    from jax.experimental.serialize_executable import serialize
    return pickle.dumps(("lapack" in compiled.as_text(), serialize(compiled)))


_LAPACK = threading.Lock()


def _deserialize(data: bytes):
    from jax.experimental.serialize_executable import deserialize_and_load
    lapack, payload = pickle.loads(data)
    if lapack:  # its kernels, registered from SciPy's LAPACK (0.2–0.3 s to import)
        from jax._src.lax import linalg
        with _LAPACK:  # (also from the loading thread)
            linalg.initialize_lapack()
    return deserialize_and_load(*payload)


def _signature(args) -> tuple:
    """The tree structure and every leaf's shape, dtype and weak typing (hashable; checked on
    every call)."""
    leaves, tree = jax.tree_util.tree_flatten(args)
    return tree, tuple((np.shape(a), a.dtype if hasattr(a, "dtype") else np.result_type(a),
                        getattr(a, "weak_type", not hasattr(a, "dtype"))) for a in leaves)


@contextmanager
def _compiling_elsewhere(path: Path):
    """Held while this process compiles the program kept at ``path``: a process that needs
    the same program waits for it (an advisory lock beside the file, where the OS has one)
    instead of compiling it twice."""
    try:
        import fcntl
        path.parent.mkdir(parents=True, exist_ok=True)
        fh = open(path.with_suffix(".lock"), "a")
    except (ImportError, OSError):
        yield
        return
    with fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX)
        except OSError:
            pass
        yield  # closing the file releases the lock


def _write_atomic(path: Path, data: bytes):
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.replace(tmp, path)
    except BaseException:
        os.unlink(tmp)
        raise
