"""Identification of E, ρ and μ over static snapshots (eq. 18–19), from marker positions,
tendon length changes, or both; snapshots taken while a tendon was paid out (released) sign
its Capstan exponent the other way (:mod:`tendonsense.sliding`), so that pull/release cycles
under a known load measure μ by the width of their hysteresis.

Each snapshot's equilibrium is an exact constraint: its shape ``q_k(θ)`` is solved by the core
Newton solver, and the measurement Jacobian follows by implicit differentiation,
``dm/dθ = m_q (−E_q⁻¹ ∂E/∂θ)``; Levenberg–Marquardt on ``log θ`` minimises
``Σ_k ‖p_k − p_k^meas‖² / σ_p² + ‖y_k − y_k^meas‖² / σ_y²`` (markers and tendon readings,
each weighted by its noise).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Callable, NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from scipy.optimize import brentq, minimize_scalar

from . import inputs, tendons
from .compiled import Program
from .forward import model_for, solve
from .inputs import PARAMETERS, parameter_names  # noqa: F401 (API)
from .kinematics import poses
from .model import Structure
from .readings import Snapshot, SnapshotError, motion_step_error, read_snapshots  # noqa: F401 (API)
from .result import compact_repr, joined
from .robot import Robot
from .simulation import MAX_STEP, simulate
from .statics import CACHE_SIZE, Drive, Unknowns, marker_positions, solve_system, terms
from .units import apart


#: default measurement noise (1 σ): markers, tendon length changes (m)
MARKER_NOISE = 1e-3
LENGTH_NOISE = 1e-4

@dataclass(frozen=True)
class LeftOut:
    """Cross-validation of one snapshot: the parameters fitted without it and how far its
    measurements lie from their prediction (RMS, m; None where not measured)."""

    snapshot: int  # 1-based, in the order given
    parameters: dict[str, float] | None  # None if the rest cannot determine them
    marker_error: float | None
    displacement_error: float | None
    fitted_marker_error: float | None  # the same snapshot's misfit with every snapshot fitted
    fitted_displacement_error: float | None
    converged: bool
    note: str = ""

    def to_json(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


@dataclass(frozen=True)
class Identified:
    """The fitted parameters (SI) with their 1-σ uncertainty from the measurement noise (the
    Gauss–Newton covariance at the fit), and the misfits before and after (RMS, m; None for a
    kind of measurement no snapshot has)."""

    parameters: dict[str, float]
    marker_rmse: float | None
    displacement_rmse: float | None
    initial_marker_rmse: float | None
    initial_displacement_rmse: float | None
    converged: bool
    iterations: int
    robot: Robot  # the robot with the fitted values
    crossval: tuple[LeftOut, ...] = ()
    snapshot_errors: tuple[tuple[float | None, float | None], ...] = ()  # per snapshot, fitted
    sigma: dict[str, float | None] = field(default_factory=dict)  # 1 σ per parameter, SI
    note: str = ""  # why the fit is not converged, when it is not
    #: the RMS of the residuals in units of their noise (about 1 where the model explains the
    #: data and the noise is as assumed)
    misfit: float | None = None
    warning: str = ""  # a converged fit that does not explain the data: why to doubt it
    #: the noise the fit assumed (1 σ, m): a marker coordinate, a tendon length change
    noise: tuple[float, float] | None = None

    __repr__ = compact_repr

    def to_json(self) -> dict:
        out = {**self.parameters, "sigma": self.sigma, "marker_rmse": self.marker_rmse,
               "displacement_rmse": self.displacement_rmse,
               "initial_marker_rmse": self.initial_marker_rmse,
               "initial_displacement_rmse": self.initial_displacement_rmse,
               "converged": self.converged, "iterations": self.iterations}
        if self.note:
            out["note"] = self.note
        out["misfit"] = self.misfit
        if self.warning:
            out["warning"] = self.warning
        if self.crossval:
            out["crossval"] = [c.to_json() for c in self.crossval]
        return out


def _check(robot: Robot, snapshots: Sequence[Snapshot], params: Sequence[str]):
    if not snapshots:
        raise SnapshotError("no snapshots")
    allowed = parameter_names(robot)
    bad = [p for p in params if p not in allowed]
    if bad or not params:
        raise SnapshotError(f"parameters to fit must be among {', '.join(allowed)}; got "
                            f"{', '.join(params) or 'none'}")
    for k, s in enumerate(snapshots, start=1):
        try:
            # a modulus being fitted bounds no tension (the robot's is a guess)
            inputs.tensions(robot, s.tensions,
                            math.inf if "young_modulus" in params else None)
            inputs.displacements(robot, s.displacements)
            inputs.sliding(robot, s.sliding, ("in", "out"))
        except ValueError as exc:
            raise SnapshotError(f"snapshot {k}: {exc}") from None
        if not s.markers and not s.displacements:
            raise SnapshotError(f"snapshot {k}: no measured markers and no tendon "
                                f"displacements")
        for m, p in s.markers.items():
            if m not in robot.marker_names:
                raise SnapshotError(f"snapshot {k}: no marker {m!r} in the robot")
            if error := inputs.marker_error(robot, m, p):
                raise SnapshotError(f"snapshot {k}: {error}")
        for n, v in s.displacements.items():
            if n not in robot.tendon_names:
                raise SnapshotError(f"snapshot {k}: no tendon {n!r} in the robot")
            if not np.isfinite(v):
                raise SnapshotError(f"snapshot {k}: displacement of {n!r} is not finite")
    tensioned = any(any(v != 0 for v in s.tensions.values()) for s in snapshots)
    if "friction" in params and not tensioned:
        raise SnapshotError("friction cannot be identified: no snapshot has a tendon under "
                            "tension")
    for p in params:
        name = p.partition("_")[2]
        if p.startswith("friction_") and not any(s.tensions.get(name, 0) for s in snapshots):
            raise SnapshotError(f"{p} cannot be identified: no snapshot has tendon {name!r} "
                                f"under tension")
    loaded = any(s.load is not None for s in snapshots)
    if {"young_modulus", "density"} <= set(params) and not (loaded or tensioned):
        raise SnapshotError("young_modulus and density cannot both be identified from "
                            "gravity-only snapshots (only density / young_modulus is "
                            "observable): add a known load or tendon tension")


def _observable(J: np.ndarray, params: Sequence[str], what: str):
    """Refuse parameters that the measurements cannot determine: a column of ``J`` (weighted
    residuals per log θ) that is zero, or columns that are proportional."""
    norms = np.linalg.norm(J, axis=0)
    dead = [p for p, n in zip(params, norms) if not n > 1e-12 * max(norms.max(), 1e-300)]
    if dead:
        raise SnapshotError(f"{', '.join(dead)} cannot be identified: it changes none of the "
                            f"measured {what} of these snapshots")
    if len(params) > 1:
        _, s, Vt = np.linalg.svd(J / norms, full_matrices=False)
        if s[-1] < 1e-7 * s[0]:
            tied = [p for p, v in zip(params, Vt[-1]) if abs(v) > 0.1]
            raise SnapshotError(f"{' and '.join(tied)} cannot be told apart by these "
                                f"snapshots: their effects on the measured {what} are "
                                f"proportional; add snapshots that load the rod differently "
                                f"(another tension, a known weight)")


@lru_cache(maxsize=CACHE_SIZE)
def _snapshot_fns(structure: Structure):
    """Compiled marker positions and tendon length changes, and their Jacobians with the
    equilibrium's (E_q, E_θ, p_q, y_q), θ the values :data:`PARAMETERS` by name."""
    unknowns = Unknowns.none(structure.n_tendons, 1)

    def equilibrium(q, theta, values, drive):
        values = values._replace(**theta)
        t = terms(structure, values, q, jnp.zeros(0), drive, unknowns, 1.0)
        return values.young_modulus * (values.stiffness() @ q) - t.load, t.y

    def measurements(q, values):
        return (marker_positions(structure, values, q),
                tendons.length_changes(structure, values, poses(values, q)[0], q))

    def jacobians(q, values, drive):
        theta = {k: getattr(values, k) for k in PARAMETERS}
        (Eq, Et), (Yq, _) = jax.jacfwd(equilibrium, argnums=(0, 1))(q, theta, values, drive)
        return Eq, Et, jax.jacfwd(lambda q: marker_positions(structure, values, q))(q), Yq

    return (Program(measurements, "measurements", structure),
            Program(jacobians, "identification_jacobians", structure))


