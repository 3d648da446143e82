import copy
import csv
from pathlib import Path

import pytest

import jax

import tendonsense  # noqa: F401  (enables float64 before anything else touches JAX)
from tendonsense import compiled

# This process compiles hundreds of programs; after many of them, writing one more executable
# into XLA's persistent compilation cache has crashed it (a segmentation fault inside
# jax's put_executable_and_time, jax 0.10.2). tendonsense keeps its programs' executables
# itself (tendonsense.compiled) and leaves XLA's cache off; so does this process.
jax.config.update("jax_enable_compilation_cache", False)


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs():
    """Each test module starts without the programs the ones before it compiled: a process
    that has loaded several hundred executables has crashed inside XLA's CPU compiler."""
    yield
    compiled.release()
    jax.clear_caches()
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


def write_columns(path, cols) -> None:
    """A readings log: the columns {name: values} written as a CSV with a header."""
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(list(cols))
        w.writerows(zip(*cols.values()))
