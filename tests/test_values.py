"""Values at run time (issue 8): one compiled program per robot structure, point loads at any
X, batched solves and exact derivatives with respect to the values."""

import ast
import dataclasses
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tendonsense import compiled, estimation, load_robot, statics
from tendonsense.estimation import PointForceUnknown, estimate
from tendonsense.forward import model_for, solution_derivatives, solve
from tendonsense.tracking import solve_batch
from tendonsense.robot import Marker


def variant(robot, rng):
    """The robot with other numbers everywhere it has numbers, the same structure."""
    rod = dataclasses.replace(
        robot.rod, young_modulus=robot.rod.young_modulus * rng.uniform(0.5, 2.0),
        poisson_ratio=rng.uniform(0.3, 0.5), density=robot.rod.density * rng.uniform(0.7, 1.3),
        radius_knots=tuple((x, r * rng.uniform(0.9, 1.1)) for x, r in robot.rod.radius_knots))
    tendons = tuple(dataclasses.replace(
        t, friction=rng.uniform(0.0, 0.6),
        offset_base=tuple(v * rng.uniform(0.9, 1.0) for v in t.offset_base)) for t in robot.tendons)
    markers = tuple(Marker(m.name, m.X * rng.uniform(0.8, 1.0), tuple(rng.uniform(-1e-3, 1e-3, 3)))
                    for m in robot.markers)
    a = rng.uniform(-0.3, 0.3)
    c, s = np.cos(a), np.sin(a)
    return robot.replace(rod=rod, tendons=tendons, markers=markers,
                         gravity=tuple(rng.normal(size=3) * 3),
                         base_position=tuple(rng.normal(size=3) * 0.1),
                         base_rotation=((c, -s, 0.0), (s, c, 0.0), (0.0, 0.0, 1.0)))


def test_no_new_programs_for_new_values_or_load_positions(prototype, monkeypatch):
    """Tracing runs the Python of ``_terms`` (every residual's); it must not run again for 20
    robots with other numbers and 20 other load positions (forward statics, forward
    kinematics, estimation)."""
    # plain jit (no programs loaded from disk), from fresh caches, so that every trace shows
    monkeypatch.setenv("TENDONSENSE_CACHE_DIR", "")
    for factory in (statics.newton_solver, statics._outputs_fn, estimation._jacobians_fn):
        factory.cache_clear()
    calls = []
    original = statics._terms
    monkeypatch.setattr(statics, "_terms", lambda *a, **k: calls.append(1) or original(*a, **k))
    rng = np.random.default_rng(0)

    def run(robot, X):
        r = solve(robot, {"t1": 1.5}, [(X, (0.0, 0.05, -0.1))])
        e = estimate(robot, {"t1": r.displacements["t1"]}, {"t1": 1.5},
                     [PointForceUnknown(X, (0, 0.05, -0.1))])
        assert r.converged and e.converged
        assert e.magnitudes[0] == pytest.approx(np.hypot(0.05, 0.1), rel=1e-6)

    run(prototype, 0.2)  # compile once
    before = len(calls)
    assert before > 0  # the count sees the traces
    for _ in range(20):
        run(variant(prototype, rng), 0.2)
    for X in rng.uniform(0.01, 0.25, 20):
        run(prototype, float(X))
    assert len(calls) == before
    assert model_for(variant(prototype, rng)).structure == model_for(prototype).structure


class _Stop(Exception):
    pass


EXAMPLES = sorted((Path(__file__).resolve().parents[1] / "examples").glob("*.toml"))


@pytest.mark.parametrize("path", EXAMPLES, ids=[p.stem for p in EXAMPLES])
def test_every_example_keeps_its_solver_on_disk(path, tmp_path, monkeypatch):
    """The solver of every example robot (and of the elements basis) is compiled once and its
    executable kept in the cache: one that is not would be traced and compiled again in every
    new process."""
    monkeypatch.setenv("TENDONSENSE_CACHE_DIR", str(tmp_path))
    kept = []

    def load_only(program, *args):  # compile and keep, without running
        kept.append(program._load(compiled._signature(args), args) is not program.jitted)
        raise _Stop

    monkeypatch.setattr(compiled.Program, "__call__", load_only)
    robot = load_robot(path)
    L = robot.rod.length
    for r in (robot, robot.replace(elements=(L / 3, 2 * L / 3))):
        statics.newton_solver.cache_clear()
        with pytest.raises(_Stop):
            solve(r, {robot.tendon_names[0]: 1.0})
    statics.newton_solver.cache_clear()
    assert kept == [True, True]
    assert len(list((tmp_path / "programs").glob("newton-*.exe"))) == 2