@dataclass
class _Setup:
    """One robot's snapshots ready to fit: drives, measurements and their weights."""

    model: object
    params: tuple[str, ...]
    drives: list
    markers: list  # per snapshot: (indices, measured (n, 3))
    lengths: list  # per snapshot: (indices, measured (n,))
    signs: list  # per snapshot: every tendon's friction sign (n_t,), +1 in, −1 out
    weights: tuple[float, float]  # 1/σ markers, 1/σ lengths
    scale: np.ndarray  # θ at log ratio 0

    def values(self, log_ratio):
        """The model's values at ``θ = scale · exp(log_ratio)`` and θ by name."""
        with np.errstate(over="ignore"):  # (a trial step far out: inf, refused by the fit)
            theta = dict(zip(self.params, self.scale * np.exp(log_ratio)))
        names = self.model.robot.tendon_names
        mu = np.array(self.model.values.friction, float)
        if "friction" in theta:
            own = {p.partition("_")[2] for p in self.params if p.startswith("friction_")}
            mu[[j for j, n in enumerate(names) if n not in own]] = theta["friction"]
        for j, n in enumerate(names):
            mu[j] = theta.get(f"friction_{n}", mu[j])
        other = {k: v for k, v in theta.items() if k in ("young_modulus", "density")}
        return self.model.with_values(friction=mu, **other).values, theta

    def column(self, Et: dict, name: str, signs: np.ndarray) -> np.ndarray:
        """∂E/∂θ of one parameter (``friction``: the tendons without a μ of their own) at a
        snapshot whose tendons slide with ``signs`` (its friction is ``signs · μ``)."""
        if name in ("young_modulus", "density"):
            return np.asarray(Et[name])
        names = self.model.robot.tendon_names
        if name == "friction":
            own = {p.partition("_")[2] for p in self.params if p.startswith("friction_")}
            cols = [j for j, n in enumerate(names) if n not in own]
        else:
            cols = [names.index(name.partition("_")[2])]
        return np.asarray(Et["friction"])[:, cols] @ signs[cols]

    def evaluate(self, log_ratio, subset, q_start):
        """Per snapshot in ``subset``: (marker residual (n, 3), length residual (n,)), the
        weighted residual's Jacobian w.r.t. log θ and the shapes; None if an equilibrium
        fails."""
        structure = self.model.structure
        values, chosen = self.values(log_ratio)
        dtheta = np.array([chosen[n] for n in self.params])  # d/d log θ = θ d/dθ
        measure, jac_fn = _snapshot_fns(structure)
        unknowns = Unknowns.none(structure.n_tendons, 1)
        parts, jac, qs = [], [], {}
        wm, wl = self.weights
        for k in subset:
            d, signs = self.drives[k], self.signs[k]
            vk = values if np.all(signs == 1) else values._replace(
                friction=signs * np.asarray(values.friction))
            sol = solve_system(structure, vk, (), d, unknowns, q_start.get(k))
            if not bool(sol.converged):
                return None
            p, y = measure(sol.x, vk)
            (mi, mp), (li, ly) = self.markers[k], self.lengths[k]
            parts.append((np.asarray(p)[mi] - mp, np.asarray(y)[li] - ly))
            Eq, Et, Pq, Yq = jac_fn(sol.x, vk, d)
            dE = np.stack([self.column(Et, n, signs) for n in self.params], axis=1) * dtheta
            dq = -np.linalg.solve(np.asarray(Eq), dE)
            jac += [wm * (np.asarray(Pq)[mi] @ dq).reshape(-1, len(self.params)),
                    wl * np.asarray(Yq)[li] @ dq]
            qs[k] = sol.x
        return parts, np.concatenate(jac), qs

    def residual(self, parts) -> np.ndarray:
        wm, wl = self.weights
        return np.concatenate([np.concatenate([wm * m.ravel(), wl * y]) for m, y in parts])

    def fit(self, theta, subset, qs, max_iterations, progress=None):
        """Levenberg–Marquardt from ``theta`` (log ratios): (θ, parts, J, qs, converged,
        iterations, why not converged)."""
        first = self.evaluate(theta, subset, qs)
        if first is None:
            raise SnapshotError("a snapshot's equilibrium did not converge with the starting "
                                "parameters")
        parts, J, qs = first
        r = self.residual(parts)
        damping, converged, it, gn = 1e-3, False, 0, np.inf
        note = f"the iteration limit ({max_iterations}) reached"
        for it in range(1, max_iterations + 1):
            g, H = J.T @ r, J.T @ J
            # the undamped Gauss–Newton step, relative change of θ: converged below 1e-6, or
            # below 1e-5 once no step lowers the cost (the equilibrium solves' resolution)
            gn = np.linalg.norm(np.linalg.lstsq(H, -g, rcond=None)[0])
            if gn <= 1e-6:
                converged = True
                break
            improved = False
            while damping < 1e10:
                step = np.linalg.solve(H + damping * np.diag(np.diag(H) + 1e-12), -g)
                trial = self.evaluate(theta + step, subset, qs)
                if trial is not None and _sq(self.residual(trial[0])) < r @ r:
                    theta, (parts, J, qs) = theta + step, trial
                    r = self.residual(parts)
                    damping, improved = max(damping / 5, 1e-10), True
                    break
                damping *= 5
            if progress is not None:
                progress(it, max_iterations)
            if not improved:
                converged = gn <= 1e-5
                note = "no Levenberg–Marquardt step lowers the misfit"
                break
        if converged:
            note = ""
        elif np.isfinite(gn):
            note += f" with a Gauss–Newton step of {gn:.1e} in log θ (converged below 1e-6)"
        return theta, parts, J, qs, bool(converged), it, note


