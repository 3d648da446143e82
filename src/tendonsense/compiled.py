"""Compiled programs kept between runs: a program is traced once per robot structure and
argument shapes, serialised (``jax.export``) into the cache directory, and later processes
load it instead of tracing it again; the XLA compilation cache (see ``__init__``) then
supplies the machine code. A cached program is keyed by its name, the structure, the
argument shapes and a hash of this package's source and of the JAX version, so that an edited
model never runs a stale program. Without a cache directory, or if serialisation is not
available, it is plain :func:`jax.jit`.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
import threading
from functools import lru_cache
from pathlib import Path

import jax
import numpy as np


def cache_dir() -> Path | None:
    """``TENDONSENSE_CACHE_DIR`` (an empty value: no cache), else ``~/.cache/tendonsense``."""
    path = os.environ.get("TENDONSENSE_CACHE_DIR")
    if path is None:
        base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
        path = os.path.join(base, "tendonsense")
    return Path(path) if path else None


@lru_cache(maxsize=1)
def _source_hash() -> str:
    h = hashlib.sha256(jax.__version__.encode())
    for f in sorted(Path(__file__).parent.glob("*.py")):
        h.update(f.read_bytes())
    return h.hexdigest()[:16]


@lru_cache(maxsize=1)
def _register() -> bool:
    """Register every named tuple of the modules whose values programs take or return, for
    serialisation; False if serialisation is unavailable."""
    try:
        import flatbuffers  # noqa: F401  (jax.export serialisation needs it)
    except ImportError:
        return False
    from . import kinematics, model, statics, tracking
    for mod in (kinematics, model, statics, tracking):
        for name, cls in vars(mod).items():
            if not (isinstance(cls, type) and issubclass(cls, tuple) and hasattr(cls, "_fields")
                    and cls.__module__ == mod.__name__):
                continue
            try:
                jax.export.register_namedtuple_serialization(
                    cls, serialized_name=f"tendonsense.{name}")
            except ValueError:  # already registered
                pass
    return True


#: held while a program compiles: XLA's serialisation of an executable into the compilation
#: cache is not safe from two threads at once (batches solve on two threads)
_COMPILING = threading.RLock()


class FirstCallLocked:
    """A jitted function whose first call per argument signature (the one that compiles)
    holds :data:`_COMPILING`."""

    def __init__(self, fn):
        self.fn = fn
        self.seen: set[tuple] = set()

    def __call__(self, *args):
        signature = _signature(args)
        if signature in self.seen:
            return self.fn(*args)
        with _COMPILING:
            out = jax.block_until_ready(self.fn(*args))
            self.seen.add(signature)
        return out


class Program:
    """``jax.jit(fn)`` whose traced form is kept on disk between runs (see module doc)."""

    def __init__(self, fn, name: str, key):
        self.fn, self.name, self.key = fn, name, repr(key)
        self.jitted = jax.jit(fn)
        self.loaded: dict[tuple, object] = {}

    def __call__(self, *args):
        signature = _signature(args)
        call = self.loaded.get(signature)
        if call is None:
            with _COMPILING:
                call = self.loaded.get(signature)
                if call is None:
                    call = self._load(signature, args)
                    out = jax.block_until_ready(call(*args))
                    self.loaded[signature] = call
                    return out
        return call(*args)

    def _load(self, signature: tuple, args):
        root = cache_dir()
        if root is None or not _register():
            return self.jitted
        tree, shapes = signature
        described = ",".join(f"{shape}:{dtype}" for shape, dtype in shapes)
        digest = hashlib.sha256(f"{self.name}|{self.key}|{tree}|{described}|{_source_hash()}"
                                .encode()).hexdigest()[:32]
        path = root / "programs" / f"{self.name}-{digest}.bin"
        try:
            exp = jax.export.deserialize(bytearray(path.read_bytes()))
        except FileNotFoundError:
            exp = None
        except Exception:  # an unreadable file: trace again, and overwrite it
            exp = None
        if exp is None:
            try:
                exp = jax.export.export(self.jitted)(*args)
                _write_atomic(path, exp.serialize())
            except Exception:
                return self.jitted
        return jax.jit(exp.call)


def _signature(args) -> tuple:
    """The tree structure and every leaf's shape and dtype (hashable; checked on every call)."""
    leaves, tree = jax.tree_util.tree_flatten(args)
    return tree, tuple((np.shape(a), a.dtype if hasattr(a, "dtype") else np.result_type(a))
                       for a in leaves)


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
