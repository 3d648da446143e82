"""The paper's analyses (§IV, §V-B4): sensitivity to measurement and friction errors,
force resolution, and the comparison of GVS with simpler strain models.

Each returns plain data (lists of dicts / arrays) that the CLI writes as CSV/JSON and
:mod:`tendonsense.plotting` draws.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from . import experiments
from .estimation import PointForceUnknown, estimate_problem, problem, reduced_jacobians
from .forward import forward_kinematics, solve
from .robot import Robot
from .model import Values
from .stability import UNSTABLE_NOTE

from .units import GF  # noqa: F401  (N per gram-force)

#: the paper's figures (§IV)
PAPER_SINGLE = {"length": (0.12, 0.17), "tension": (0.08, 0.10), "friction": (0.08, 0.10)}
PAPER_3D = {"length": (0.04, 0.08), "tension": (0.12, 0.16), "friction": (0.12, 0.16)}
PAPER_RESOLUTION_G = {"x": (3.72, 3.6), "y": (0.36, 0.16), "z": (0.46, 0.2)}


@dataclass(frozen=True)
class Errors:
    """Error amplitudes of §IV: tendon length (m), tension and friction (relative)."""

    length: float = 1e-3
    tension: float = 0.025
    friction: float = 0.15


def _axes(robot: Robot) -> np.ndarray:
    """The base frame's axes (columns, global): the analyses' forces are in it (x along the
    rod at its base; for the paper's prototype the global axes, z vertical)."""
    return np.asarray(robot.base_rotation, float)


def _values_with_friction(prob, factors) -> Values:
    v = prob.model.values
    return v._replace(friction=np.asarray(v.friction) * np.asarray(factors, float))


def sensitivity_single(robot: Robot, tendon: str = "t1", forces_gf=(-25.0, -75.0, -125.0),
                       y_range=(-0.02, 0.0), n_y: int = 9, errors: Errors = Errors(),
                       progress=None) -> list[dict]:
    """Fig. 3a: a tip force along the base frame's z (:func:`_axes`; vertical on the paper's
    prototype) estimated from one tendon, the estimate under ±length, ±tension and ±friction
    errors. One row per (force, y); a row whose truth or estimate did not converge has no
    estimates, its ``note`` says why; ``unstable``: the estimate's shape is an unstable
    equilibrium (:func:`~tendonsense.stability.unstable`; kept in the summary)."""
    L = robot.rod.length
    up = _axes(robot)[:, 2]
    prob = problem(robot, [tendon], [PointForceUnknown(L, tuple(up))])
    j = robot.tendon_names.index(tendon)
    rows = []
    grid = list(itertools.product(forces_gf, np.linspace(*y_range, n_y)))
    for k, (f_gf, y) in enumerate(grid):
        F = f_gf * GF
        truth = forward_kinematics(robot, {tendon: y}, point_forces=[(L, tuple(F * up))])
        T = truth.tensions[tendon]
        row = {"force_gF": f_gf, "force_N": F, "displacement_m": float(y), "tension_N": T,
               "truth_converged": bool(truth.converged)}
        if not truth.converged or T <= 0:
            row["note"] = ("slack" if truth.converged else "forward problem failed: " + (
                truth.note or "not converged"))
            rows.append(row)
            continue
        nominal = estimate_problem(prob, {tendon: y}, {tendon: T})
        if not nominal.converged:
            row["note"] = "estimate failed: " + (nominal.note or "not converged")
            rows.append(row)
            continue
        row["estimate_N"] = float(nominal.magnitudes[0])
        row["unstable"] = UNSTABLE_NOTE in nominal.note
        x0 = nominal.extra["x"]
        for sign, tag in ((+1, "plus"), (-1, "minus")):
            cases = {
                "length": dict(displacements={tendon: y + sign * errors.length},
                               tensions={tendon: T}),
                "tension": dict(displacements={tendon: y},
                                tensions={tendon: T * (1 + sign * errors.tension)}),
                "friction": dict(displacements={tendon: y}, tensions={tendon: T},
                                 values=_values_with_friction(
                                     prob, [1 + sign * errors.friction * (i == j)
                                            for i in range(len(robot.tendons))])),
            }
            for source, kw in cases.items():
                r = estimate_problem(prob, x0=x0, **kw)
                row[f"{source}_{tag}_N"] = float(r.magnitudes[0]) if r.converged else np.nan
        rows.append(row)
        if progress:
            progress(k + 1, len(grid))
    return rows


def single_summary(rows: list[dict]) -> dict:
    """Mean and maximum relative error per error source (both signs)."""
    out = {}
    for source in ("length", "tension", "friction"):
        errs = [abs(r[f"{source}_{s}_N"] - r["force_N"]) / abs(r["force_N"])
                for r in rows if "estimate_N" in r for s in ("plus", "minus")]
        errs = np.array(errs)
        out[source] = {"mean": float(np.nanmean(errs)), "max": float(np.nanmax(errs)),
                       "paper_mean": PAPER_SINGLE[source][0], "paper_max": PAPER_SINGLE[source][1]}
    return out


def default_3d_forces_gf():
    """Tip forces for Fig. 3b / the resolution analysis: every sign of (50, 50, 75) gF."""
    return [np.array([sx * 50.0, sy * 50.0, sz * 75.0])
            for sx, sy, sz in itertools.product((-1, 1), repeat=3)]


def _per_tendon(names, tensions) -> dict[str, float]:
    """``tensions`` (N: one for every tendon, or one each) by tendon name."""
    return dict(zip(names, np.broadcast_to(np.asarray(tensions, float), (len(names),)).tolist()))


def sensitivity_3d(robot: Robot, forces_gf=None, tensions=1.5,
                   errors: Errors = Errors(), progress=None) -> list[dict]:
    """Fig. 3b: 3-D tip forces from every tendon (three in the paper), each at ``tensions``
    (N: one for all, or one per tendon); per force and error source, the 3^n estimates from
    every per-tendon error sign (−, 0, +) of amplitude error / n_tendons. Forces and
    estimates are in the base frame (:func:`_axes`); a force whose truth or estimate did not
    converge has no errors (NaN, and the summary leaves it out); ``unstable`` as in
    :func:`sensitivity_single`."""
    forces_gf = default_3d_forces_gf() if forces_gf is None else forces_gf
    L = robot.rod.length
    names = robot.tendon_names
    n = len(names)
    axes = _axes(robot)
    prob = problem(robot, names, [PointForceUnknown(L, tuple(e)) for e in axes.T])
    T = _per_tendon(names, tensions)
    out = []
    for k, f_gf in enumerate(forces_gf):
        F = np.asarray(f_gf) * GF
        truth = solve(robot, T, [(L, tuple(axes @ F))])
        y = truth.displacements
        nominal = estimate_problem(prob, y, T)
        entry = {"force_gF": np.asarray(f_gf, float).tolist(), "force_N": F.tolist(),
                 "estimate_N": nominal.magnitudes.tolist(),
                 "converged": bool(truth.converged and nominal.converged),
                 "unstable": UNSTABLE_NOTE in nominal.note}
        if not entry["converged"]:  # no solution: no errors to draw from it
            for source in ("length", "tension", "friction"):
                entry[source] = {"estimates_N": [], "mean_relative_error": float("nan"),
                                 "max_relative_error": float("nan")}
            out.append(entry)
            continue
        for source in ("length", "tension", "friction"):
            amp = getattr(errors, source) / n
            estimates = []
            for signs in itertools.product((-1, 0, 1), repeat=n):
                s = np.array(signs, float)
                kw = {"displacements": dict(y), "tensions": dict(T)}
                if source == "length":
                    kw["displacements"] = {m: y[m] + s[i] * amp for i, m in enumerate(names)}
                elif source == "tension":
                    kw["tensions"] = {m: T[m] * (1 + s[i] * amp) for i, m in enumerate(names)}
                else:
                    kw["values"] = _values_with_friction(prob, 1 + s * amp)
                r = estimate_problem(prob, x0=nominal.extra["x"], **kw)
                estimates.append(r.magnitudes if r.converged else np.full(3, np.nan))
            estimates = np.array(estimates)
            entry["converged"] &= bool(np.all(np.isfinite(estimates)))
            err = np.linalg.norm(estimates - F, axis=1) / np.linalg.norm(F)
            entry[source] = {"estimates_N": estimates.tolist(),
                             "mean_relative_error": float(np.nanmean(err)),
                             "max_relative_error": float(np.nanmax(err))}
        out.append(entry)
        if progress:
            progress(k + 1, len(forces_gf))
    return out


def summary_3d(entries: list[dict]) -> dict:
    out = {}
    for source in ("length", "tension", "friction"):  # over the forces solved
        means = [e[source]["mean_relative_error"] for e in entries]
        out[source] = {"mean": float(np.nanmean(means)),
                       "min_over_forces": float(np.nanmin(means)),
                       "max_over_forces": float(np.nanmax(means)),
                       "paper_range": list(PAPER_3D[source])}
    return out


def resolution(robot: Robot, forces_gf=None, tensions=1.5,
               tension_resolution: float = 0.025 / 3, progress=None) -> list[dict]:
    """§IV resolution: at fixed tendon lengths, every tendon at ``tensions`` (N: one for
    all, or one per tendon), the smallest increment of each tip-force component (in the base
    frame, :func:`_axes`) that changes at least one tension by the sensor resolution (first order,
    ``dT/dF = −(∂y/∂T)⁻¹ ∂y/∂F`` with the equilibrium eliminated)."""
    forces_gf = default_3d_forces_gf() if forces_gf is None else forces_gf
    L = robot.rod.length
    names = robot.tendon_names
    axes = _axes(robot)
    prob = problem(robot, names, [PointForceUnknown(L, tuple(e)) for e in axes.T])
    T = _per_tendon(names, tensions)
    tensions = np.array(list(T.values()))
    rows = []
    for k, f_gf in enumerate(forces_gf):
        F = np.asarray(f_gf) * GF
        truth = solve(robot, T, [(L, tuple(axes @ F))])
        est = estimate_problem(prob, truth.displacements, T)
        if not (truth.converged and est.converged):
            rows.append({"force_gF": np.asarray(f_gf, float).tolist(), "converged": False,
                         **{f"resolution_{a}_g": float("nan") for a in "xyz"}})
            continue
        drive = prob.drive(np.array(tensions, float), np.array([truth.displacements[n]
                                                                  for n in names]))
        Jz, JT = reduced_jacobians(prob, est.extra["x"], drive, prob.model.values)
        try:
            dT_dF = -np.linalg.solve(JT, Jz)  # (n_t, 3)
        except np.linalg.LinAlgError:
            raise ValueError(
                f"at fixed lengths this robot's tendon tensions are not determined by the tip "
                f"force ({', '.join(names)}: ∂y/∂T is singular: more tendons than independent "
                f"ways they load the rod, or two that pull alike); the analysis (§IV) is for "
                f"the paper's three tendons at 120°"
            ) from None
        detect = tension_resolution * np.abs(np.array(tensions, float))[:, None]
        delta = np.min(detect / np.maximum(np.abs(dT_dF), 1e-300), axis=0)  # N per component
        rows.append({"force_gF": np.asarray(f_gf, float).tolist(), "converged": True,
                     **{f"resolution_{a}_g": float(d / GF) for a, d in zip("xyz", delta)}})
        if progress:
            progress(k + 1, len(forces_gf))
    return rows


def resolution_summary(rows: list[dict]) -> dict:
    out = {}
    for a in "xyz":
        v = np.array([r[f"resolution_{a}_g"] for r in rows])
        out[a] = {"mean_g": float(np.nanmean(v)), "std_g": float(np.nanstd(v)),
                  "paper_mean_g": PAPER_RESOLUTION_G[a][0], "paper_std_g": PAPER_RESOLUTION_G[a][1]}
    return out


#: strain settings of the compared models (§V-B4)
def model_variants(robot: Robot) -> dict[str, Robot]:
    deg = dict(robot.strain)
    bend = {k: deg.get(k, 4) for k in ("bending_y", "bending_z")}
    return {"GVS": robot,
            "3D-PC+E": robot.replace(strain=tuple({**bend, "elongation": deg.get("elongation", 3)}
                                                  .items())),
            "3D-PC": robot.replace(strain=tuple(bend.items()))}


def same_estimates(table: dict[str, list]) -> dict[str, str]:
    """Models of a :func:`compare` table whose estimates equal an earlier model's on every
    row (to 1e-9 relative): {model: the earlier model}."""
    out, models = {}, list(table)
    for k, m in enumerate(models):
        for earlier in models[:k]:
            pairs = list(zip(table[m], table[earlier]))
            if all(a.ours is not None and b.ours is not None and np.allclose(
                    a.ours, b.ours, rtol=1e-9, atol=0.0) for a, b in pairs):
                out[m] = earlier
                break
    return out


def compare(robot: Robot, table, progress=None) -> dict[str, list]:
    """The estimator with each strain model on the experiment rows of ``table`` (a path, or
    its :func:`~tendonsense.experiments.read_experiments`)."""
    out = {}
    variants = model_variants(robot)
    for k, (name, r) in enumerate(variants.items()):
        out[name] = experiments.run(r, table)
        if progress:
            progress(k + 1, len(variants))
    return out