def _sq(r):
    return float(r @ r)


def _check_noises(robot: Robot, marker_noise: float, length_noise: float) -> None:
    """The read-out noises a fit weighs its residuals by: positive metres, a length noise a
    sensor of the robot's tendons can have and a marker noise one of its markers can have
    (:func:`~tendonsense.inputs.length_noise_error`,
    :func:`~tendonsense.inputs.marker_noise_error`)."""
    for noise, what in ((marker_noise, "marker noise"), (length_noise, "length noise")):
        if not (np.isfinite(noise) and noise > 0):
            raise ValueError(f"{what} must be a positive number of metres, got {noise}")
    if error := inputs.length_noise_error(robot, "length noise", length_noise):
        raise ValueError(error)
    if error := inputs.marker_noise_error(robot, "marker noise", marker_noise):
        raise ValueError(error)


def _setup(robot: Robot, snapshots: Sequence[Snapshot], params, marker_noise, length_noise):
    _check_noises(robot, marker_noise, length_noise)
    model = model_for(robot)
    base = model.values
    gravity = np.asarray(robot.gravity, float)
    drives, markers, lengths = [], [], []
    for s in snapshots:
        T = np.array([s.tensions.get(n, 0.0) for n in robot.tendon_names], float)
        X, F = (s.load[0], s.load[1]) if s.load is not None else (robot.rod.length, (0, 0, 0))
        drives.append(Drive(T, np.asarray([F], float), np.asarray([X], float), gravity,
                            np.zeros(0)))
        markers.append(([robot.marker_names.index(m) for m in s.markers],
                        np.array([s.markers[m] for m in s.markers]).reshape(-1, 3)))
        lengths.append(([robot.tendon_names.index(n) for n in s.displacements],
                        np.array(list(s.displacements.values()), float)))
    mu = np.asarray(base.friction, float)
    start = {"young_modulus": float(base.young_modulus), "density": float(base.density),
             "friction": max(float(mu.mean()) if mu.size else 0.0, 0.05),
             **{f"friction_{n}": max(float(mu[j]), 0.05)
                for j, n in enumerate(robot.tendon_names)}}
    signs = [inputs.friction_signs(robot, s.sliding) for s in snapshots]
    return _Setup(model, tuple(params), drives, markers, lengths, signs,
                  (1.0 / marker_noise, 1.0 / length_noise),
                  np.array([start[p] for p in params]))


