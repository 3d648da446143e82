"""The friction direction of every tendon over a log of readings: a play operator on the
logarithm of its tension, at every turn of the tendon.

A tendon pulled in has its tension fade toward the anchor, ``T_anchor = T exp(−μφ)`` (eq. 10
over its turning angle φ, :func:`~tendonsense.tendons.turning`); paid out, it grows,
``T_anchor = T exp(+μφ)``; in between it sticks. Where it sticks, each disk holds the tension
past it until the ratio across it leaves the Capstan band, so the tension past the j-th turn,
``w_j = ln T_j``, follows the play operator ``w_j ← clip(w_j, p − μψ_j, p + μψ_j)`` of
``p = ln T`` (the reading), ``ψ_j`` the turning from the actuator to there
(:func:`~tendonsense.tendons.depths`; plays of widths a and b in a row are one of width a + b):
a released tendon slips out near the actuator first while the far turns still hold the
tension of the pull. The state of turn j, ``s_j = (p − w_j) / (μψ_j)`` ∈ [−1, 1] (+1 pulled
in, −1 paid out, stuck between), signs its Capstan exponent: the model is solved with friction
``s_j μ`` past turn j (``T_j = T exp(−s_j μ ψ_j)``); a tendon's state, direction and band are
its anchor's (the last turn's: without noise a tendon in or out at its anchor is so at every
turn; within the noise's reach of the anchor's edge, turns nearer the actuator may be inside
their narrower bands). A continuous tendon keeps one state (its anchor's). A named
direction sets every turn (:func:`~tendonsense.inputs.friction_signs`). With the shape fixed
that is the play operator on each ``w_j``; the states themselves are kept and moved by
``Δs_j = Δp / (μψ_j)`` from reading to reading, ``1/(μψ_j)`` by the trapezoid rule over the
last shape and this one, so a change of shape alone keeps them. Against the per-disk
stick/slip truth of ``benchmarks/friction.py`` (the reference BVP): one state per tendon
(every turn at the anchor's) gives 11 % rms error in a release under a tip weight and 50 %
under a weight at L/2, one per turn 3 % and 19 %. Keeping ``w_j`` instead of ``s_j`` (a
change of shape then moves the states) gives 71 % with one state per tendon (tip), and with
one per turn 3.3 % and 18 %, but 5 of 250 rows at L/2 without an equilibrium.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Mapping, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .compiled import Program
from .inputs import EDGE
from .model import Structure
from .readings import RELEASE_AT_START
from .statics import CACHE_SIZE
from .tendons import turning

#: passes to settle friction states with the shapes they give, and the tolerance on a state
FIXED_POINT, STATE_TOL = 10, 1e-4

#: a direction a log or a reading sets (``sliding_<tendon>``) as the state it sets: NaN, the
#: history decides (``stuck`` keeps the history's state and marks the tendon stuck)
GIVEN = {"in": 1.0, "out": -1.0, "stuck": np.nan, "": np.nan}
#: a direction by its code in a compiled program's output (:func:`~tendonsense.fastpath.live`)
DIRECTION = {1.0: "in", -1.0: "out", 0.0: "stuck"}

#: standard deviations of the tensions' read-out noise within which a state cannot be told
#: from its band's edge (:func:`reach`)
NOISE_REACH = 3.0


def reach(mu, phi, tension_noise: float, xp=np) -> np.ndarray:
    """How far into its band, in units of the state, read-out noise of relative standard
    deviation ``tension_noise`` can take a tendon of friction ``mu`` turning by ``phi``:
    ``NOISE_REACH σ / (μφ)`` (0 without a band: the state is then ±1). A state that close to
    ±1 is labelled by the edge (in or out, :func:`labels`), not stuck. ``xp``: numpy, or
    jax.numpy in a compiled program."""
    band = xp.asarray(mu, float) * xp.asarray(phi, float)
    return xp.where(band > 0, NOISE_REACH * tension_noise / xp.where(band > 0, band, 1.0), 0.0)


def labels(states, mu, phi, tension_noise: float, stuck_given):
    """Each tendon's direction, ``in``, ``out`` or ``stuck``, from its friction state in
    [−1, 1] (+1 pulled in), a state within the tension noise's :func:`reach` of its band's edge
    (at least :data:`~tendonsense.inputs.EDGE`) read as that edge, and ``stuck`` wherever
    ``stuck_given`` (the log said so): a tuple for states (n_t,), a list of tuples, one a
    reading, for states (N, n_t) and ``phi`` of the same shape."""
    edge = reach(mu, phi, tension_noise).tolist()
    if np.ndim(states) == 1:
        return tuple(map(_direction, np.asarray(states, float).tolist(), edge,
                         np.asarray(stuck_given, bool).tolist()))
    return [tuple(map(_direction, *row)) for row in zip(
        np.asarray(states, float).tolist(), edge, np.asarray(stuck_given, bool).tolist())]


def _direction(state: float, reach: float, stuck: bool) -> str:
    edge = max(EDGE, reach)  # a NaN state compares False: stuck
    return "stuck" if stuck else "in" if state >= 1 - edge else "out" if state <= -1 + edge \
        else "stuck"


@lru_cache(maxsize=CACHE_SIZE)
def turning_program(structure: Structure) -> Program:
    """Compiled ``(q (N, nq), values) -> φ (N, n_t)``."""
    return Program(jax.vmap(lambda q, values: turning(structure, values, q), (0, None)),
                   "turning", structure)


class FrictionHistory:
    """The friction state of every tendon along a log (module docstring), ``mu`` (n_t,) their
    friction coefficients, at each of ``turns`` turns (:func:`~tendonsense.tendons.turns`;
    None: one state per tendon, at its anchor). The first reading of a tendon finds it pulled
    in; a state changes with the tension, ``Δs_j = Δ ln T / (μψ_j)`` clipped to [−1, 1], and
    is kept while the tension is (a change of shape alone neither pulls a tendon in nor pays it
    out). ``s`` and ``phi`` are (n_t, turns), or (n_t,) without turns."""

    def __init__(self, mu, margin: float = 0.0, turns: int | None = None):
        self.mu = np.asarray(mu, float)
        self.margin = float(margin)  # of ln T: changes within it are not taken as motion
        self.turns = turns
        shape = self.mu.shape if turns is None else (*self.mu.shape, turns)
        self.s = np.full(shape, np.nan)  # the last state; NaN: slack or no reading
        self.p = np.zeros(self.mu.shape)  # the last ln T
        self.phi = np.zeros(shape)  # the turning to each turn of the last shape

    def copy(self) -> "FrictionHistory":
        h = FrictionHistory(self.mu, self.margin, self.turns)
        h.s, h.p, h.phi = self.s.copy(), self.p.copy(), self.phi.copy()
        return h

    @property
    def active(self) -> bool:
        """Whether any tendon has friction (without, the direction changes nothing)."""
        return bool(np.any(self.mu > 0))

    def pulled(self, tensions, given: Mapping[int, str] | None = None) -> bool:
        """If every tendon stays pulled in at this reading whatever its band (its tension
        rises or holds, it was pulled in, the log says nothing else), take the reading and
        return True; else return False and change nothing (the state needs :meth:`step`)."""
        if given and any(d != "in" for d in given.values()):
            return False
        T = np.asarray(tensions, float)
        live = T > 0
        p = np.log(np.where(live, T, 1.0))
        low = self.s.reshape(len(T), -1).min(axis=1)  # NaN (slack before): not below 1
        if (live & ((low < 1) | (p < self.p))).any():
            return False
        self.s = np.where(_per_turn(live, self.s), np.where(np.isnan(self.s), 1.0, self.s),
                          np.nan)
        self.p = p
        return True

    def step(self, tensions, phi=None, given: Mapping[int, str] | None = None) -> np.ndarray:
        """The state (the shape of ``s``) for the next reading: ``tensions`` (n_t,), N;
        ``phi`` the turning to each turn of its shape (the shape of ``s``; None: the last
        shape's); ``given`` {tendon index: in|out|stuck} from the log (in and out set the
        state, stuck keeps the history's)."""
        T = np.asarray(tensions, float)
        mu = _per_turn(self.mu, self.s)
        last = mu * self.phi
        if phi is not None:
            if np.shape(phi) != self.s.shape:
                raise ValueError(f"turning {np.shape(phi)} for friction states {self.s.shape}")
            self.phi = np.asarray(phi, float)
        band = mu * self.phi
        p = np.log(np.where(T > 0, T, 1.0))
        rise = _per_turn(p - self.p, self.s)
        per = _per_width(np, last, np.where(band > 0, band, 1.0))  # used where band > 0
        # the state moves within ±(1 + margin/band) and reads clipped to ±1: a reading must
        # pass the band's edge by the margin to move the tension past the turn
        wide = 1.0 + self.margin / np.where(band > 0, band, 1e-300) if self.margin \
            else np.ones_like(band)
        with np.errstate(invalid="ignore"):  # Δs = Δ ln T / (μψ); without a band: in or out
            moved = np.where(band > 0, self.s + rise * per,
                             np.where(rise != 0, np.copysign(np.inf, rise), self.s))
        u = np.where(np.isnan(self.s), wide, np.clip(moved, -wide, wide))  # first: pulled in
        code = np.array([{"in": 1.0, "out": -1.0}.get((given or {}).get(k), 0.0)
                         for k in range(len(T))])
        u = np.where(_per_turn(code != 0, u), _per_turn(code, u) * wide, u)
        u = np.where(_per_turn(T > 0, u), u, wide)
        self.s, self.p = np.where(_per_turn(T > 0, u), u, np.nan), p
        return np.clip(u, -1.0, 1.0)


def _per_turn(a, like):
    """``a`` (n_t,) against states ``like`` (n_t,) or (n_t, turns)."""
    return a[:, None] if np.ndim(like) == 2 else a


def _per_width(xp, last, width):
    """``1 / (μφ)`` for the state's change ``Δs = Δ ln T / (μφ)`` over one reading, by the
    trapezoid rule between the last shape's band ``last`` and this one's ``width`` (> 0): a
    reading's noise moves φ with ln T, and the rule at either end alone would sum that
    correlation into a drift of the stuck state (``c σ² / μφ`` a reading); this one
    telescopes. ``last`` ≤ 0 (no shape yet): ``width`` alone."""
    return 0.5 * (1.0 / width + 1.0 / xp.where(last > 0, last, width))


def fallen(T: np.ndarray, mu: np.ndarray, names, tension_noise: float) -> list[str]:
    """Per reading of a series taken pulled in (``T`` (N, n_t) N, ``mu`` (N, n_t)), a note
    naming the tendons with friction whose tension has fallen from its highest since it was
    last slack by more than noise explains — released, stuck or paid out, the pulled-in law
    misreads them — else ''. In ln T, the larger of
    :data:`~tendonsense.readings.RELEASE_AT_START` and (r + max(NOISE_REACH, r) + 1) σ with
    r = √(2 ln k): the highest of k noisy readings lies about rσ above their mean, and fewer
    than one of them about rσ below it (one σ more: a hold of 20,000 readings at 1 % noise
    noted none, 1 without it). A tension under a tenth of the series' largest (a slack
    tendon's sensor offset) or not a number is not looked at, and the tendon starts afresh
    after it."""
    T, mu = np.asarray(T, float), np.asarray(mu, float)
    n = T.shape[0]
    if n == 0:
        return []
    slack = ~(T > 0.1 * np.nanmax(T, initial=0.0))
    k = np.arange(n)[:, None]
    # each tendon's highest since it was last slack: a running maximum that each slack
    # reading restarts (the readings of a later stretch lifted above every earlier one's)
    stretch = np.cumsum(slack, axis=0) * (np.nanmax(T, initial=0.0) + 1.0)
    lifted = np.maximum.accumulate(np.where(slack, -np.inf, T + stretch), axis=0)
    top = lifted - stretch
    higher = ~slack & (T + stretch > np.vstack([np.full(T.shape[1], -np.inf), lifted[:-1]]))
    at = np.maximum.accumulate(np.where(higher, k, 0), axis=0)  # the reading it was
    since = k - np.maximum.accumulate(np.where(slack, k, -1), axis=0)  # readings since slack
    reach = np.sqrt(2 * np.log(np.maximum(since, 1)))
    step = np.maximum(RELEASE_AT_START, tension_noise * (
        reach + np.maximum(NOISE_REACH, reach) + 1.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        low = (mu > 0) & ~slack & (np.log(T / top) < -step)
    notes = [""] * n
    for r in np.flatnonzero(low.any(axis=1)).tolist():
        said = [f"{names[j]}'s from {top[r, j]:.4g} N (reading {at[r, j] + 1}) to "
                f"{T[r, j]:.4g} N" for j in np.flatnonzero(low[r])]
        notes[r] = (f"tension fallen, {', '.join(said)}: this series takes every tendon "
                    f"pulled in (eq. 10 as written); a released tendon is stuck or paid out, "
                    f"its friction otherwise (tendonsense.logs.estimate_readings follows each "
                    f"tendon's history)")
    return notes


def band_range(middle, corners) -> np.ndarray:
    """(n, 2) ``[low, high]`` of n magnitudes over the stuck tendons' friction band, from
    their estimate at its ``middle`` (n,) and at its ``corners`` (k, n; every stuck tendon
    pulled in or paid out, NaN where no equilibrium was found). A corner without one leaves
    the range open on its side (±inf: toward it the magnitudes grow until the model has no
    equilibrium): with one stuck tendon the side away from the other corner, with more (or
    both corners failed) both sides."""
    middle, corners = np.asarray(middle, float), np.atleast_2d(np.asarray(corners, float))
    m = np.vstack([middle, corners])
    low, high = np.nanmin(m, axis=0), np.nanmax(m, axis=0)
    failed = np.isnan(corners).any(axis=1)
    if failed.any():
        if len(corners) == 2 and not failed.all():
            above = corners[~failed][0] >= middle  # the failed corner lies the other way
            low, high = np.where(above, -np.inf, low), np.where(above, high, np.inf)
        else:
            low, high = np.full_like(low, -np.inf), np.full_like(high, np.inf)
    return np.stack([low, high], axis=1)


def band_note(middle, corners) -> str:
    """Where a magnitude's estimate at the band's ``middle`` lies outside its estimates at
    the band's ``corners`` (all found), a note that the estimate is not monotone over the
    band: more than one equilibrium may explain the reading (e.g. a rod bent past a right
    angle), and the range spans the ones found; else ''."""
    middle, corners = np.asarray(middle, float), np.atleast_2d(np.asarray(corners, float))
    tol = 1e-9 * (1.0 + np.abs(middle))
    out = [i for i in range(middle.size) if np.isfinite(corners[:, i]).all() and (
        middle[i] < corners[:, i].min() - tol[i] or middle[i] > corners[:, i].max() + tol[i])]
    if not out:
        return ""
    i = out[0]
    return (f"not monotone over the friction band: magnitude {i + 1} is "
            f"{middle[i]:.4g} at its middle, {' and '.join(f'{c:.4g}' for c in corners[:, i])}"
            f" at its ends; more than one equilibrium may explain this reading, and the "
            f"range spans the ones found")


class Band(NamedTuple):
    """:class:`FrictionHistory`'s state as arrays, carried along a compiled scan
    (:func:`~tendonsense.fastpath.follower`): each tendon's last state at each turn (NaN: slack
    or no reading), last ln T and the turning to each turn of the last shape (``s`` and
    ``phi`` (n_t, turns), or (n_t,) with one state per tendon)."""

    s: jax.Array
    p: jax.Array
    phi: jax.Array

    @classmethod
    def of(cls, history: FrictionHistory) -> "Band":
        return cls(*(np.array(a, float) for a in (history.s, history.p, history.phi)))

    def into(self, history: FrictionHistory) -> None:
        history.s, history.p, history.phi = (np.array(a, float) for a in self)


def play(band: Band, mu, tensions, phi, given):
    """:meth:`FrictionHistory.step` in JAX: the state (the shape of ``band.s``) of a reading
    with ``tensions`` at a shape whose turning to each turn is ``phi``, and the band after it;
    ``given`` (n_t,) a state set by the log (+1 in, −1 out), NaN where the history decides."""
    live = _per_turn(tensions > 0, band.s)
    p = jnp.log(jnp.where(tensions > 0, tensions, 1.0))
    mu, given = _per_turn(mu, band.s), _per_turn(given, band.s)
    rise, width = _per_turn(p - band.p, band.s), mu * phi
    wide = width > 0
    change = jnp.where(wide, rise * _per_width(jnp, mu * band.phi, jnp.where(wide, width, 1.0)),
                       jnp.sign(rise) * jnp.inf)
    s = jnp.where(jnp.isnan(band.s), 1.0,
                  jnp.clip(band.s + jnp.nan_to_num(change, nan=0.0), -1.0, 1.0))
    s = jnp.where(live, jnp.where(jnp.isnan(given), s, given), 1.0)
    return s, Band(jnp.where(live, s, jnp.nan), p, phi)


def pulled(band: Band, tensions, given):
    """:meth:`FrictionHistory.pulled` in JAX: whether every tendon stays pulled in whatever
    its band (or the reading sets every one pulled in), and the band after the reading if
    so."""
    live = tensions > 0
    p = jnp.log(jnp.where(live, tensions, 1.0))
    low = band.s.min(axis=1) if band.s.ndim == 2 else band.s  # NaN: not below 1
    keeps = jnp.all(given == 1.0) | jnp.all(jnp.isnan(given) | (given == 1.0)) & ~jnp.any(
        live & ((low < 1) | (p < band.p)))
    return keeps, Band(jnp.where(_per_turn(live, band.s), jnp.ones_like(band.s), jnp.nan), p,
                       band.phi)
