"""Process-wide settings, applied before JAX starts: float64 on the CPU, and where compiled
programs are kept. Importing this module does not import JAX."""

from __future__ import annotations

import os
import sys
from pathlib import Path


def cache_dir() -> Path | None:
    """``TENDONSENSE_CACHE_DIR`` (an empty value: no cache), else ``~/.cache/tendonsense``."""
    path = os.environ.get("TENDONSENSE_CACHE_DIR")
    if path is None:
        base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
        path = os.path.join(base, "tendonsense")
    return Path(path) if path else None


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


def configure() -> None:
    """Apply :func:`jax_options`: through the environment when JAX is not imported yet (so
    that importing this package costs no JAX start-up), else on JAX's live configuration."""
    # small matrices: Eigen's thread pool costs more than it saves
    if "xla_cpu_multi_thread_eigen" not in os.environ.get("XLA_FLAGS", ""):
        os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "")
                                   + " --xla_cpu_multi_thread_eigen=false").strip()
    options = jax_options()
    if "jax" in sys.modules:
        import jax
        for name, value in options.items():
            jax.config.update(name, value)
    else:
        for name, value in options.items():
            os.environ[name.upper()] = str(value).lower() if isinstance(value, bool) else str(value)