def _what(snapshots) -> str:
    kinds = [w for w, has in (("marker positions", any(s.markers for s in snapshots)),
                              ("tendon lengths", any(s.displacements for s in snapshots)))
             if has]
    return " and ".join(kinds)


#: a parameter fitted below this share of its starting value ran to zero, the edge of its
#: range (the data push it below): it is not determined, and has no ±
RAN_TO_ZERO = 1e-6
#: a fit whose χ² is above this quantile of the χ² distribution of its degrees of freedom
#: is said not to explain the data (and one below 1 − it, to have less noise than assumed)
MISFIT_QUANTILE = 0.999


def misfit_of(kinds: dict[str, tuple[np.ndarray, float]], n_params: int
              ) -> tuple[float | None, str]:
    """The RMS of the residuals in units of their noise over their degrees of freedom (about 1
    where the model explains the data and the noise is as assumed; None without a degree of
    freedom), ``kinds`` {kind: (residuals, noise)} (m), and a warning where their χ² is above
    the :data:`MISFIT_QUANTILE` quantile of its distribution (the 1-σ values assume the noise
    alone), or one kind's below the 1 − :data:`MISFIT_QUANTILE` one (its noise assumed is too
    large: the ± values too wide)."""
    from scipy.stats import chi2 as distribution
    chi2 = {k: (float(np.sum((np.asarray(r) / s) ** 2)), np.size(r))
            for k, (r, s) in kinds.items()}
    n = sum(m for _, m in chi2.values())
    dof = n - n_params
    if dof < 1:
        return None, ""
    total = sum(c for c, _ in chi2.values())
    ratio = float(np.sqrt(total / dof))
    small, overstated = [], []  # every kind whose noise assumed is too large, its name
    share = {k: m - n_params * m / n for k, (_, m) in chi2.items()}  # its degrees of freedom
    for k, (c, m) in chi2.items():
        dof_k = share[k]
        low = distribution.ppf(1 - MISFIT_QUANTILE, dof_k) if dof_k >= 1 else 0.0
        if c < low:
            was, least = apart(np.sqrt(c / dof_k), np.sqrt(low / dof_k))
            small.append(f"the {k} residuals are {was} times the {k} noise assumed "
                         f"({kinds[k][1]:g} m), where such noise gives at least {least} "
                         f"times over {m} of them")
            overstated.append(k)
    said = [f"{'; '.join(small)}: the {' and '.join(overstated)} noise is smaller than "
            f"assumed, and the ± values, which assume it, are too wide"] if small else []
    high = distribution.ppf(MISFIT_QUANTILE, dof)
    if total > high:  # (said as well: one kind's small noise must not hide a fit that misses
        # the rest; each kind named over its share of the degrees of freedom, as above, so
        # that the two do not read as one noise)
        seen = {k: (c, max(share[k], 1.0)) for k, (c, m) in chi2.items() if m}
        each = "" if len(seen) < 2 else " (" + ", ".join(
            f"the {k} ones {np.sqrt(c / d):.2g}" for k, (c, d) in seen.items()) + " times theirs)"
        above = [k for k, (c, d) in seen.items() if c > d] or list(seen)
        was, most = apart(ratio, np.sqrt(high / dof))
        said.append(f"the residuals are {was} times the noise assumed{each}, where noise "
                    f"explains at most {most} times over {n} of them: the "
                    f"model does not fit the data (a parameter not fitted, a load not given, a "
                    f"unit) or the {' and '.join(above)} noise is larger than assumed (as "
                    f"given); the ± values assume that noise alone")
    return ratio, "; and ".join(said)


