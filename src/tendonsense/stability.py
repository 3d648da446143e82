"""Stability of an equilibrium, and the state the rod settles in from an unstable one.

An equilibrium of eq. 7 is stable when every eigenvalue of the tangent stiffness over the
material's, ``(E K)⁻¹ ∂E/∂q`` with the tensions held, has a positive real part
(:func:`stiffness_ratio`: 1 for the unloaded rod, ``1 − P/P_cr`` for Euler's column). A solve
from the straight rod keeps the plane of its loads by symmetry, so where that planar shape is
unstable (or where the planar branch ends and the solve fails) the robot takes another state;
:func:`settle` finds it by following the damped rod's quasi-static motion from the unstable
shape, nudged along its unstable mode.
"""

from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .compiled import Program
from .model import Structure, Values, host
from .statics import CACHE_SIZE, Drive, NewtonResult, Unknowns, residual, scaling

#: an equilibrium whose stiffness ratio (:func:`unstable`) falls below −UNSTABLE is unstable
UNSTABLE = 1e-6
#: how :func:`unstable`'s note begins (a result's note holds it among others)
UNSTABLE_NOTE = "unstable equilibrium"
#: how the note of a solve's result that :func:`settle` found begins
SETTLED_NOTE = "settled"


def tangent(values: Values, res: NewtonResult, nq: int) -> np.ndarray:
    """``∂E/∂q`` (unscaled, eq. 7) at a Newton solution, from the Jacobian of its scaled
    residual (:func:`~tendonsense.statics.residual`: ``J_qq = L⁻¹ ∂E/∂q / √E``,
    ``K = L Lᵀ``)."""
    L = np.linalg.cholesky(host(values).stiffness())
    return np.sqrt(float(values.young_modulus)) * L @ np.asarray(res.jacobian, float)[:nq, :nq]


def stiffness_ratio(values: Values, tangent) -> float:
    """The least real part of the eigenvalues λ of ``(E K)⁻¹ ∂E/∂q`` at an equilibrium whose
    tangent stiffness is ``tangent`` (``∂E/∂q`` with the tensions and any unknowns held): the
    tangent stiffness over the material's (the Hessian of the potential energy where there is
    no friction). λ is 1 for an unloaded rod and ``1 − P/P_cr`` for a column under an end load
    P (Euler's P_cr); below −:data:`UNSTABLE` a mode grows from any disturbance
    (:func:`is_unstable`)."""
    K = float(values.young_modulus) * host(values).stiffness()
    with np.errstate(all="ignore"):
        return float(_least(np.linalg.eigvals(np.linalg.solve(K, np.asarray(tangent, float)))
                            .real, np))


def _least(real_parts, xp=jnp):
    """The least of the eigenvalues' real parts, 0 where one is not finite (traceable with
    ``xp`` jax.numpy; numpy on the host: no program to build)."""
    return xp.where(xp.all(xp.isfinite(real_parts)), xp.min(real_parts), 0.0)


def scaled_ratios(J_qq, L_inv):
    """The real parts of the eigenvalues of :func:`stiffness_ratio`'s ``(E K)⁻¹ ∂E/∂q`` from
    the scaled residual's ``J_qq = L⁻¹ ∂E/∂q / √E``
    (:func:`~tendonsense.statics.residual`, ``L_inv`` its
    :class:`~tendonsense.statics.Scaling`'s): the same eigenvalues as
    ``L⁻ᵀ J_qq / √E = J_qq L_invᵀ``, traceable."""
    return jnp.linalg.eigvals(J_qq @ L_inv.T).real


def is_unstable(ratio):
    """Whether stiffness ratios (:func:`stiffness_ratio`; a number or an array, NaN: not
    known) are an unstable equilibrium's."""
    return np.asarray(ratio) < -UNSTABLE


def unstable_note(ratio: float) -> str:
    """Why an equilibrium of stiffness ratio ``ratio`` (:func:`stiffness_ratio`) is unstable,
    or '': a mode whose stiffness the loads have overcome."""
    if not is_unstable(ratio):
        return ""
    return (f"{UNSTABLE_NOTE}: a mode of the rod has lost its stiffness to the loads "
            f"(stiffness ratio {ratio:.3g}; a column loaded past Euler's load has "
            f"1 − P/P_cr): the rod would buckle or snap away from this shape to another, "
            f"which this solution is not")


