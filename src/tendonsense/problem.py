"""The estimation problem (eq. 17): what is measured, what is unknown, how readings become
vectors (by the rules of :mod:`tendonsense.inputs`), the known drive, how the measurements
depend on the unknowns, and the 1-σ band of sensor noise. Below every solver of it
(:mod:`~tendonsense.estimation`, :mod:`~tendonsense.fastpath`, :mod:`~tendonsense.online`,
:mod:`~tendonsense.tracking`)."""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property, lru_cache
from typing import Mapping, Sequence

import jax
import numpy as np

from . import inputs
from .compiled import Program
from .forward import model_for
from .inputs import GravityUnknown, Noise, PointForceUnknown, Unknown, check_point_forces
from .model import Model, Structure, Values
from .robot import Robot, check_robot
from .stability import unstable
from .statics import CACHE_SIZE, Drive, Unknowns, terms


@dataclass(frozen=True, eq=False)
class Problem:
    """An estimation problem's fixed structure: the model, measured tendons, how the
    unknowns enter and the known drive (without the measurements)."""

    robot: Robot
    model: Model
    measured: tuple[int, ...]
    unknowns: Unknowns
    known_forces: np.ndarray  # (n_p, 3), zero where an unknown force acts
    load_X: np.ndarray  # (n_p,) known forces, then the unknown ones
    gravity: np.ndarray
    #: for every located unknown: (index of its load in load_X, (A, B) range of X)
    located: tuple[tuple[int, tuple[float, float]], ...] = ()

    @property
    def n_z(self) -> int:
        """Extra unknowns of the solver: the magnitudes, then the located forces' X."""
        return self.unknowns.gravity.shape[0]

    @property
    def n_magnitudes(self) -> int:
        return self.n_z - len(self.located)

    def fixed(self) -> "Problem":
        """The problem with every located force held at the X of ``load_X`` (set it first
        with :meth:`at`)."""
        n = self.n_magnitudes
        u = self.unknowns
        return replace(self, unknowns=Unknowns(u.tensions[:, :n], u.forces[:n], u.gravity[:n],
                                               u.positions[:0]), located=())

    def at(self, X) -> "Problem":
        """The problem with the located forces' reference X set to ``X`` (one per located)."""
        load_X = self.load_X.copy()
        for (i, _), x in zip(self.located, np.atleast_1d(X)):
            load_X[i] = x
        return replace(self, load_X=load_X)

    def locations(self, x) -> np.ndarray:
        """The located forces' X at the solution ``x = [q; magnitudes; X offsets]``."""
        offsets = np.asarray(x)[len(x) - len(self.located):] if self.located else []
        return np.array([self.load_X[i] + o for (i, _), o in zip(self.located, offsets)])

    @cached_property
    def rest_lengths(self) -> np.ndarray:
        """Every tendon's path length on the straight rod (l* of eq. 9), m."""
        return inputs.rest_lengths(self.robot)

    def readings(self, displacements: Mapping[str, float], tensions: Mapping[str, float],
                 young_modulus: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(T, y)`` per tendon of one reading, by the rules of :mod:`tendonsense.inputs`
        (``young_modulus``: the sample's own, where it is not the robot file's); every
        measured tendon needs its length change and its tension."""
        return inputs.readings(self.robot, displacements, tensions, self.rest_lengths,
                               young_modulus, self.measured_names)

    def many_readings(self, displacements: Sequence[Mapping[str, float]],
                      tensions: Sequence[Mapping[str, float]], young_modulus=None
                      ) -> tuple[np.ndarray, np.ndarray, dict[int, str]]:
        """:meth:`readings` of n readings at once (:func:`tendonsense.inputs.many_readings`:
        the rules on arrays, a series' cost): ``(T, y)`` (n, n_t) and the reason every bad one
        breaks a rule, by index."""
        return inputs.many_readings(self.robot, displacements, tensions, self.rest_lengths,
                                    young_modulus, self.measured_names)

    @cached_property
    def measured_names(self) -> tuple[str, ...]:
        """The measured tendons' names."""
        return tuple(self.robot.tendon_names[j] for j in self.measured)

    @cached_property
    def _estimated_forces(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The loads the magnitudes act at: their indices in ``load_X``, each magnitude's unit
        force there (n_magnitudes, n × 3) and :func:`~tendonsense.inputs.max_force` per unit E
        at their X (for known X)."""
        n = self.n_magnitudes
        unit = np.asarray(self.unknowns.forces, float)[:n]
        points = np.flatnonzero(np.any(unit != 0, axis=(0, 2)))
        tops = np.array([inputs.max_force(self.robot, X, 1.0) for X in self.load_X[points]])
        return points, unit[:, points].reshape(n, -1), tops

    def overloaded(self, x, young_modulus=None) -> list[str | None]:
        """For solutions ``x`` (N, nq + n_z), why each is no load the model holds, or None: a
        force estimated above :func:`~tendonsense.inputs.max_force` at its X, the bound a
        known force is held to (half the rod's axial stiffness E·A where it is thinnest);
        ``young_modulus`` the rod's (a scalar or one per solution) where it is not the robot
        file's."""
        n, nq = self.n_magnitudes, self.model.nq
        points, unit, tops = self._estimated_forces
        if not points.size:  # (gravity alone)
            return [None] * len(np.atleast_2d(x))
        if young_modulus is None and not self.located and np.ndim(x) == 1:  # (a live sample)
            F = (x[nq:nq + n] @ unit).reshape(-1, 3)
            if ((F * F).sum(axis=1) <= (self.robot.rod.young_modulus * tops) ** 2).all():
                return [None]
        x = np.atleast_2d(np.asarray(x, float))
        out: list[str | None] = [None] * len(x)
        with np.errstate(all="ignore"):  # (rows that did not converge: NaN or huge)
            F = x[:, nq:nq + n] @ unit
            size = np.sqrt(np.sum(F.reshape(len(x), -1, 3) ** 2, axis=2))  # (N, loads)
        E = np.reshape(self.robot.rod.young_modulus if young_modulus is None
                       else np.asarray(young_modulus, float), (-1, 1))
        X = self.load_X[points][None]
        if self.located:  # the bound where each force was found
            where = {i: j for j, (i, _) in enumerate(self.located)}
            X = np.clip(np.stack([self.load_X[p] + x[:, nq + n + where[p]] if p in where
                                  else np.full(len(x), self.load_X[p]) for p in points], 1),
                        0.0, self.robot.rod.length)
            tops = np.array([[inputs.max_force(self.robot, X_, 1.0) for X_ in row]
                             for row in X])
        over = size > E * tops
        if not over.any():
            return out
        top, X = np.broadcast_to(E * tops, size.shape), np.broadcast_to(X, size.shape)
        for k, col in zip(*np.nonzero(over)):
            if out[k] is None:
                out[k] = (f"the estimated force of {size[k, col]:.4g} N at X = {X[k, col]:.4g} m "
                          f"is more than half the rod's axial stiffness where it is thinnest "
                          f"(E·A = {top[k, col] / inputs.MAX_COMPRESSION:.3g} N): no load "
                          f"the model holds explains these readings (is the force's X or "
                          f"direction right?)")
        return out

    def drive(self, tensions, targets) -> Drive:
        return Drive(np.asarray(tensions, float), self.known_forces, self.load_X, self.gravity,
                     np.asarray(targets, float))


def problem(robot: Robot, measured: Sequence[str], unknowns: Sequence[Unknown],
            point_forces=()) -> Problem:
    """Set up the estimation of ``unknowns`` from the tendons named in ``measured``."""
    inputs.check_unknowns(check_robot(robot), measured, unknowns)
    n_p = len(unknowns)
    n_loc = sum(isinstance(u, PointForceUnknown) and u.located for u in unknowns)
    X_known, F_known = check_point_forces(robot, point_forces)
    forces = [u for u in unknowns if isinstance(u, PointForceUnknown)]
    L = robot.rod.length
    ranges = []
    for u in forces:
        ranges.append((0.0, L) if u.X is None else (u.X if u.located else (u.X, u.X)))
    n_known = len(X_known)
    Fz = np.zeros((n_p + n_loc, n_known + len(forces), 3))
    az = np.zeros((n_p + n_loc, 3))
    Pz = np.zeros((n_loc, n_known + len(forces)))
    gravity = np.array(robot.gravity, float)
    k, located = 0, []
    for i, u in enumerate(unknowns):
        if isinstance(u, GravityUnknown):
            az[i] = gravity
            gravity = np.zeros(3)
        else:
            Fz[i, n_known + k] = u.direction
            if u.located:  # z_{n_p + j} moves the force from its reference X
                Pz[len(located), n_known + k] = 1.0
                located.append((n_known + k, ranges[k]))
            k += 1
    F = np.concatenate([F_known, np.zeros((len(forces), 3))])
    X = np.concatenate([X_known, [0.5 * (a + b) for a, b in ranges]])
    unk = Unknowns(np.zeros((len(robot.tendons), n_p + n_loc)), Fz, az, Pz)
    idx = tuple(robot.tendon_names.index(n) for n in measured)
    return Problem(robot, model_for(robot), idx, unk, F, X, gravity, tuple(located))


@lru_cache(maxsize=CACHE_SIZE)
def _jacobians_fn(structure: Structure, measured: tuple[int, ...]):
    """``(∂E/∂q, ∂E/∂z, ∂E/∂T, ∂y_meas/∂q)`` for the unscaled equilibrium ``E = Kq − BT − F``."""

    def parts(q, z, T, drive, unknowns, values):
        t = terms(structure, values, q, z, drive._replace(tensions=T), unknowns, 1.0)
        E = values.young_modulus * (values.stiffness() @ q) - t.load
        return E, t.y[np.array(measured, int)]

    def jac(q, z, T, drive, unknowns, values):
        (Eq, Ez, ET), (yq, _, _) = jax.jacfwd(parts, argnums=(0, 1, 2))(q, z, T, drive, unknowns,
                                                                     values)
        return Eq, Ez, ET, yq

    return Program(jac, "jacobians", (structure, measured))


def jacobians(prob: Problem, x, drive, values: Values) -> tuple[np.ndarray, ...]:
    """``(∂E/∂q, ∂E/∂z, ∂E/∂T, ∂y_meas/∂q)`` at ``x`` (one call of the compiled program)."""
    return tuple(np.asarray(a) for a in _jacobians_fn(prob.model.structure, prob.measured)(
        *_jacobians_args(prob, x, drive, values)))


def preload_jacobians(prob: Problem, drive, values: Values) -> None:
    """:func:`jacobians`' program loaded from disk on another thread, ahead of its first call
    (:meth:`~tendonsense.compiled.Program.preload`)."""
    _jacobians_fn(prob.model.structure, prob.measured).preload(
        *_jacobians_args(prob, np.zeros(prob.model.nq + prob.n_z), drive, values))


def _jacobians_args(prob: Problem, x, drive, values: Values) -> tuple:
    nq, x = prob.model.nq, np.asarray(x, float)
    return x[:nq], x[nq:], drive.tensions, drive, prob.unknowns, values


def reduced_jacobians(prob: Problem, x, drive, values: Values, parts=None):
    """Reduced Jacobians of the measured lengths w.r.t. the magnitudes and the tensions, with
    the equilibrium eliminated: ``dy/dz = −y_q E_q⁻¹ E_z``, ``dy/dT = −y_q E_q⁻¹ E_T``
    (``parts``: :func:`jacobians` at ``x`` if known)."""
    Eq, Ez, ET, yq = jacobians(prob, x, drive, values) if parts is None else parts
    sol = np.linalg.solve(Eq, np.concatenate([Ez, ET], axis=1))
    return -yq @ sol[:, :prob.n_z], -yq @ sol[:, prob.n_z:]


def unstable_at(prob: Problem, x, drive, values: Values, parts=None) -> str:
    """:func:`~tendonsense.stability.unstable` for the solution ``x`` of ``prob`` (its
    magnitudes held, as dead loads), from the Jacobians the 1-σ band uses (``parts``); a
    force estimated along a given direction suggests estimating its direction too (the rod
    may rest out of the plane of its loads, where a fixed direction misreads it)."""
    why = unstable(values, (jacobians(prob, x, drive, values) if parts is None else parts)[0])
    if (why and prob.n_magnitudes < 3 and len(prob.robot.tendons) >= 3
            and np.any(np.asarray(prob.unknowns.forces) != 0)):
        why += (" (a rod that has swung out of the plane of its loads is read wrongly along "
                "a given direction: give three unknowns along x, y and z at the force's X "
                "(--unknown X,1,0,0 --unknown X,0,1,0 --unknown X,0,0,1; in Python "
                "PointForceUnknown(X, d) for d along x, y and z), with readings of three "
                "tendons)")
    return why


#: a magnitude whose strain the measured lengths' gradients span less than this fraction of
#: is unseen (:func:`unseen`; by symmetry the fraction is then exactly 0)
UNSEEN = 1e-9


def unseen(prob: Problem, x, drive, values: Values, parts=None
           ) -> tuple[tuple[int, ...], str]:
    """The magnitudes whose size the readings cannot tell at ``x`` and why (``()``, '' if
    none): the strain a change of each makes (``E_q⁻¹ E_z``) is orthogonal, to
    :data:`UNSEEN`, to every measured length's gradient ``y_q`` — e.g. a force across the
    plane in which the measured tendons bend the rod, which by symmetry changes their lengths
    at second order only. Each estimate's Newton matrix is then singular: a solver stops where
    it started. ``parts``: :func:`jacobians` at ``x`` if known."""
    Eq, Ez, _, yq = jacobians(prob, x, drive, values) if parts is None else parts
    with np.errstate(all="ignore"):
        d = np.linalg.solve(Eq, Ez[:, :prob.n_magnitudes])
        seen = np.linalg.norm(np.linalg.qr(yq.T)[0].T @ d, axis=0) / np.linalg.norm(d, axis=0)
    blind = [k for k in range(prob.n_magnitudes) if seen[k] < UNSEEN]
    if not blind:
        return (), ""
    names = [prob.robot.tendon_names[j] for j in prob.measured]
    what = []
    for k in blind:
        F = np.asarray(prob.unknowns.forces, float)[k]
        p = np.flatnonzero(np.any(F != 0, axis=1))
        what.append(f"unknown {k + 1} (the force along ({', '.join(f'{c:g}' for c in F[p[0]])})"
                    f" at X = {prob.load_X[p[0]]:g} m)" if p.size else
                    f"unknown {k + 1} (gravity's scale)")
    why = (f"the measured tendon{'s' if len(names) > 1 else ''} ({', '.join(names)}) "
           f"do{'es' if len(names) == 1 else ''} not change length with {' or '.join(what)} "
           f"at the shape reached: the readings cannot tell "
           f"{'its' if len(blind) == 1 else 'their'} size (is it across the plane the measured "
           f"tendons bend the rod in? give a direction they see, or measure a tendon it "
           f"stretches)")
    return tuple(blind), why


def band(dz_dm: np.ndarray, n_lengths: int, tensions: np.ndarray, noise: Noise) -> np.ndarray:
    """1-σ band of the magnitudes from their sensitivity ``dz_dm`` (…, n_z, m) to [lengths;
    tensions] (first-order propagation of the sensor noise, as in
    :mod:`tendonsense.estimation`); ``tensions`` (…, m − n_lengths)."""
    with np.errstate(all="ignore"):  # a failed sample's sensitivity may not be finite
        return noise_band(np, dz_dm, n_lengths, np.asarray(tensions, float), noise.length,
                          noise.tension)


def covariance(dz_dm: np.ndarray, n_lengths: int, tensions: np.ndarray, noise: Noise
               ) -> np.ndarray:
    """The covariance (…, n_z, n_z) of the magnitudes whose diagonal's root is :func:`band`
    (same arguments)."""
    with np.errstate(all="ignore"):
        return noise_covariance(np, dz_dm, n_lengths, np.asarray(tensions, float),
                                noise.length, noise.tension)


def noise_band(xp, dz_dm, n_lengths: int, tensions, length, tension):
    """:func:`band` in ``xp`` (numpy, or jax.numpy in a compiled program) with the noise's
    ``length`` (m) and relative ``tension``."""
    return xp.sqrt((_scaled(xp, dz_dm, n_lengths, tensions, length, tension) ** 2).sum(axis=-1))


def noise_covariance(xp, dz_dm, n_lengths: int, tensions, length, tension):
    """The covariance (…, n_z, n_z) of the unknowns whose diagonal's root is
    :func:`noise_band` (same arguments)."""
    s = _scaled(xp, dz_dm, n_lengths, tensions, length, tension)
    return s @ xp.swapaxes(s, -1, -2)


def _scaled(xp, dz_dm, n_lengths, tensions, length, tension):
    """``dz_dm`` with each measurement's column times its noise (1 σ)."""
    scale = xp.concatenate([xp.full((*tensions.shape[:-1], n_lengths), length),
                            tension * xp.abs(tensions)], axis=-1)
    return dz_dm * scale[..., None, :]


#: a least-squares estimate's length misfit whose χ² is above this quantile of its
#: distribution under the sensor noise alone is more than that noise explains
MISFIT_QUANTILE = 0.999
#: the words that open a misfit's note (:func:`misfit_notes`), and those that close it
MISFIT = "the readings disagree beyond their noise"
NOISE_ALONE = "the ± assumes the noise alone"


def misfit_notes(Jz, JT, misfit, tensions, noise: Noise) -> list[str]:
    """For least-squares estimates (leading axis: the estimate), a note where the length misfit
    ``misfit`` (N, n_m; m, per measured tendon) is more than the sensor noise explains, or '':
    its χ² against the covariance the noise gives that misfit (``Jz`` (N, n_m, n_z), ``JT``
    (N, n_m, n_T): the measured lengths' sensitivities to the magnitudes and to the
    ``tensions`` (N, n_T), the length noise and the relative tension noise through ``JT``,
    on the left null space of ``Jz``: what the magnitudes cannot absorb), over as many
    degrees of freedom as that space has, above its :data:`MISFIT_QUANTILE` quantile. A row
    with a value that is not finite (no solution) has none."""
    from scipy.special import chdtri
    Jz, JT, e, T = (np.asarray(a, float) for a in (Jz, JT, misfit, tensions))
    notes = [""] * len(e)
    rows = np.flatnonzero(np.isfinite(Jz).all(axis=(1, 2)) & np.isfinite(JT).all(axis=(1, 2))
                          & np.isfinite(e).all(axis=1) & np.isfinite(T).all(axis=1))
    Jz, JT, e, T = Jz[rows], JT[rows], e[rows], T[rows]
    m = e.shape[-1]
    # the misfit's part the magnitudes cannot absorb: on the columns of U past Jz's rank
    U, s, _ = np.linalg.svd(Jz)
    top = s.max(axis=-1, initial=0.0)
    rank = np.sum(s > 1e-10 * top[..., None], axis=-1) * (top > 0)
    null = np.arange(m) >= rank[..., None]  # (…, m)
    C = noise.length**2 * np.eye(m) + (JT * (noise.tension * T[..., None, :])**2) @ np.swapaxes(
        JT, -1, -2)
    r = np.where(null, np.einsum("...ji,...j->...i", U, e), 0.0)
    Cu = np.swapaxes(U, -1, -2) @ C @ U
    both = null[..., :, None] & null[..., None, :]
    Cn = np.where(both, Cu, np.eye(m))  # the null space's block, identity elsewhere
    chi2 = np.einsum("...i,...i->...", r, np.linalg.solve(Cn, r[..., None])[..., 0])
    dof = m - rank
    with np.errstate(invalid="ignore"):
        over = (dof >= 1) & (chi2 > chdtri(np.maximum(dof, 1), 1 - MISFIT_QUANTILE))
    rms = np.sqrt(np.mean(e**2, axis=-1))
    for k in np.flatnonzero(over):
        notes[rows[k]] = (
            f"{MISFIT}: the measured lengths are met to {rms[k] * 1e3:.3g} mm RMS, "
            f"{np.sqrt(chi2[k] / dof[k]):.2g} times what the length and tension noise explain "
            f"(is a tendon swapped or mislabelled, a force's X or direction wrong, a load not "
            f"given?); {NOISE_ALONE}")
    return notes


def misfit_part(note: str) -> str:
    """The misfit's note (:func:`misfit_notes`) within ``note``, or ''."""
    start = note.find(MISFIT)
    end = note.find(NOISE_ALONE, start)
    return note[start:end + len(NOISE_ALONE)] if start >= 0 and end >= 0 else ""


def misfit_note(Jz, JT, misfit, tensions, noise: Noise) -> str:
    """:func:`misfit_notes` of one estimate."""
    return misfit_notes(*(np.asarray(a, float)[None] for a in (Jz, JT, misfit, tensions)),
                        noise)[0]


#: two magnitudes whose estimates correlate beyond this are confounded: the readings fix a
#: combination of them, not each (each σ is then over 7× what it would be, the other known)
CONFOUNDED = 0.99


def confounded(covariance, n: int) -> str:
    """A note naming the magnitudes (the first ``n`` unknowns of ``covariance``) that the
    readings cannot tell apart, pairs correlated beyond :data:`CONFOUNDED`; '' if none."""
    if n < 2:
        return ""
    c = np.asarray(covariance, float)[:n, :n]
    with np.errstate(all="ignore"):
        sd = np.sqrt(np.diag(c))
        rho = c / np.outer(sd, sd)
    pairs = [(i, j) for i in range(n) for j in range(i + 1, n)
             if abs(rho[i, j]) > CONFOUNDED]
    if not pairs:
        return ""
    return ("confounded: " + ", ".join(
        f"magnitudes {i + 1} and {j + 1} (correlation {rho[i, j]:+.4f})" for i, j in pairs)
        + ": these readings fix a combination of them, not each (hence their 1-σ band); "
        "measure another tendon or estimate fewer loads")