def _fit_again_off_the_edge(fit, setup, subset, max_iterations):
    """``fit`` (:meth:`_Setup.fit`'s tuple), or a better one: where a parameter ran to 0
    (:data:`RAN_TO_ZERO`), the fit again from the others' fitted values and that one's start
    (a start far off can slide down a valley to the edge: E 3× the truth drove μ to 0, E and
    ρ 16 % off); the fit of the lower misfit is kept, the iterations of both counted."""
    theta = fit[0]
    edge = theta < np.log(RAN_TO_ZERO)
    if not edge.any():
        return fit
    try:
        again = setup.fit(np.where(edge, 0.0, theta), subset, fit[3], max_iterations)
    except SnapshotError:  # an equilibrium that fails from there: the first fit stands
        return fit
    better = _sq(setup.residual(again[1])) < _sq(setup.residual(fit[1]))
    return (*(again if better else fit)[:5], fit[5] + again[5], (again if better else fit)[6])


def _errors(parts):
    """RMS marker distance and RMS length residual over ``parts`` (None where empty)."""
    m = np.concatenate([p for p, _ in parts]) if parts else np.zeros((0, 3))
    y = np.concatenate([y for _, y in parts]) if parts else np.zeros(0)
    return (float(np.sqrt(np.mean(np.sum(m**2, axis=1)))) if len(m) else None,
            float(np.sqrt(np.mean(y**2))) if len(y) else None)


def identify(robot: Robot, snapshots: Sequence[Snapshot],
             params: Sequence[str] = inputs.DEFAULT_PARAMETERS, max_iterations: int = 50,
             progress: Callable[[int, int], None] | None = None, *,
             marker_noise: float = MARKER_NOISE, length_noise: float = LENGTH_NOISE,
             crossval: bool = False) -> Identified:
    """Fit ``params`` (among young_modulus, density, friction — one μ for every tendon — and
    friction_<tendon>) to the snapshots' markers and/or tendon length changes, starting from
    the robot file's values; each kind of measurement weighted by its noise (1 σ, m), which
    also gives each parameter's 1-σ uncertainty (``sigma``). A snapshot's ``sliding``
    {tendon: in|out} is the direction the tendon was moving when it was taken (pulled in or
    paid out); snapshots of both, under a known load, tell μ apart from E.

    With ``crossval``, also refit without each snapshot in turn and predict it
    (:class:`LeftOut`): whether the calibration generalises beyond the poses it saw."""
    if isinstance(params, str):
        raise SnapshotError(f"parameters to fit: a list such as ({params!r},), not a string")
    params = tuple(dict.fromkeys(params))
    _check(robot, snapshots, params)
    setup = _setup(robot, snapshots, params, marker_noise, length_noise)
    everything = range(len(snapshots))
    first = setup.evaluate(np.zeros(len(params)), everything, {})
    if first is None:
        raise SnapshotError("a snapshot's equilibrium did not converge with the robot file's "
                            "parameters")
    _observable(first[1], params, _what(snapshots))
    initial = _errors(first[0])
    theta, parts, J, qs, converged, it, note = _fit_again_off_the_edge(setup.fit(
        np.zeros(len(params)), everything, first[2], max_iterations, progress), setup,
        everything, max_iterations)
    _, fitted = setup.values(theta)
    fitted = {k: float(v) for k, v in fitted.items()}
    # (JᵀJ)⁻¹ of the noise-weighted residuals: the covariance of log θ (eq. 19 linearised)
    with np.errstate(invalid="ignore"):  # (a parameter at its edge: no ±, said below)
        log_sigma = np.sqrt(np.diag(np.linalg.pinv(J.T @ J)))
    sigma = {k: float(v * ls) for (k, v), ls in zip(fitted.items(), log_sigma)}
    per_snapshot = tuple(_errors([p]) for p in parts)
    folds = _cross_validate(setup, snapshots, theta, qs, per_snapshot, max_iterations,
                            progress) if crossval else ()
    mu = {p.partition("_")[2]: v for p, v in fitted.items() if p.startswith("friction_")}
    shared = {n: fitted["friction"] for n in robot.tendon_names
              if "friction" in fitted and n not in mu}
    try:
        new_robot = robot.with_parameters(young_modulus=fitted.get("young_modulus"),
                                          density=fitted.get("density"),
                                          friction={**shared, **mu} or None)
    except ValueError as exc:  # no robot has such a value: the data are not what was assumed
        raise SnapshotError(f"the fit ran to a value no robot has, {exc}: check the snapshots' "
                            f"units (N, m) and loads") from None
    ratio, warning = misfit_of(
        {"marker": (np.concatenate([m.ravel() for m, _ in parts]), marker_noise),
         "length": (np.concatenate([y for _, y in parts]), length_noise)}, len(params))
    if zero := [k for k, r in zip(params, theta) if r < np.log(RAN_TO_ZERO)]:
        sigma.update(dict.fromkeys(zero))
        warning = joined(
            f"{' and '.join(zero)} ran to 0, the edge of {'its' if len(zero) == 1 else 'their'}"
            f" range (these data push {'it' if len(zero) == 1 else 'them'} below): not "
            f"determined, no ± given", warning)
    return Identified(fitted, *_errors(parts), *initial, converged, it, new_robot, folds,
                      per_snapshot, sigma, note, ratio, warning, (marker_noise, length_noise))