def unstable(values: Values, tangent) -> str:
    """Why an equilibrium whose tangent stiffness is ``tangent`` (``∂E/∂q`` with the tensions
    and any unknowns held) is unstable, or '' (:func:`stiffness_ratio`, :func:`unstable_note`):
    the rod buckles or snaps away from this shape."""
    return unstable_note(stiffness_ratio(values, tangent))


def _linearised(structure: Structure, values: Values, drive: Drive, unknowns: Unknowns, x):
    """Forward statics' scaled residual at ``x``, its load size, its exact Jacobian and its
    scaling's ``L_inv`` (traceable)."""
    sc = scaling(values, ())

    def r(x):
        out = residual(structure, values, (), x, drive, unknowns, 1.0, sc)
        return out[0], out

    J, (res, size) = jax.jacfwd(r, has_aux=True)(x)
    return res, size, J, sc.L_inv


@lru_cache(maxsize=CACHE_SIZE)
def _ratios_fn(structure: Structure):
    def ratios(values, varied, drives, unknowns, xs, wanted):
        def one(sample):
            x, d, p, want = sample

            def ratio():
                _, _, J, L_inv = _linearised(structure, values._replace(**p), d, unknowns, x)
                return _least(scaled_ratios(J, L_inv))

            return jax.lax.cond(want, ratio, lambda: jnp.asarray(jnp.nan))

        # one sample at a time: no batched jacfwd
        return jax.lax.map(one, (xs, drives, varied, wanted))

    return Program(ratios, "stiffness_ratios", structure)


def stiffness_ratios(structure: Structure, values: Values, varied: dict, drives: Drive,
                     unknowns: Unknowns, xs, wanted) -> np.ndarray:
    """:func:`stiffness_ratio` of forward-statics solutions ``xs`` (n, nq) of ``drives`` (a
    :class:`~tendonsense.statics.Drive` with a leading sample axis), each with its own
    ``varied`` values ({name: (n, ...)}, may be empty), where ``wanted`` (n,) (NaN
    elsewhere), in one compiled program (an exact Jacobian each)."""
    return np.asarray(_ratios_fn(structure)(values, varied, drives, unknowns,
                                            jnp.asarray(xs, float), jnp.asarray(wanted, bool)))


def preload_stiffness_ratios(structure: Structure, values: Values, varied: dict,
                             drives: Drive, unknowns: Unknowns, xs, wanted) -> None:
    """:func:`stiffness_ratios`' program for these arguments' kinds loaded from disk on
    another thread, ahead of its first call (:meth:`~tendonsense.compiled.Program.preload`)."""
    _ratios_fn(structure).preload(values, varied, drives, unknowns, jnp.asarray(xs, float),
                                  jnp.asarray(wanted, bool))


@lru_cache(maxsize=CACHE_SIZE)
def _linear_fn(structure: Structure):
    return Program(lambda values, drive, unknowns, x: _linearised(
        structure, values, drive, unknowns, x), "linearised", structure)


def preload_settle(structure: Structure, values: Values, drive: Drive, unknowns: Unknowns,
                   x) -> None:
    """:func:`settle`'s program loaded from disk on another thread, ahead of its first call
    (:meth:`~tendonsense.compiled.Program.preload`)."""
    _linear_fn(structure).preload(values, drive, unknowns, np.asarray(x, float))


#: pseudo-time steps :func:`settle` takes at most, over all its nudges
SETTLE_STEPS = 1000
#: the nudge along the unstable mode, relative to ‖q‖ (at least 1)
NUDGE = 1e-3
#: the local error of a pseudo-time step, relative to ‖q‖ (at least 1)
STEP_ERROR = 0.02
#: a step from a stable shape after which the residual is more than GROWTH times as large is
#: taken again shorter (one leaving an unstable shape may grow it: its length is capped)
GROWTH = 4.0
#: a pseudo-time step that must be shorter than this to stay in the model's range ends
#: :func:`settle` (the motion leaves the model there, e.g. two disks of a tendon meet or a
#: fibre is compressed to nothing)
SHORTEST = 1e-9
#: why :func:`settle` stopped short of its steps where the rod's motion left the model
LEFT_THE_MODEL = ("the motion left the model's range (its equations have no value just "
                  "beyond: e.g. two disks of a tendon meet, or a fibre is compressed to "
                  "nothing)")