def test_variant_matches_a_freshly_built_model(prototype):
    """with_values gives the same solution as a robot file with those numbers."""
    robot = prototype.with_parameters(young_modulus=1.7e6, density=900.0, friction=0.2)
    direct = solve(robot, {"t1": 2.0, "t3": 0.5})
    model = model_for(prototype).with_values(young_modulus=1.7e6, density=900.0, friction=0.2)
    drive = statics.Drive(*(np.asarray(a) for a in (
        [2.0, 0.0, 0.5], np.zeros((0, 3)), np.zeros(0), prototype.gravity, np.zeros(0))))
    res = statics.solve_system(model.structure, model.values, (), drive,
                               statics.Unknowns.none(3), None)
    np.testing.assert_allclose(np.asarray(res.x), direct.q, rtol=0, atol=1e-10)


def test_robots_that_differ_in_material_values_share_one_build(prototype):
    """A notebook's loop over ``with_parameters`` built a new model every call (4–7 ms, more
    than the solve): the geometry is now built once and each robot's own values put in,
    leaf for leaf what :meth:`Model.build` gives."""
    import jax
    from tendonsense.model import Model
    base = model_for(prototype)
    for robot in (prototype, prototype.with_parameters(young_modulus=2.3e6, density=1111.0,
                                                       friction=0.17, damping=5.0)):
        model, fresh = model_for(robot), Model.build(robot)
        assert model.robot is robot and model.structure == fresh.structure
        assert model.values.Phi1 is base.values.Phi1  # the one build
        a, b = (jax.tree_util.tree_flatten(m.values) for m in (model, fresh))
        assert a[1] == b[1]
        for x, y in zip(a[0], b[0]):
            assert np.asarray(x).dtype == np.asarray(y).dtype
            np.testing.assert_array_equal(x, y)


def test_batch_matches_single_solves(prototype):
    rng = np.random.default_rng(1)
    n = 12
    E = prototype.rod.young_modulus * rng.uniform(0.7, 1.5, n)
    mu = rng.uniform(0.1, 0.6, n)
    T = np.zeros((n, 3))
    T[:, 0] = rng.uniform(0.5, 3.0, n)
    X = rng.uniform(0.05, 0.25, n)
    F = np.stack([np.zeros(n), np.zeros(n), -rng.uniform(0.0, 0.2, n)], axis=1)
    out = solve_batch(prototype, T, [(X, F)], values={"young_modulus": E, "friction": mu},
                      chunk=8)
    assert out.converged.all() and out.markers["tip"].shape == (n, 3)
    for k in (0, 5, 11):
        one = solve(prototype.with_parameters(young_modulus=E[k], friction=mu[k]),
                    dict(zip(prototype.tendon_names, T[k])), [(X[k], F[k])])
        np.testing.assert_allclose(out.markers["tip"][k], one.markers["tip"], atol=1e-10)
        assert out.displacements["t1"][k] == pytest.approx(one.displacements["t1"], abs=1e-12)


def test_batch_refuses_bad_values(prototype):
    with pytest.raises(ValueError, match="stiffness"):
        solve_batch(prototype, np.ones((2, 3)), values={"stiffness": [1.0, 2.0]})
    with pytest.raises(ValueError, match="outside the rod"):
        solve_batch(prototype, np.ones((2, 3)), [(np.array([0.1, 0.4]), (0, 0, -1))])
    # a flat (X, fx, fy, fz) and a pair not in a list were Python's "too many values to
    # unpack"; a tendon's own μ by name is said how to give
    with pytest.raises(ValueError, match=r"point force 1: a pair \(X, \(fx, fy, fz\)\)"):
        solve_batch(prototype, np.ones((2, 3)), [(0.25, 0, 0, -0.1)])
    with pytest.raises(ValueError, match="not one pair"):
        solve_batch(prototype, np.ones((2, 3)), (0.25, (0, 0, -0.1)))
    with pytest.raises(ValueError, match=r"friction as \(N, n_tendons\)"):
        solve_batch(prototype, np.ones((2, 3)), values={"friction_t1": [0.3, 0.4]})