def _cross_validate(setup: _Setup, snapshots, theta, qs, fitted_errors, max_iterations,
                    progress) -> tuple[LeftOut, ...]:
    """Refit without each snapshot (from the full fit) and predict the one left out."""
    n = len(snapshots)
    if n < 2:
        raise SnapshotError("cross-validation needs at least 2 snapshots")
    out = []
    for k in range(n):
        rest = [i for i in range(n) if i != k]
        fitted = _Fold(None, None, None, False, "")
        try:
            _check(setup.model.robot, [snapshots[i] for i in rest], setup.params)
            t, _, J, _, ok, _, _ = setup.fit(theta, rest, dict(qs), max_iterations)
            _observable(J, setup.params, _what([snapshots[i] for i in rest]))
            predicted = setup.evaluate(t, [k], qs)
            if predicted is None:
                fitted = _Fold(t, None, None, False, "its equilibrium did not converge")
            else:
                fitted = _Fold(t, *_errors(predicted[0]), ok, "")
        except SnapshotError as exc:
            fitted = _Fold(None, None, None, False, f"the rest cannot: {exc}")
        params = None if fitted.theta is None else {
            p: float(v) for p, v in setup.values(fitted.theta)[1].items()}
        out.append(LeftOut(k + 1, params, fitted.marker, fitted.displacement,
                           *fitted_errors[k], fitted.converged, fitted.note))
        if progress is not None:
            progress(k + 1, n)
    return tuple(out)


class _Fold(NamedTuple):
    theta: np.ndarray | None
    marker: float | None
    displacement: float | None
    converged: bool
    note: str


#: the range of relaxation times τ = 3η/E searched for the damping, s (the upper end: ten
#: times the log's duration), and the points of the first, coarse search
TAU_MIN, TAU_POINTS = 1e-4, 13


#: a log's first row further than this many noise σ from the rest shape of its tensions is
#: not at rest (a damping fit simulates from rest there)
AT_REST = 5.0


def _moving_at_start(start, row, measured, markers, length_noise, marker_noise) -> str:
    """Why a log's first ``row`` is not at rest: its lengths or markers further than
    :data:`AT_REST` σ from ``start``, the static shape of its tensions ('' if not)."""
    dy = max((abs(start.displacements[n] - row.displacements[n]) for n in measured),
             default=0.0)
    dp = max((float(np.linalg.norm(start.markers[m] - np.asarray(row.markers[m])))
              for m in markers if m in row.markers), default=0.0)
    if max(dy / length_noise, dp / marker_noise) <= AT_REST:
        return ""
    off = [f"{what} {d * 1e3:.2g} mm ({d / noise:.0f} σ)" for what, d, noise in (
        ("a tendon length", dy, length_noise), ("a marker", dp, marker_noise)) if d > 0]
    return (f"the log does not start at rest: its first row is {' and '.join(off)} from the "
            f"static shape of its tensions, where the motion is simulated from; start the log "
            f"before the robot moves (or drop its first rows until it is still)")


