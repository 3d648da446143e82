"""tendonsense: shape and external forces of tendon-driven slender soft robots from their
tendon readings, with a geometric variable-strain Cosserat-rod model."""

import os

# Small matrices: Eigen's thread pool costs more than it saves (set before JAX starts).
if "xla_cpu_multi_thread_eigen" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "")
                               + " --xla_cpu_multi_thread_eigen=false").strip()

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_platforms", "cpu")


def _enable_compilation_cache():
    """Keep compiled solvers on disk between runs (``TENDONSENSE_CACHE_DIR``, default
    ``~/.cache/tendonsense``; set it to an empty string to switch the cache off)."""
    from .compiled import cache_dir
    root = cache_dir()
    if root is None:
        return
    path = os.path.join(root, "xla")
    try:
        os.makedirs(path, exist_ok=True)
    except OSError:
        return
    jax.config.update("jax_compilation_cache_dir", path)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)


_enable_compilation_cache()

from .robot import Robot, RobotFileError, load_robot  # noqa: E402

__all__ = ["Robot", "RobotFileError", "load_robot"]
__version__ = "0.1.0"
