"""Physics validation figures of the core model (issue 2), printed: closed-form beams, the
frictionless actuation identity, basis convergence and the independent Cosserat BVP of the test
suite. Run from the repository root: ``python benchmarks/validation.py`` (about 2 minutes)."""
import sys, time
from pathlib import Path
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import numpy as np, jax, jax.numpy as jnp
import tendonsense
from conftest import robot_from, uniform_rod
from tendonsense.robot import load_robot
from tendonsense.forward import solve, model_for
from tendonsense import tendons
from tendonsense.kinematics import poses
from cosserat_bvp import CosseratBVP
from test_cosserat_reference import CASES, RICH
r, L, E, F = 0.01, 0.25, 1e6, 1e-3
robot = robot_from(rod=uniform_rod(r, L, E), gravity={"acceleration": [0, 0, 0]}, marker=[{"name": "tip", "X": L}])
res = solve(robot, point_forces=[(L, (0.0, 0.0, -F))])
I = np.pi * r**4 / 4
print("cantilever rel err", (-res.markers["tip"][2]) / (F*L**3/(3*E*I)) - 1)
d, T = 0.008, 0.5
robot = robot_from(rod=uniform_rod(r, L, E), gravity={"acceleration": [0, 0, 0]}, tendon=[{"name": "t", "offset_base": [0, d], "offset_tip": [0, d], "friction": 0.0, "disks": 41}], solver={"intervals": 40})
res = solve(robot, {"t": T}); pts = res.backbone[:, [0, 2]]
A = np.c_[2 * pts, np.ones(len(pts))]; (cx, cz, c), *_ = np.linalg.lstsq(A, (pts**2).sum(1), rcond=None)
print("arc curvature rel err", (1/np.sqrt(c + cx**2 + cz**2)) / (T*d/(E*I)) - 1)
p = load_robot(Path(__file__).resolve().parents[1] / 'examples' / 'paper_prototype.toml')
print("T1=0.88 y1 [mm]", solve(p, {"t1": 0.88}).displacements["t1"]*1e3)
m = model_for(p.with_parameters(friction=0.0))
worst = 0
for seed in range(3):
    q = jnp.asarray(np.random.default_rng(seed).normal(scale=2.0, size=m.nq))
    B = np.asarray(tendons.actuation(m.structure, m.values, q, jnp.zeros(3)))
    dy = np.asarray(jax.jacfwd(lambda q: tendons.length_changes(m.structure, m.values, poses(m.values, q)[0], q))(q))
    worst = max(worst, np.abs(B + dy.T).max() / np.abs(B).max())
print("B identity max rel", worst)
loads = [(0.25, (0.0, 0.2, -0.5))]; tension = {"t1": 2.0, "t3": 1.0}
base = solve(p, tension, loads); richer = solve(p.replace(strain=tuple((k, v + 2) for k, v in p.strain)), tension, loads)
print("basis +2 tip moved [mm]", np.linalg.norm(base.markers["tip"] - richer.markers["tip"])*1e3)
for case, (T, ld) in CASES.items():
    ref = CosseratBVP(p, T, ld).solve().markers()
    g = solve(p.replace(strain=RICH), dict(zip(p.tendon_names, T)), ld)
    g0 = solve(p, dict(zip(p.tendon_names, T)), ld)
    print(f"BVP {case}: rich {max(np.linalg.norm(g.markers[k]-ref[k]) for k in ref)*1e3:.3f} mm, default basis (no shear) {max(np.linalg.norm(g0.markers[k]-ref[k]) for k in ref)*1e3:.3f} mm, tip motion {np.linalg.norm(ref['tip']-[0.25,0,0])*1e3:.0f} mm")
# warm-started solve (plain API)
res = solve(p, {"t1": 2.0}, [(0.25, (0,0,-0.2))])
ts=[]
for k in range(50):
    t=time.perf_counter(); solve(p, {"t1": 2.0 + 1e-3*k}, [(0.25, (0,0,-0.2))], q0=res.q); ts.append(time.perf_counter()-t)
print("warm-started solve (plain API, incl. result/backbone) median ms", np.median(ts)*1e3)