@pytest.mark.parametrize("name, step", [("young_modulus", 1e-4), ("density", 1e-4),
                                        ("load_X", 1e-4), ("friction", 1e-4)])
def test_implicit_derivatives_match_finite_differences(prototype, name, step):
    """The exact derivatives against central differences of whole solves (test only)."""
    T = {"t1": 2.0, "t3": 0.8}
    X0, f = 0.17, (0.0, 0.05, -0.15)
    d = solution_derivatives(prototype, T, [(X0, f)], wrt=(name,))

    def tip(h):
        robot, X = prototype, X0
        if name == "load_X":
            X = X0 + h
        elif name == "friction":  # tendon t1 only
            t = prototype.tendons
            robot = prototype.replace(tendons=(dataclasses.replace(
                t[0], friction=t[0].friction + h), *t[1:]))
        else:
            v = getattr(prototype.rod, name)
            robot = prototype.with_parameters(**{name: v + h * v})
        r = solve(robot, T, [(X, f)])
        return np.concatenate([r.markers["tip"], list(r.displacements.values())])

    scale = 1.0 if name in ("load_X", "friction") else getattr(prototype.rod, name)
    fd = (tip(step) - tip(-step)) / (2 * step * scale)
    exact = np.concatenate([d.markers[name][2], d.displacements[name]])
    if name == "friction":
        exact = exact[:, 0]
    exact = exact.reshape(-1)
    assert np.abs(exact).max() > 1e-8
    np.testing.assert_allclose(exact, fd, rtol=1e-5, atol=1e-6 * np.abs(fd).max())


LOCK_SCRIPT = """
import sys, time
import jax, numpy as np
from tendonsense import compiled
compiles = []
original = jax.stages.Lowered.compile
def slow(self, *a, **k):
    compiles.append(1)
    time.sleep(3.0)  # a long compile: the other process arrives while it runs
    return original(self, *a, **k)
jax.stages.Lowered.compile = slow
program = compiled.Program(lambda x: 2.0 * x + 1.0, "lock_test", "key")
out = program(np.arange(3.0))
print(len(compiles), float(out.sum()))
"""


def test_two_processes_compile_a_program_once(tmp_path):
    """Two processes that need the same program at once: one compiles it, the other waits and
    loads the kept executable."""
    env = dict(os.environ, TENDONSENSE_CACHE_DIR=str(tmp_path))
    procs = [subprocess.Popen([sys.executable, "-c", LOCK_SCRIPT], env=env, text=True,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE)
             for _ in range(2)]
    outs = [p.communicate(timeout=300) for p in procs]
    assert all(p.returncode == 0 for p in procs), outs
    counts = sorted(int(out.split()[0]) for out, _ in outs)
    assert counts == [0, 1], outs
    assert all(float(out.split()[1]) == 9.0 for out, _ in outs)
    assert len(list((tmp_path / "programs").glob("lock_test-*.exe"))) == 1


@pytest.mark.parametrize("kept", [True, False])
def test_programs_compile_with_the_packages_options(tmp_path, monkeypatch, kept):
    """Every program is compiled with :func:`settings.compiler_options` (a bad value of a
    known option fails the compile), and an XLA that lacks an option compiles without it."""
    import jax.numpy as jnp
    monkeypatch.setenv("TENDONSENSE_CACHE_DIR", str(tmp_path) if kept else "")
    x = np.linspace(0.0, 1.0, 5)
    monkeypatch.setattr(compiled, "compiler_options",
                        lambda: {"xla_cpu_use_fusion_emitters": "not a bool"})
    with pytest.raises(Exception):
        compiled.Program(lambda a: jnp.sin(a) * 2, "options_bad", kept)(x)
    monkeypatch.setattr(compiled, "compiler_options",
                        lambda: {"xla_cpu_no_such_option_anywhere": True})
    out = compiled.Program(lambda a: jnp.sin(a) * 2, "options_unknown", kept)(x)
    np.testing.assert_allclose(out, 2 * np.sin(x), rtol=1e-15)


