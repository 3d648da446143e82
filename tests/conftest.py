import copy
from pathlib import Path

import pytest

import tendonsense  # noqa: F401  (enables float64 before anything else touches JAX)
from tendonsense.robot import load_robot, parse_robot

ROOT = Path(__file__).resolve().parents[1]
PROTOTYPE = ROOT / "examples" / "paper_prototype.toml"


@pytest.fixture(scope="session")
def prototype():
    return load_robot(PROTOTYPE)


def robot_from(**tables):
    """A robot from SPEC §3 tables given as keyword arguments (``tendon=[...]`` etc.)."""
    data = {"name": "test"}
    data.update(copy.deepcopy(tables))
    return parse_robot(data, source="test")


def uniform_rod(radius=0.01, length=0.25, E=1e6, nu=0.5, rho=0.0):
    return {"length": length, "radius": [radius, radius], "young_modulus": E,
            "poisson_ratio": nu, "density": rho}