def inertia_left_out(dy, dp, length_noise: float, marker_noise: float,
                     bounded: bool = True) -> str:
    """A warning where the rod's inertia, left out of a damping fit, moves the fitted
    motion's readings (its length changes by ``dy`` (m), its markers by ``dp`` (…, 3), m) by
    more than their noise resolves, or ''. With ``D`` = Δχ² of that move against the noise,
    the fitted log η can be off by up to √D of its 1-σ (Cauchy–Schwarz: the move's part along
    the damping's own effect on the readings, which χ² rising by 1 scales), so D > 1 is said
    (``bounded``: the fit has a ±)."""
    D = float(np.sum((dy / length_noise) ** 2) + np.sum((dp / marker_noise) ** 2))
    if not D > 1:
        return ""
    moved = [f"{1e3 * np.sqrt(np.mean(a2)):.3g} mm RMS ({what})" for a2, what in (
        (dy ** 2, "lengths"), (np.sum(dp ** 2, -1), "markers")) if a2.size]
    off = (f"by up to {np.sqrt(D):.2g} times its ±" if bounded
           else "by more than the noise resolves")
    return (f"without inertia (--no-inertia, inertia=False): the rod's inertia moves the fitted "
            f"motion's readings by {' and '.join(moved)}, a χ² of {D:.3g} against the noise "
            f"assumed: this motion is not slow enough to leave it out, and the damping may be "
            f"off {off} (fit with inertia)")