def test_programs_are_compiled_without_source_locations(monkeypatch):
    """A program's executable carries no source locations or operation names (they were a
    fifth to a third of its size and of its loading), and computes what the function with
    them does; the same function jitted elsewhere keeps its own (JAX caches lowerings by
    function)."""
    import jax
    import jax.numpy as jnp

    def fn(a):
        return jnp.cumsum(jnp.sin(a)) @ jnp.cos(a)

    monkeypatch.setenv("TENDONSENSE_CACHE_DIR", "")
    x = np.linspace(0.0, 1.0, 7)
    ours = compiled.Program(fn, "strip_test", 0).executable(x)
    theirs = jax.jit(fn).lower(x).compile()
    assert "op_name" in theirs.as_text() and "op_name" not in ours.as_text()
    assert float(ours(x)) == pytest.approx(float(theirs(x)), rel=1e-15)


def test_a_program_called_again_skips_its_signature(tmp_path, monkeypatch):
    """A program called again with arguments of the same kinds runs its last executable
    without forming their signature; other shapes, dtypes or trees get the executable of
    their own, each with the right answer."""
    import jax.numpy as jnp
    monkeypatch.setenv("TENDONSENSE_CACHE_DIR", str(tmp_path))
    signatures = []
    real = compiled._signature
    monkeypatch.setattr(compiled, "_signature", lambda args: signatures.append(1) or real(args))
    program = compiled.Program(lambda a, p: jnp.sum(a) * p.get("k", 2.0), "again", "test")
    x3 = np.arange(3.0)
    assert float(program(x3, {})) == 6.0 and len(signatures) == 1
    for _ in range(3):
        assert float(program(x3 + 1, {})) == 12.0
    assert len(signatures) == 1
    for args, want in [((np.arange(4.0), {}), 12.0), ((x3.astype(np.float32), {}), 6.0),
                       ((x3, {"k": np.float64(3.0)}), 9.0), ((x3, {}), 6.0)]:
        assert float(program(*args)) == want
    assert len(signatures) == 5 and len(program.loaded) == 4


def test_the_kept_programs_stay_within_the_cache_limit(tmp_path, monkeypatch):
    """Kept programs take at most ``settings.cache_limit`` bytes: a new one pushes out the
    least recently used (a program loaded again counts as used), never itself; the others
    still load, and an evicted one compiles again with the same answer."""
    import jax.numpy as jnp
    from tendonsense import settings
    monkeypatch.setenv("TENDONSENSE_CACHE_DIR", str(tmp_path))
    folder = tmp_path / "programs"
    x = np.arange(3.0)

    def run(k):  # a fresh program object: loads the kept executable if there is one
        return float(compiled.Program(lambda a: jnp.sum(a) * k, f"evict{k}", "test")(x))

    for k in (1, 2, 3):
        assert run(k) == 3.0 * k
    files = {k: next(folder.glob(f"evict{k}-*.exe")) for k in (1, 2, 3)}
    for k, f in files.items():  # oldest first: 1, 2, 3; then 1 used again
        os.utime(f, (1000.0 * k, 1000.0 * k))
    assert run(1) == 3.0 and files[1].stat().st_mtime > 3000.0
    size = max(f.stat().st_size for f in files.values())
    monkeypatch.setattr(settings, "cache_limit", 3 * size)
    assert run(4) == 12.0
    left = sorted(f.name.split("-")[0] for f in folder.glob("*.exe"))
    assert left == ["evict1", "evict3", "evict4"], left
    assert files[2].with_suffix(".lock").exists()  # (lock files stay: one may be held)
    monkeypatch.setattr(settings, "cache_limit", None)  # the environment's, in MB
    monkeypatch.setenv("TENDONSENSE_CACHE_LIMIT", "0")
    assert settings.cache_limit_bytes() == 0
    assert run(2) == 6.0  # compiled again, kept alone
    assert [f.name.split("-")[0] for f in folder.glob("*.exe")] == ["evict2"]
    monkeypatch.setenv("TENDONSENSE_CACHE_LIMIT", "500")
    assert settings.cache_limit_bytes() == 500_000_000
    monkeypatch.setenv("TENDONSENSE_CACHE_LIMIT", "2G")  # not megabytes: said, default kept
    assert settings.cache_limit_bytes() == settings.CACHE_LIMIT


