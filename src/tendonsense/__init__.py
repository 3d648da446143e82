"""tendonsense: shape and external forces of tendon-driven slender soft robots from their
tendon readings, with a geometric variable-strain Cosserat-rod model."""

import jax

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_platforms", "cpu")

from .robot import Robot, RobotFileError, load_robot  # noqa: E402

__all__ = ["Robot", "RobotFileError", "load_robot"]
__version__ = "0.1.0"
