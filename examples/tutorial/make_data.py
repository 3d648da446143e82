"""Make the tutorial's example data from the model itself (run from the repository root:
``python examples/tutorial/make_data.py``).

Writes examples/tutorial/snapshots.csv (static poses of the paper's prototype with known
tip weights and tensions, marker positions with 0.5 mm noise),
examples/tutorial/snapshots_tendons.csv (13 such poses read by the tendons alone, 0.1 mm
noise) and
examples/tutorial/readings.csv (a 6 s log at 50 Hz: tendon t1 pulled from 1 N to 3 N and
released again while a tip weight of 0, 10 and 20 gF hangs on the tip; 0.1 mm and 0.8 %
sensor noise). The "true" robot is examples/paper_prototype.toml; along the log, t1's
friction follows its tension history as a real tendon's does, at every disk it turns at
(pulled in while the tension rises, stuck when it turns, the disks near the actuator paid out
first, the anchor once ln T has fallen through its band 2μφ).
"""

import csv

import jax
import numpy as np

from tendonsense import load_robot
from tendonsense.forward import model_for, solve
from tendonsense.sliding import FIXED_POINT, STATE_TOL, FrictionHistory
from tendonsense.statics import Drive, Unknowns, shape_outputs, solve_system
from tendonsense.tendons import depths, turns

GF = 9.80665e-3
robot = load_robot("examples/paper_prototype.toml")
rng = np.random.default_rng(12)

# --- snapshots: weights at the tip without tension, then tensions without weight
poses = [({}, 0.0), ({}, 5.0), ({}, 10.0), ({}, 20.0),
         ({"t1": 1.0}, 0.0), ({"t1": 2.0}, 0.0), ({"t1": 3.0}, 0.0),
         ({"t2": 2.0}, 0.0), ({"t3": 2.0}, 0.0), ({"t1": 2.0}, 10.0)]
header = ([f"tension_{t}" for t in robot.tendon_names] + ["load_X", "load_fx", "load_fy", "load_fz"]
          + [f"marker_{m}_{a}" for m in robot.marker_names for a in "xyz"])
with open("examples/tutorial/snapshots.csv", "w", newline="") as fh:
    w = csv.writer(fh)
    w.writerow(header)
    for tensions, grams in poses:
        load = [(0.25, (0.0, 0.0, -grams * GF))] if grams else []
        res = solve(robot, tensions, load)
        assert res.converged
        row = [tensions.get(t, 0.0) for t in robot.tendon_names]
        row += [0.25, 0.0, 0.0, round(-grams * GF, 6)] if grams else ["", "", "", ""]
        row += [round(float(v), 5) for m in robot.marker_names
                for v in res.markers[m] + rng.normal(0, 5e-4, 3)]
        w.writerow(row)

# --- a readings log: t1 pulled from 1 N to 3 N and back, a tip weight of 0 / 10 / 20 gF
n, rate = 300, 50.0
time = np.arange(n) / rate
T1 = 2.0 - np.cos(2 * np.pi * time / 6.0)
grams = np.where(time < 2, 0.0, np.where(time < 4, 10.0, 20.0))

def released(T, load):
    """The length change of t1 at each tension of ``T`` under ``load`` (N, 3), its friction
    state at every turn following the tension history: at each reading the state at the
    sample's own shape (the turning to each disk, ψ), settled by a few solves."""
    model = model_for(robot)
    turned = jax.jit(lambda q: depths(model.structure, model.values, q))
    mu = np.asarray(model.values.friction, float)
    history = FrictionHistory(mu, turns=turns(model.values))
    phi, q, out = np.zeros_like(history.phi), None, []
    for T_k, f in zip(T, load):
        tensions = np.array([T_k, 0.0, 0.0])
        drive = Drive(tensions, np.asarray(f, float)[None], np.array([0.25]),
                      np.asarray(robot.gravity, float), np.zeros(0))
        before, state = history, None
        for _ in range(FIXED_POINT):
            history = before.copy()
            history.phi = phi
            new = history.step(tensions, None if state is None else phi_k)
            if state is not None and np.max(np.abs(new - state)) <= STATE_TOL:
                break
            state = new
            values = model.values._replace(friction=state * mu[:, None])
            res = solve_system(model.structure, values, (), drive, Unknowns.none(3, 1), q)
            assert res.converged
            q_k = np.asarray(res.x)
            phi_k = np.asarray(turned(q_k))
        q, phi = q_k, phi_k
        out.append(float(shape_outputs(model.structure, model.values, q)[2][0]))
    return np.array(out)


y = released(T1, np.stack([0 * T1, 0 * T1, -grams * GF], 1)) + rng.normal(0, 1e-4, n)
T = T1 * (1 + rng.normal(0, 0.025 / 3, n))
with open("examples/tutorial/readings.csv", "w", newline="") as fh:
    w = csv.writer(fh)
    w.writerow(["time", "tension_t1", "tension_t2", "tension_t3", "displacement_t1"])
    for k in range(n):  # t2 and t3 slack: their tensions read 0
        w.writerow([f"{time[k]:.2f}", f"{T[k]:.5f}", "0", "0", f"{y[k]:.6f}"])
with open("examples/tutorial/applied_weight.csv", "w", newline="") as fh:
    w = csv.writer(fh)
    w.writerow(["time", "applied_N"])
    for k in range(n):
        w.writerow([f"{time[k]:.2f}", f"{grams[k] * GF:.6f}"])
# --- camera-free snapshots: the same kind of poses, only the tendons' own length readings
rng = np.random.default_rng(13)
poses += [({"t1": 3.5}, 0.0), ({"t2": 3.0}, 0.0), ({"t3": 3.0}, 0.0)]
with open("examples/tutorial/snapshots_tendons.csv", "w", newline="") as fh:
    w = csv.writer(fh)
    w.writerow([f"tension_{t}" for t in robot.tendon_names] + ["load_X", "load_fx", "load_fy",
                "load_fz"] + [f"displacement_{t}" for t in robot.tendon_names])
    for tensions, grams in poses:
        load = [(0.25, (0.0, 0.0, -grams * GF))] if grams else []
        res = solve(robot, tensions, load)
        assert res.converged
        row = [tensions.get(t, 0.0) for t in robot.tendon_names]
        row += [0.25, 0.0, 0.0, round(-grams * GF, 6)] if grams else ["", "", "", ""]
        row += [round(res.displacements[t] + rng.normal(0, 1e-4), 6) for t in robot.tendon_names]
        w.writerow(row)
print("wrote examples/tutorial/snapshots.csv, examples/tutorial/readings.csv, "
      "examples/tutorial/applied_weight.csv, examples/tutorial/snapshots_tendons.csv")