def test_programs_compile_unpinned(monkeypatch):
    """Every compilation runs inside :func:`settings.unpinned` (a process kept to a core
    compiles on the cores it had)."""
    from contextlib import contextmanager
    entered = []

    @contextmanager
    def recording():
        entered.append(True)
        yield

    monkeypatch.setattr(compiled, "unpinned", recording)
    monkeypatch.setenv("TENDONSENSE_CACHE_DIR", "")
    assert float(compiled.Program(lambda a: a.sum() + 1, "unpinned", "test")(np.ones(2))) == 3
    assert entered == [True]


def test_factorisations_match_lapack():
    """:mod:`tendonsense.linalg`'s LU, Cholesky, solve and determinant (XLA operations only)
    against NumPy's LAPACK, pivoting included."""
    import jax
    from tendonsense import linalg
    rng = np.random.default_rng(3)
    for n in (1, 2, 7, 40):
        A = rng.normal(size=(n, n))
        A[0, 0] = 0.0 if n > 1 else 1.0  # a zero first pivot: the rows must be swapped
        B = rng.normal(size=(n, 3))
        np.testing.assert_allclose(jax.jit(linalg.solve)(A, B), np.linalg.solve(A, B),
                                   rtol=1e-9, atol=1e-11)
        np.testing.assert_allclose(jax.jit(linalg.det)(A), np.linalg.det(A), rtol=1e-10)
        S = A @ A.T + n * np.eye(n)
        np.testing.assert_allclose(jax.jit(linalg.cholesky)(S), np.linalg.cholesky(S),
                                   rtol=1e-12, atol=1e-12)
    assert not np.all(np.isfinite(linalg.cholesky(-np.eye(2))))


NO_SCIPY_SCRIPT = """
import sys
import jax
from tendonsense.cli import main
compiles = []
jax.monitoring.register_event_duration_secs_listener(
    lambda event, secs, **kw: compiles.append(1)
    if event == "/jax/core/compile/backend_compile_duration" else None)
robot, figure = sys.argv[1], sys.argv[3]
for argv in (["solve", robot, "--tension", "t1=2.0", "--plot", figure],
             ["fk", robot, "--displacement", "t1=-0.01"],
             ["estimate", robot, "--displacement", "t1=-0.005", "--tension", "t1=2.1",
              "--unknown", "0.25,0,0,-1"]):
    assert main(argv) == 0
if sys.argv[2] == "lapack":  # a kept program that calls LAPACK still loads and runs
    import jax.numpy as jnp, numpy as np
    from tendonsense import compiled
    out = compiled.Program(lambda a: jnp.linalg.solve(a, jnp.ones(2)), "lapack_test", 0)(
        2.0 * np.eye(2))
    assert np.allclose(out, 0.5), out
print(len(compiles))
print(sorted(m for m in sys.modules if m.split(".")[0] == "scipy")[:3])
"""