class Settled(NamedTuple):
    """Where :func:`settle` came to rest."""

    x: np.ndarray  # q where it stopped
    converged: bool  # at rest (equilibrium to the solver's tolerance) and stable
    steps: int  # pseudo-time steps taken
    nudges: int  # nudges along an unstable mode
    why: str = ""  # why it stopped before its last step without coming to rest, or ''


def settle(structure: Structure, values: Values, drive: Drive, unknowns: Unknowns, x,
           tolerance: float, max_steps: int = SETTLE_STEPS) -> Settled:
    """The stable equilibrium the rod comes to rest in from ``x`` (an unstable equilibrium of
    forward statics, or where a solve stopped): nudged along its most unstable mode (the
    eigenvector of :func:`stiffness_ratio`'s least eigenvalue, the sign that makes its largest
    component positive: the opposite nudge may rest elsewhere, e.g. in the mirror image), then
    the quasi-static motion of a rod damped in proportion to its stiffness,
    ``τ E K q̇ = −E(q)`` (eq. 7's residual), followed by linearly implicit Euler steps
    (pseudo-transient continuation), exact Jacobians: each step's length set by its local
    error, and below ``1 / (2|λ|)`` while a mode λ < 0 is unstable (a longer step would return
    to the unstable shape); once the shape is stable the steps grow into Newton's, and one
    after which the residual grows more than :data:`GROWTH` times is taken again a quarter as
    long, as is a step to where the equations have no value
    (:data:`LEFT_THE_MODEL` where it would have to be shorter than :data:`SHORTEST`).
    Nudged again if it comes to rest at another unstable equilibrium."""
    lin = _linear_fn(structure)
    x = np.array(x, float)
    floor = float(values.energy_floor * np.sqrt(values.young_modulus))
    steps = nudges = 0
    h, v_old, before = 1.0, None, None
    while steps < max_steps:
        r, size, J, L_inv = (np.asarray(a) for a in lin(values, drive, unknowns, x))
        finite = np.all(np.isfinite(r)) and np.all(np.isfinite(J))
        if before is not None and not (finite and (np.linalg.norm(r) <= GROWTH * before[1]
                                                   or is_unstable(before[3]))):
            # the step left the motion (its linearisation): again, a quarter as long
            x, h, v_old, before = before[0], before[2] / 4, None, None
            if h < SHORTEST:
                return Settled(x, False, steps, nudges, LEFT_THE_MODEL)
            continue
        if not finite:
            return Settled(x, False, steps, nudges, LEFT_THE_MODEL)
        lam, V = np.linalg.eig(L_inv.T @ J)  # (E K)⁻¹ ∂E/∂q: the stiffness ratios
        worst = int(np.argmin(lam.real))
        ratio = float(lam.real[worst])
        if np.linalg.norm(r) <= tolerance * (float(size) + floor):
            if not is_unstable(ratio):
                return Settled(x, True, steps, nudges)
            v = V[:, worst]  # turned so that its largest component is real and positive
            u = np.real(v * np.conj(v[np.argmax(np.abs(v))]))
            u = u / np.linalg.norm(u)
            x = x + NUDGE * max(np.linalg.norm(x), 1.0) * u
            nudges, h, v_old, before = nudges + 1, 1.0, None, None
            continue
        if ratio < 0:
            h = min(h, 0.5 / -ratio)
        dx = np.linalg.solve(np.linalg.inv(L_inv).T / h + J, -r)
        h_next = h
        if v_old is not None:  # the step's local error, from the change of the velocity
            err = 0.5 * h * np.linalg.norm(dx / h - v_old)
            h_next = h * min(4.0, max(0.5, np.sqrt(STEP_ERROR * max(np.linalg.norm(x), 1.0)
                                                   / max(err, 1e-300))))
        before = (x, np.linalg.norm(r), h, ratio)
        x, v_old, h, steps = x + dx, dx / h, min(h_next, 1e12), steps + 1
    return Settled(x, False, steps, nudges)
