"""tendonsense: shape and external forces of tendon-driven slender soft robots from their
tendon readings, with a geometric variable-strain Cosserat-rod model."""

from . import settings

settings.configure()  # before anything imports JAX; importing the package does not

from .robot import Robot, RobotFileError, load_robot  # noqa: E402

__all__ = ["Robot", "RobotFileError", "load_robot"]
__version__ = "0.1.0"