def identify_damping(robot: Robot, samples: Sequence, point_forces=(), *,
                     inertia: bool = True, marker_noise: float = MARKER_NOISE,
                     length_noise: float = LENGTH_NOISE,
                     progress: Callable[[int, int], None] | None = None) -> Identified:
    """Fit the Kelvin–Voigt damping η (``[rod] damping``, Pa·s) to a readings log with time
    stamps (:class:`~tendonsense.readings.Sample`, e.g. a step or a ramp of the tensions under
    the known ``point_forces``): the motion is simulated from rest at the first row with the
    log's tensions (linear between rows), and its tendon length changes and markers are fitted
    to the measured ones, each weighted by its noise. Each tendon's friction follows its
    tension history (:func:`~tendonsense.simulation.simulate`'s ``follow``), or slides the one
    way its ``sliding_<tendon>`` column says (``in`` or ``out`` in every row that says one).

    One parameter: a coarse search over τ = 3η/E from ``TAU_MIN`` (0.1 ms) to ten times the
    log's duration, then Brent's method in log η between the best point's neighbours. Its
    1-σ uncertainty is where χ² has risen by 1 on either side (half the interval; the profile
    of the likelihood, no derivative needed). Rows skipped by the reader are left out. The
    warning says also where the fitted damping's relaxation time is too short for the
    simulation's step (:func:`~tendonsense.inputs.coarse_step`), and, without ``inertia``,
    where the rod's inertia would move the fitted motion's readings by more than their noise
    resolves (:func:`inertia_left_out`; one more simulation, with inertia)."""
    rows = [s for s in samples if not s.error]
    if len(rows) < 3:
        raise SnapshotError(f"damping needs a log of at least 3 good rows (got {len(rows)})")
    t = np.array([np.nan if s.time is None else s.time for s in rows], float)
    if not np.all(np.isfinite(t)):
        raise SnapshotError("damping needs a time stamp (s) in every row: the log has no time "
                            "column or an empty cell")
    if error := motion_step_error("the log", rows, static=""):
        raise SnapshotError(error)
    _check_noises(robot, marker_noise, length_noise)
    names = robot.tendon_names
    measured = [n for n in names if n in rows[0].displacements]
    # (a row may lack a marker the camera missed: no residual there)
    markers = [m for m in robot.marker_names if any(m in s.markers for s in rows)]
    if not measured and not markers:
        raise SnapshotError("the log has no displacement_<tendon> or marker columns: nothing "
                            "to fit the damping to")
    sliding = {}
    for n in names:
        said = sorted({s.sliding[n] for s in rows if n in s.sliding})
        if len(said) > 1 or "stuck" in said:
            raise SnapshotError(f"column sliding_{n} says {' and '.join(said)}: the damping "
                                f"fit takes one direction per tendon (in or out) for the "
                                f"whole log, or follows its tension history where the column "
                                f"is empty in every row")
        if said:
            sliding[n] = said[0]
    t = t - t[0]
    schedule = {n: (t, np.array([s.tensions[n] for s in rows])) for n in names}
    y_meas = np.array([[s.displacements[n] for n in measured] for s in rows])
    p_meas = np.array([[s.markers.get(m, np.full(3, np.nan)) for m in markers] for s in rows]
                      ).reshape(len(rows), -1, 3)
    seen = np.isfinite(p_meas[..., 0])
    start = solve(robot, rows[0].tensions, point_forces, sliding=sliding)
    if not start.converged:
        raise SnapshotError(f"the first row's static equilibrium (the motion's start) did not "
                            f"converge: {start.note}")
    moving = _moving_at_start(start, rows[0], measured, markers, length_noise, marker_noise)
    E = robot.rod.young_modulus
    evaluations = [0]

    def misfit(log_eta):
        """(χ², marker residuals, length residuals) of the motion with η = exp(log_eta)."""
        with warnings.catch_warnings():  # a coarse step: said of the fitted damping alone
            warnings.simplefilter("ignore")
            sim = simulate(robot.with_parameters(damping=float(np.exp(log_eta))), schedule,
                           point_forces, duration=t[-1], inertia=inertia, q0=start.q, at=t[1:],
                           sliding=sliding)
        evaluations[0] += 1
        if not sim.ok:
            return np.inf, None, None
        dy = np.stack([sim.displacements[n] for n in measured], 1) - y_meas if measured \
            else np.zeros((len(t), 0))
        dp = np.where(seen[..., None], np.stack([sim.markers[m] for m in markers], 1)
                      - np.nan_to_num(p_meas), 0.0) if markers else np.zeros((len(t), 0, 3))
        chi2 = float(np.sum((dy / length_noise) ** 2) + np.sum((dp / marker_noise) ** 2))
        return chi2, dp, dy

    grid = np.log(np.geomspace(TAU_MIN, 10 * t[-1], TAU_POINTS) * E / 3)
    chi2 = []
    for k, g in enumerate(grid):
        chi2.append(misfit(g)[0])
        if progress is not None:
            progress(k + 1, TAU_POINTS + 20)
    chi2 = np.array(chi2)
    if not np.any(np.isfinite(chi2)):
        raise SnapshotError("the simulated motion did not converge at any damping")
    best = int(np.nanargmin(np.where(np.isfinite(chi2), chi2, np.nan)))
    finite = chi2[np.isfinite(chi2)]
    if finite.max() - finite.min() < 1:
        raise SnapshotError("damping cannot be identified from this log: over τ = "
                            f"{TAU_MIN:g} s … {10 * t[-1]:g} s it changes the predicted readings "
                            "by less than their noise (does the log have motion?)")
    lo, hi = grid[max(best - 1, 0)], grid[min(best + 1, grid.size - 1)]
    found = minimize_scalar(lambda g: misfit(g)[0], bounds=(lo, hi), method="bounded",
                            options={"xatol": 1e-4})
    x, chi2_min = float(found.x), float(found.fun)
    edge = best in (0, grid.size - 1)

    def crossing(direction):
        """log η where χ² has risen by 1 on one side (±inf if it never does in the range)."""
        inner = x
        for g in (grid[grid > x] if direction > 0 else grid[grid < x][::-1]):
            if misfit(g)[0] - chi2_min > 1:
                return brentq(lambda v: misfit(v)[0] - chi2_min - 1, *sorted((inner, g)),
                              xtol=1e-3)
            inner = g
        return direction * np.inf

    eta = float(np.exp(x))
    lo_eta, hi_eta = np.exp(crossing(-1)), np.exp(crossing(+1))
    sigma = float(0.5 * (hi_eta - lo_eta)) if np.isfinite(hi_eta) else None
    _, dp, dy = misfit(x)
    initial = misfit(np.log(robot.rod.damping))[1:] if robot.rod.damping > 0 else (None, None)
    if progress is not None:
        progress(TAU_POINTS + 20, TAU_POINTS + 20)

    def errors(dp, dy):
        if dp is None:
            return None, None
        return (float(np.sqrt(np.mean(np.sum(dp ** 2, -1)[seen]))) if markers else None,
                float(np.sqrt(np.mean(dy ** 2))) if measured else None)

    note = (f"the best damping lies at the end of the range searched (τ = {TAU_MIN:g} s … "
            f"{10 * t[-1]:g} s): the log does not pin it down" if edge else
            "" if sigma is not None else "the log bounds the damping from below only (χ² "
            "rises by less than 1 up to the end of the range searched)")
    ratio, warning = misfit_of({"marker": (dp[seen], marker_noise), "length": (dy, length_noise)},
                               1) if dp is not None else (None, "")
    fitted = robot.with_parameters(damping=eta)
    coarse = inputs.coarse_step(fitted, MAX_STEP)
    left_out = ""
    if not inertia and dp is not None:  # what leaving the rod's inertia out did to the fit
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            sim = simulate(fitted, schedule, point_forces, duration=t[-1], inertia=True,
                           q0=start.q, at=t[1:], sliding=sliding)
        if sim.ok:
            left_out = inertia_left_out(
                np.stack([sim.displacements[n] for n in measured], 1) - y_meas - dy
                if measured else dy,
                np.where(seen[..., None], np.stack([sim.markers[m] for m in markers], 1)
                         - np.nan_to_num(p_meas) - dp, 0.0)[seen] if markers else dp[seen],
                length_noise, marker_noise, sigma is not None)
        else:
            left_out = ("without inertia (--no-inertia, inertia=False): the fitted motion "
                        "simulated with the rod's inertia did not converge, so whether leaving "
                        "it out matters is not known")
    warning = joined(moving, warning, coarse and f"at the fitted damping {coarse}", left_out)
    return Identified({"damping": eta}, *errors(dp, dy), *errors(*initial),
                      bool(found.success) and not edge, evaluations[0],
                      fitted, sigma={"damping": sigma}, note=note,
                      misfit=ratio, warning=warning, noise=(marker_noise, length_noise))