def test_a_warm_start_imports_no_lapack(tmp_path):
    """The solvers' kept programs call no LAPACK kernel, so a warm ``solve`` (its figure
    included), ``fk`` or ``estimate`` does not import SciPy's LAPACK (0.2–0.3 s of every
    start-up); a kept program that does call one loads it (issue 24). Nor does it compile
    anything: every step on the host is NumPy or a kept program (an eager JAX operation
    compiles in every new process)."""
    env = dict(os.environ, TENDONSENSE_CACHE_DIR=str(tmp_path))
    robot = str(Path(__file__).parents[1] / "examples" / "paper_prototype.toml")
    outs = [subprocess.run([sys.executable, "-c", NO_SCIPY_SCRIPT, robot, what,
                            str(tmp_path / "shape.png")], env=env,
                           capture_output=True, text=True, timeout=600)
            for what in ("lapack", "lapack", "none")]  # compiled, then loaded twice
    assert all(o.returncode == 0 for o in outs), [o.stderr[-2000:] for o in outs]
    assert outs[1].stdout.splitlines()[-1] != "[]"  # the LAPACK program imported it
    assert outs[2].stdout.splitlines()[-1] == "[]", outs[2].stdout[-500:]
    assert outs[0].stdout.splitlines()[-2] != "0"  # (the count sees a compile)
    assert outs[2].stdout.splitlines()[-2] == "0", outs[2].stdout[-500:]


PRELOAD_SCRIPT = """
import sys, threading
from tendonsense import compiled, load_robot
from tendonsense.estimation import PointForceUnknown, estimate
from tendonsense.forward import solve
loads, real = [], compiled._kept
def kept(path):
    loads.append((path.name.split("-")[0], threading.current_thread().name))
    return real(path)
compiled._kept = kept
robot = load_robot(sys.argv[1])
assert solve(robot, {"t1": 2.0}).converged
assert estimate(robot, {"t1": -0.005}, {"t1": 2.1}, [PointForceUnknown(0.25, (0, 0, -1))]
                ).converged
from tendonsense.tracking import solve_batch
assert solve_batch(robot, {"t1": [2.0, 3.0]}, workers=1, stability=True).converged.all()
assert solve(robot, {"t1": 10.0}, [(0.25, (0, 0, -1.2))], settle=True).converged
print(sorted(loads))
print(sum(len(p._loading) for p in list(compiled._PROGRAMS)))
"""


def test_a_first_solve_or_estimate_loads_its_later_programs_meanwhile(tmp_path):
    """In a new process with the programs kept, a solve loads its outputs' program, an
    estimate its Jacobians', a batch checked for stability its stiffness ratios' and a solve
    that may settle its settling's on another thread while its own solver loads and runs;
    each is loaded once and used (none left waiting: its signature is the call's)."""
    env = dict(os.environ, TENDONSENSE_CACHE_DIR=str(tmp_path))
    robot = str(Path(__file__).parents[1] / "examples" / "paper_prototype.toml")
    outs = [subprocess.run([sys.executable, "-c", PRELOAD_SCRIPT, robot], env=env,
                           capture_output=True, text=True, timeout=600) for _ in range(2)]
    assert all(o.returncode == 0 for o in outs), [o.stderr[-2000:] for o in outs]
    loads, waiting = outs[1].stdout.splitlines()[-2:]
    ahead = "tendonsense-load_0"
    loads = [(name, "pool" if thread.startswith("ThreadPoolExecutor") else thread)
             for name, thread in ast.literal_eval(loads)]
    assert loads == sorted([("newton", "MainThread"), ("outputs", ahead),
                            ("newton", "MainThread"), ("jacobians", ahead),
                            ("tracker", "pool"), ("stiffness_ratios", ahead),
                            ("linearised", ahead)]), loads
    assert waiting == "0"


def test_a_series_bounds_each_samples_tension_with_its_own_modulus(prototype):
    """A series or batch with its own E per sample checks each tension against half of that
    sample's E·A (39.3 N at the tip with the file's E): 20 N breaks the rule at E/4, 45 N
    does not at 2 E (a sample the file's E alone would have refused)."""
    from tendonsense.tracking import estimate_batch, estimate_series
    prob = estimation.problem(prototype, ["t1"], [PointForceUnknown(0.25, (0, 0, -1))])
    E = prototype.rod.young_modulus * np.array([0.25, 2.0])
    for run in (estimate_series, estimate_batch):
        out = run(prob, [{"t1": -0.01}] * 2, [{"t1": 20.0}, {"t1": 45.0}],
                  values={"young_modulus": E})
        assert "would shorten the rod" in out[0].note and not out[0].converged
        assert out[1].converged or not out[1].note.startswith("bad value"), out[1].note
