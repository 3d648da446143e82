"""Figures, drawn headlessly (matplotlib, Agg backend) and written as PNG."""

from __future__ import annotations

import io
import textwrap
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import NamedTuple

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: E402
from matplotlib.cm import ScalarMappable  # noqa: E402
from matplotlib.collections import LineCollection  # noqa: E402
from matplotlib.colors import ListedColormap, Normalize  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.textpath import TextPath  # noqa: E402
from matplotlib.ticker import MaxNLocator  # noqa: E402

from .forward import THROUGH_ITSELF, crossing, model_for, stretched  # noqa: E402
from .inputs import EDGE, PointForceUnknown, friction_signs, parameter_words  # noqa: E402
from .kinematics import frames_fn  # noqa: E402
from .readings import write_bytes_atomic  # noqa: E402
from .result import Result, joined  # noqa: E402
from .robot import Robot  # noqa: E402
from .stability import SETTLED_NOTE, UNSTABLE_NOTE  # noqa: E402
from .tendons import turning_along  # noqa: E402
from .units import GF, between, newtons, spread  # noqa: E402

SOURCES = ("length", "tension", "friction")
COLOURS = {"length": "tab:blue", "tension": "tab:orange", "friction": "tab:green"}


def _save(fig, path, tight: bool = True) -> Path:
    """The figure written to ``path`` atomically, in the format its suffix names."""
    path = Path(path)
    buf = io.BytesIO()
    try:
        fig.savefig(buf, format=path.suffix[1:] or None, dpi=120,
                    bbox_inches="tight" if tight else None)
    finally:
        plt.close(fig)
    write_bytes_atomic(path, buf.getvalue())
    return path


def _equal_3d(ax, pts):
    pts = np.asarray(pts)
    centre = (pts.max(0) + pts.min(0)) / 2
    half = max((pts.max(0) - pts.min(0)).max() / 2, 1e-3)
    for set_lim, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre):
        set_lim(c - half, c + half)


#: inches: the largest size of the views together, the gaps between them, the figure margins
VIEWS_IN = (7.0, 5.6)
GAP_IN = (0.9, 0.35)
MARGIN_IN = {"left": 0.8, "right": 1.2, "top": 0.35, "bottom": 0.6}
#: data margin and smallest axis span, as fractions of the largest span of the data
PAD, MIN_SPAN = 0.05, 0.14
#: the arrow of the largest force, as a fraction of the rod's largest span
ARROW = 0.25
KNOWN, ESTIMATED, MEASURED, SLACK, REST = "tab:blue", "tab:green", "tab:cyan", "0.8", "0.55"
TENSION_CMAP = ListedColormap(plt.get_cmap("plasma")(np.linspace(0.0, 0.85, 256)))
#: (title, global axes shown horizontally and vertically)
VIEWS = (("side view (x–z)", 0, 2), ("top view (x–y)", 0, 1))
_LABEL_BOX = dict(boxstyle="round,pad=0.15", fc="white", ec="none", alpha=0.55)


Load = tuple[float, Sequence[float]]


class Estimated(NamedTuple):
    """An estimated point load: where (m), the force (N, global), its 1-σ size (N), the
    range of its size over a stuck tendon's band (N) and, for a force whose location was
    estimated, that location's 1-σ band (m)."""

    X: float
    force: Sequence[float]
    sigma: float | None = None
    band: tuple[float, float] | None = None
    X_sigma: float | None = None


def estimated_forces(result: Result, unknowns: Sequence) -> list[Estimated]:
    """The point forces an estimate found (its ``unknowns``, as given to
    :func:`~tendonsense.estimation.estimate`), to draw with :func:`shape`: each one's X (its
    estimated location where it was located), force, 1-σ size, and its range over a stuck
    tendon's band."""
    if result.magnitudes is None:
        return []
    where = result.extra.get("locations") or [None] * len(unknowns)
    band = result.magnitude_range
    X_sigma = result.extra.get("location_sigma") or [None] * len(unknowns)
    return [Estimated(u.X if where[i] is None else where[i],
                      result.magnitudes[i] * np.asarray(u.direction, float), result.sigma[i],
                      tuple(band[i]) if len(band) else None, X_sigma[i])
            for i, u in enumerate(unknowns) if isinstance(u, PointForceUnknown)]


def shape(result: Result, path, robot: Robot, *, forces: Sequence[Load] = (),
          estimated: Sequence[Estimated] = (), measured_markers: dict | None = None,
          title: str = "", given: str = "", failed: str | None = None,
          sliding: Mapping[str, str] | None = None) -> Path:
    """The shape figure (:func:`shape_figure`) written as a PNG at ``path`` (atomically, the
    legend below the views included), e.g. an estimate with the forces it found::

        plotting.shape(est, "estimate.png", robot, estimated=plotting.estimated_forces(
            est, unknowns), title="my robot: estimated", given="t1 at 2.1 N")"""
    return _save(shape_figure(result, robot, forces=forces, estimated=estimated,
                              measured_markers=measured_markers, title=title, given=given,
                              failed=failed, sliding=sliding), path)


def shape_figure(result: Result, robot: Robot, *, forces: Sequence[Load] = (),
                 estimated: Sequence[Estimated] = (), measured_markers: dict | None = None,
                 title: str = "", given: str = "", failed: str | None = None,
                 sliding: Mapping[str, str] | None = None) -> Figure:
    """A side (x–z) and a top (x–y) view of ``result`` on ``robot`` at one equal scale (mm):
    the unloaded rod, the clamped base, the backbone, named markers, the tendons coloured by
    their tension along them (eq. 10) and the point loads drawn to one scale, labelled in N
    and gF.

    ``forces`` are known loads ``[(X, f N global)]``, ``estimated`` estimated ones
    (:class:`Estimated`, or tuples of its fields); ``measured_markers`` ({name: xyz m}) are
    drawn as crosses. ``title`` and ``given`` are the two title lines. ``sliding``
    ({tendon: 'in' | 'out' | 'stuck'}, default in) is how the result was solved: a tendon
    paid out grows toward its anchor, a stuck one is drawn at its band's middle (no friction:
    one tension, as :func:`~tendonsense.estimation.estimate` solves it). With ``failed`` (a
    reason) or a result that did not converge, the views are stamped NOT CONVERGED; a result
    at an unstable equilibrium (its note: :func:`~tendonsense.stability.unstable`) has red
    frames and UNSTABLE EQUILIBRIUM under its title; one that settled from such a state
    (:func:`~tendonsense.forward.solve`'s ``settle``) says SETTLED there.

    The figure is not pyplot's (``plt.close`` is not needed: it is freed with the last
    reference to it); a notebook shows it as a cell's value, and
    ``fig.savefig(path, bbox_inches="tight")`` writes it (the legend lies below the views,
    outside the figure's own box: :func:`shape` writes it so). The result carries no loads:
    pass the known ones as ``forces`` and an estimate's as ``estimated``
    (:func:`estimated_forces`)."""
    L = robot.rod.length
    loads = ([(X, np.asarray(f, float), newtons(float(np.linalg.norm(f))), KNOWN)
              for X, f in forces]
             + [(e.X, np.asarray(e.force, float), _estimate_label(e), ESTIMATED)
                for e in (Estimated(*e) for e in estimated)])
    routes = [np.linspace(0.0, L, 61) if t.continuous else np.asarray(t.disks, float)
              for t in robot.tendons]
    model = model_for(robot)
    g = np.asarray(frames_fn(model.structure)(
        model.values, np.asarray(result.q, float),
        np.concatenate([*routes, [X for X, *_ in loads]]).astype(float)))
    p, R = g[:, :3, 3] * 1e3, g[:, :3, :3]
    tendons, k = [], 0  # (name, tension at the actuator, path mm, each segment's tension)
    for t, X, sign in zip(robot.tendons, routes, friction_signs(robot, sliding)):
        T = result.tensions.get(t.name, 0.0)
        r = p[k:k + len(X)] + np.einsum("nij,nj->ni", R[k:k + len(X)], t.offset(X, L) * 1e3)
        tendons.append((t.name, T, r, T * np.exp(-sign * t.friction * turning_along(
            r, R[k][:, 0]))))
        k += len(X)
    at = p[k:]
    backbone = np.asarray(result.backbone, float) * 1e3
    rest = (np.asarray(robot.base_position, float)
            + np.outer([0.0, L], np.asarray(robot.base_rotation, float)[:, 0])) * 1e3
    markers = {m: np.asarray(v, float) * 1e3 for m, v in result.markers.items()}
    measured = {m: np.asarray(v, float) * 1e3 for m, v in (measured_markers or {}).items()}
    rod = _finite(np.concatenate([backbone, rest]))
    big = np.ptp(rod, axis=0).max()
    fmax = max([np.linalg.norm(f) for _, f, *_ in loads], default=0.0)
    scale = ARROW * big / fmax if fmax > 0 else 0.0
    arrows = [(a, f * scale, f, s, c) for a, (_, f, s, c) in zip(at, loads)]
    lo, hi = _limits(_finite(np.concatenate(
        [rod, *(r for _, _, r, _ in tendons), _points(markers), _points(measured),
         _points([a - v for a, v, *_ in arrows])])))
    # not pyplot's: a figure a notebook or a sweep keeps is freed with it (pyplot would hold
    # every one until plt.close)
    fig = Figure()
    FigureCanvasAgg(fig)
    axes, cax = [fig.add_axes((0, 0, 1, 1)) for _ in VIEWS], fig.add_axes((0, 0, 1, 1))
    note = result.note if failed is None and result.converged else ""
    where = crossing(robot, result.backbone) if THROUGH_ITSELF in note else None
    Xb = np.linspace(0.0, L, len(backbone))
    rings = None if where is None else np.array(
        [[np.interp(x, Xb, backbone[:, c]) for c in range(3)] for x in where[:2]])
    warning = joined("UNSTABLE EQUILIBRIUM: the rod would leave this shape for another"
                     if UNSTABLE_NOTE in note else "",
                     "PASSES THROUGH ITSELF: the model has no contact, the robot cannot take "
                     "this shape" if THROUGH_ITSELF in note else "",
                     (f"LARGE STRAIN: {strain}; are the values in SI units?")
                     if "large strain: " in note and (strain := stretched(robot, result.backbone))
                     else "")
    remark = ("SETTLED: the stable state the damped rod comes to rest in (the equilibrium "
              "solved for was unstable or not found; see the note)"
              if failed is None and result.converged
              and result.note.startswith(SETTLED_NOTE) else "")
    texts = (title, given, warning, remark)
    tmax = max([T for _, T, _, along in tendons for T in (T, *along)], default=0.0)
    norm = Normalize(0.0, tmax if tmax > 0 else 1.0)
    bar_names = _bar_names(tendons, norm.vmax)
    names_in = max([TextPath((0, 0), n, size=8).get_extents().width / 72
                    for _, n in bar_names], default=0.0)
    pt_per_mm = 72 * _place(fig, axes, cax, lo, hi, texts, names_in)
    X_of = {m.name: m.X for m in robot.markers}
    leaders = []  # each marker's name and where it was first put
    for view, (ax, (name, i, j)) in enumerate(zip(axes, VIEWS)):
        ax.set_title(name, loc="left", fontsize=9)
        ax.set_ylabel(f"{'xyz'[j]} (mm)")
        ax.plot(rest[:, i], rest[:, j], ls="--", color=REST, lw=1.2, zorder=1)
        for _, T, r, along in tendons:
            if T > 0:
                ax.add_collection(LineCollection(
                    np.stack([r[:-1], r[1:]], axis=1)[..., [i, j]], colors=TENSION_CMAP(
                        norm(along)), lw=1.3, zorder=2))
            else:
                ax.plot(r[:, i], r[:, j], color=SLACK, lw=1.3, zorder=2)
        ax.plot(backbone[:, i], backbone[:, j], color="black", lw=2.5, zorder=3)
        ax.plot(*rest[0, [i, j]], marker="s", color="black", ms=8, zorder=4)
        _draw_arrows(ax, view, arrows)
        names = [(m, markers[m], "black") for m in markers]
        names += [(m, xyz, MEASURED) for m, xyz in measured.items() if m not in markers
                  or np.linalg.norm((xyz - markers[m])[[i, j]]) > 0.04 * big]
        for m, xyz, colour in names:
            n = _label_side(backbone, L, X_of.get(m), xyz, i, j, arrows)
            clear = 0.0 if m not in X_of else max([0.0, *(
                (np.array([np.interp(X_of[m], X, r[:, c]) for c in (i, j)]) - xyz[[i, j]]) @ n
                for (_, _, r, _), X in zip(tendons, routes))])
            name = ax.annotate(m, xyz[[i, j]], xytext=(9 + clear * pt_per_mm) * n,
                               fontsize=8, textcoords="offset points", color=colour,
                               bbox=_LABEL_BOX, zorder=6, **_align(n))
            leaders.append((name, tuple(name.xyann)))
        if markers:
            ax.scatter(*_points(markers)[:, [i, j]].T, s=30, fc="white", ec="black", lw=1.2,
                       zorder=5)
        if measured:
            ax.scatter(*_points(measured)[:, [i, j]].T, s=45, marker="x", color=MEASURED,
                       lw=1.8, zorder=5)
        if rings is not None:
            ax.scatter(rings[:, i], rings[:, j], s=260, fc="none", ec="red", lw=1.8,
                       zorder=6)
    for _ in range(3):
        _separate(fig, axes)
        lo, hi = _fit_text(fig, axes, lo, hi)
        _place(fig, axes, cax, lo, hi, texts, names_in)
    for name, first in leaders:  # a name moved off another one: a line to its marker
        if tuple(name.xyann) != first:
            name.axes.annotate("", name.xy, xytext=name.xyann, textcoords="offset points",
                               zorder=5, arrowprops=dict(arrowstyle="-", lw=0.6, alpha=0.6,
                                                         color=name.get_color(), shrinkA=0,
                                                         shrinkB=4))
    if axes[0].get_position().y0 > axes[1].get_position().y1:
        axes[0].tick_params(labelbottom=False)
    else:
        axes[0].set_xlabel("x (mm)")
    axes[1].set_xlabel("x (mm)")
    if tmax > 0:
        _tension_bar(fig, cax, norm, bar_names)
    else:
        cax.remove()
    _legend(fig, axes, tendons, markers, measured, loads, rings is not None)
    _title(fig, axes, title, given, warning, remark)
    if failed is not None or not result.converged:
        _stamp(fig, axes, failed)
    elif warning:  # a solution still: its labels kept clear
        _red_frames(axes)
    return fig


def _finite(pts):
    return pts[np.isfinite(pts).all(axis=1)]


def _points(d):
    return np.array(list(d.values()) if isinstance(d, dict) else d, float).reshape(-1, 3)


def _limits(pts):
    lo, hi = pts.min(0), pts.max(0)
    big = max((hi - lo).max(), 1.0)
    pad = np.maximum(PAD * big, (MIN_SPAN * big - (hi - lo)) / 2)
    return lo - pad, hi + pad


def _place(fig, axes, cax, lo, hi, texts, names_in=0.0) -> float:
    """Size the figure and place the views at one scale (stacked or side by side, whichever
    is larger), with the limits ``lo``, ``hi`` (mm, global x y z), room above them for
    ``texts`` (:func:`_title`'s) and the colour bar with ``names_in`` inches of names on its
    left; the scale in inches per mm."""
    (_, i, j), (_, _, k) = VIEWS
    span = hi - lo
    ex, ez, ey = span[i], span[j], span[k]
    (W, H), (gw, gh) = VIEWS_IN, GAP_IN
    stacked = min(W / ex, (H - gh) / (ez + ey))
    beside = min((W - gw) / (2 * ex), H / max(ez, ey))
    s = max(stacked, beside)
    if stacked >= beside:
        w, h = ex * s, ez * s + gh + ey * s
        boxes = [(0, ey * s + gh, ex * s, ez * s), (0, 0, ex * s, ey * s)]
    else:
        w, h = 2 * ex * s + gw, max(ez, ey) * s
        boxes = [(0, h - ez * s, ex * s, ez * s), (ex * s + gw, h - ey * s, ex * s, ey * s)]
    m, bar = MARGIN_IN, max(0.35, names_in + 0.15)
    fw, fh = m["left"] + w + bar + m["right"], m["bottom"] + h + m["top"] + _head_in(w, *texts)
    fig.set_size_inches(fw, fh)
    for ax, (x, y, bw, bh), (_, a, b) in zip(axes, boxes, VIEWS):
        ax.set_position(((m["left"] + x) / fw, (m["bottom"] + y) / fh, bw / fw, bh / fh))
        ax.set_xlim(lo[a], hi[a])
        ax.set_ylim(lo[b], hi[b])
        ax.set_aspect("equal", adjustable="box")
    cax.set_position(((m["left"] + w + bar) / fw, m["bottom"] / fh, 0.15 / fw, h / fh))
    return s


def _fit_text(fig, axes, lo, hi):
    """The limits widened so that every label lies inside its view."""
    renderer = fig.canvas.get_renderer()
    lo, hi = lo.copy(), hi.copy()
    gap = 0.01 * (hi - lo).max()
    for ax, (_, i, j) in zip(axes, VIEWS):
        for t in ax.texts:
            if t.get_text():
                box = t.get_window_extent(renderer).transformed(ax.transData.inverted())
                lo[[i, j]] = np.minimum(lo[[i, j]], np.array([box.x0, box.y0]) - gap)
                hi[[i, j]] = np.maximum(hi[[i, j]], np.array([box.x1, box.y1]) + gap)
    return lo, hi


def _separate(fig, axes, tries=6):
    """Labels moved a line further from their point (up or down) while they overlap one
    placed before them."""
    renderer = fig.canvas.get_renderer()
    for ax in axes:
        placed: list = []
        for t in (t for t in ax.texts if t.get_text()):
            step = (1 if t.get_va() == "bottom" else -1) * 1.2 * t.get_fontsize()
            for _ in range(tries):
                box = t.get_window_extent(renderer)
                if not any(box.overlaps(b) for b in placed):
                    break
                t.xyann = (t.xyann[0], t.xyann[1] + step)
            placed.append(t.get_window_extent(renderer))


def _estimate_label(e: Estimated) -> str:
    """An estimated force's label: its size ± σ, or with a stuck tendon the range it lies in;
    where its location was estimated, that location ± σ."""
    size = float(np.linalg.norm(e.force))
    text = (newtons(size) + ("" if e.sigma is None else f"\n{spread(e.sigma)}")
            if e.band is None else
            f"{newtons(size)} mid-band;\na stuck tendon: {between(*e.band)}")
    if e.X_sigma is not None:
        text += f"\nat X = {e.X * 1e3:.0f} ± {e.X_sigma * 1e3:.0f} mm"
    return text


def _draw_arrows(ax, view, arrows):
    """Force arrows ending at their point, each labelled beyond its tail (the longest tail of
    the arrows along it) in the view where it is longest (the first of equals); a force
    nearly along the line of sight as ⊙ / ⊗."""
    _, i, j = VIEWS[view]
    out = np.cross(np.eye(3)[i], np.eye(3)[j])
    placed: list = []
    for a, v, f, label, colour in sorted(arrows, key=lambda r: -np.linalg.norm(r[1])):
        v2 = v[[i, j]]
        if not np.linalg.norm(v):
            if view == 0:
                ax.scatter(*a[[i, j]], s=60, color=colour, zorder=4)
                ax.annotate(label, a[[i, j]], xytext=(0, 12), zorder=6,
                            textcoords="offset points", color=colour, fontsize=8,
                            bbox=_LABEL_BOX, ha="center", va="bottom")
            continue
        if np.linalg.norm(v2) < 0.15 * np.linalg.norm(v):
            into = v @ out < 0
            ax.scatter(*a[[i, j]], s=90, fc="none", ec=colour, lw=1.5, zorder=4)
            ax.scatter(*a[[i, j]], s=25 if into else 6, marker="x" if into else "o",
                       color=colour, lw=1.5, zorder=4)
            continue
        tail = a[[i, j]] - v2
        ax.annotate("", a[[i, j]], tail, zorder=4, arrowprops=dict(
            arrowstyle="-|>", color=colour, lw=2, mutation_scale=16, shrinkA=0, shrinkB=0))
        lengths = [np.linalg.norm(v[[c, d]]) for _, c, d in VIEWS]
        if view != int(np.argmax(np.round(lengths, 9))):
            continue
        d = -v2 / np.linalg.norm(v2)
        tail = a[[i, j]] - max((w for b, w, *_ in arrows if np.allclose(a, b, atol=1e-3)
                                and w @ v > 0.95 * np.linalg.norm(w) * np.linalg.norm(v)),
                               key=np.linalg.norm)[[i, j]]
        near = sum(np.linalg.norm(tail - t) < 0.05 * np.linalg.norm(v2) for t in placed)
        placed.append(tail)
        align = _align(d)
        if align["ha"] == "center":
            x0, x1 = ax.get_xlim()
            where = (tail[0] - x0) / (x1 - x0)
            align["ha"] = "right" if where > 2 / 3 else "left" if where < 1 / 3 else "center"
        shift = 5 * d + np.array([0.0, 12.0 * near * (1 if d[1] >= 0 else -1)])
        ax.annotate(label, tail, xytext=shift,
                    textcoords="offset points", color=colour, fontsize=8, bbox=_LABEL_BOX,
                    zorder=6, **align)


def _label_side(backbone, L, X, xyz, i, j, arrows):
    """The unit direction (in the view) in which a marker's name goes: away from the rod (for
    a marker off it), else on the side a force nearby points to (its tail and label are on
    the other), else below."""
    b = _finite(backbone)
    if len(b) < 3:
        return np.array([0.0, -1.0])
    idx = (int(round(X / L * (len(b) - 1))) if X is not None
           else int(np.argmin(np.linalg.norm(b - xyz, axis=1))))
    idx = min(max(idx, 1), len(b) - 2)
    away = (xyz - b[idx])[[i, j]]
    if np.linalg.norm(away) > 0.02 * L * 1e3:
        return away / np.linalg.norm(away)
    t = (b[idx + 1] - b[idx - 1])[[i, j]]
    n = (np.array([-t[1], t[0]]) / np.linalg.norm(t) if np.linalg.norm(t) > 1e-9
         else np.array([0.0, -1.0]))
    pull = sum((v[[i, j]] for a, v, *_ in arrows
                if np.linalg.norm(a - xyz) < 0.05 * L * 1e3), np.zeros(2))
    toward = pull if np.linalg.norm(pull) > 1e-9 else np.array([0.0, -1.0])
    n = n if n @ toward >= 0 else -n
    # not onto another point's arrow that passes by in this view (a curled rod's tip force
    # past a marker near the base): the other side where it is clearer
    reach = 0.08 * L * 1e3  # about where a label's text lies
    shafts = [(a[[i, j]] - v[[i, j]], a[[i, j]]) for a, v, *_ in arrows
              if np.linalg.norm(a - xyz) >= 0.05 * L * 1e3]

    def clearance(d):
        return min((_to_segment(xyz[[i, j]] + reach * d, *s) for s in shafts), default=np.inf)

    return -n if clearance(n) < reach < clearance(-n) else n


def _to_segment(p, a, b) -> float:
    """The distance from point ``p`` to the segment from ``a`` to ``b`` (2-D)."""
    ab = b - a
    t = np.clip((p - a) @ ab / max(ab @ ab, 1e-300), 0.0, 1.0)
    return float(np.linalg.norm(p - (a + t * ab)))


def _align(d) -> dict:
    """Text alignment for a label placed from a point in the direction d."""
    if abs(d[0]) > abs(d[1]):
        return dict(ha="left" if d[0] > 0 else "right", va="center")
    return dict(ha="center", va="bottom" if d[1] > 0 else "top")


def _bar_names(tendons, vmax) -> list[tuple[float, str]]:
    """The tension bar's names: each tendon at its tension at the actuator and, where that
    differs, at its anchor (the first then says "at actuator"); names at about one tension
    joined."""
    ticks = [(T, 0, name) for name, T, _, _ in tendons if T > 0]
    ticks += [(along[-1], 1, name) for name, T, _, along in tendons
              if T > 0 and abs(along[-1] - T) >= 0.04 * vmax]
    groups: list[list] = []
    for T, anchor, name in sorted(ticks):
        if not groups or T - groups[-1][0] >= 0.04 * vmax:
            groups.append([T, [], []])
        groups[-1][1 + anchor].append(name)
    live = {name for _, _, name in ticks}

    def said(names):  # three or more at one tension: "all" (the bar's side is narrow)
        return "all" if len(names) >= 3 and set(names) == live else ", ".join(names)

    fading = {name for _, anchor, name in ticks if anchor}

    def at_actuator(names):
        return said(names) + (" at actuator" if fading & set(names) else
                              " tendons" if said(names) == "all" else "")

    return [(T, "; ".join(filter(None, (actuator and at_actuator(actuator),
                                        anchor and f"{said(anchor)} at anchor"))))
            for T, actuator, anchor in groups]


def _tension_bar(fig, cax, norm, names):
    """The tension colour bar (N) with ``names`` [(tension, name)] on its left."""
    bar = fig.colorbar(ScalarMappable(norm, TENSION_CMAP), cax=cax)
    bar.set_label("tendon tension (N)")
    left = cax.secondary_yaxis("left")
    left.set_yticks([T for T, _ in names], [n for _, n in names], fontsize=8)


def _legend(fig, axes, tendons, markers, measured, loads, crossing=False):
    h = [Line2D([], [], color=REST, ls="--", label="unloaded rod"),
         Line2D([], [], color="black", lw=2.5, label="backbone"),
         Line2D([], [], color="black", marker="s", ls="none", label="clamped base")]
    if markers:
        h.append(Line2D([], [], marker="o", mfc="white", mec="black", ls="none",
                        label="markers"))
    if measured:
        h.append(Line2D([], [], marker="x", color=MEASURED, mew=1.8, ls="none",
                        label="measured markers"))
    if any(T > 0 for _, T, *_ in tendons):
        h.append(Line2D([], [], color=TENSION_CMAP(0.7), label="tendon (colour: its tension)"))
    if any(T <= 0 for _, T, *_ in tendons):
        h.append(Line2D([], [], color=SLACK, label="slack tendon"))
    stuck = any(c == ESTIMATED and "stuck tendon" in label for _, _, label, c in loads)
    estimated = "estimated force (a stuck tendon: its range)" if stuck else \
        "estimated force (± 1 σ in its label)"
    for colour, what in ((KNOWN, "known force"), (ESTIMATED, estimated)):
        if any(c == colour for *_, c in loads):
            h.append(Line2D([], [], color=colour, lw=2, marker=">", label=what))
    if crossing:
        h.append(Line2D([], [], marker="o", ms=12, mfc="none", mec="red", mew=1.8, ls="none",
                        label="passes through itself"))
    left, bottom, right, _ = _extent(axes)
    ncol = 4 if (right - left) * fig.get_figwidth() > 5 else 2
    fig.legend(handles=h, loc="upper center", ncol=ncol, fontsize=8, frameon=False,
               bbox_to_anchor=((left + right) / 2, bottom - 0.45 / fig.get_figheight()))


def _extent(axes):
    """(left, bottom, right, top) of the views, in figure fractions."""
    boxes = [ax.get_position() for ax in axes]
    return (min(b.x0 for b in boxes), min(b.y0 for b in boxes), max(b.x1 for b in boxes),
            max(b.y1 for b in boxes))


def _wrapped(text: str, width_in: float) -> list[str]:
    """``text``'s lines above views ``width_in`` inches wide (9-point characters, each about
    0.55 of the point size wide)."""
    return textwrap.wrap(text, max(int(width_in * 72 / (9 * 0.55)), 20), subsequent_indent="  ")


def _head_in(width_in, title, given, warning="", remark="") -> float:
    """Inches :func:`_title` takes above views ``width_in`` wide."""
    return 0.25 * bool(title) + sum(0.1 + 0.16 * len(_wrapped(t, width_in))
                                    for t in (given, warning, remark) if t)


def _title(fig, axes, title, given, warning="", remark=""):
    left, _, right, top = _extent(axes)
    top += 0.3 / fig.get_figheight()
    for text, style in ((warning, dict(color="red", weight="bold")),
                        (remark, dict(color="#1f4e79", style="italic")), (given, {})):
        if text:
            lines = _wrapped(text, (right - left) * fig.get_figwidth())
            fig.text(left, top, "\n".join(lines), fontsize=9, va="bottom", **style)
            top += (0.1 + 0.16 * len(lines)) / fig.get_figheight()
    if title:
        fig.text(left, top, title, fontsize=11, weight="bold", va="bottom")


def _red_frames(axes):
    for ax in axes:
        for spine in ax.spines.values():
            spine.set(color="red", lw=2)


def _stamp(fig, axes, failed):
    """NOT CONVERGED (and the reason) across the views, their frames red."""
    _red_frames(axes)
    left, bottom, right, top = _extent(axes[:1])  # on the first view, clear of the others
    width = (right - left) * fig.get_figwidth() * 72
    x, y = (left + right) / 2, (bottom + top) / 2
    fig.text(x, y, "NOT CONVERGED", fontsize=float(np.clip(width / (0.85 * 13), 14, 40)),
             color="red", weight="bold", ha="center", va="bottom" if failed else "center",
             alpha=0.8, zorder=10, bbox=dict(fc="white", ec="red", lw=2, alpha=0.5))
    if failed:  # wrapped to the view's width (about 0.55 of the point size per character)
        size = float(np.clip(width / (0.55 * len(failed)), 8, 14))
        fig.text(x, y - 0.08 / fig.get_figheight(),
                 "\n".join(textwrap.wrap(failed, max(int(0.9 * width / (0.55 * size)), 20))),
                 color="red", ha="center", va="top", fontsize=size, zorder=10,
                 bbox=dict(fc="white", ec="none", alpha=0.85))


def sensitivity_single(rows, path):
    """Fig. 3a: estimated force vs tendon length change with the band of each error source;
    an estimate at an unstable equilibrium (a row's ``unstable``) drawn as an open circle."""
    fig, ax = plt.subplots(figsize=(7, 4.5))
    forces = sorted({r["force_gF"] for r in rows})
    shaky = [r for r in rows if r.get("unstable")]
    for f in forces:
        sel = [r for r in rows if r["force_gF"] == f and "estimate_N" in r]
        y = np.array([r["displacement_m"] for r in sel]) * 1e3
        ax.plot(y, [r["estimate_N"] / GF for r in sel], "k.-", lw=1,
                label="estimate, exact readings" if f == forces[0] else None)
        if mark := [r for r in shaky if r["force_gF"] == f]:
            ax.plot([r["displacement_m"] * 1e3 for r in mark],
                    [r["estimate_N"] / GF for r in mark], "o", ms=6, mfc="white", mec="k",
                    zorder=5, label=(f"at an unstable equilibrium ({len(shaky)} of "
                                     f"{sum('estimate_N' in r for r in rows)}: the rod "
                                     f"would leave it)")
                    if mark[0] is shaky[0] else None)
        ax.axhline(f, color="grey", ls=":", lw=0.8,
                   label="applied force" if f == forces[0] else None)
        bands = {s: ([min(r[f"{s}_plus_N"], r[f"{s}_minus_N"]) / GF for r in sel],
                     [max(r[f"{s}_plus_N"], r[f"{s}_minus_N"]) / GF for r in sel])
                 for s in SOURCES}
        width = {s: np.nanmean(np.subtract(hi, lo)) for s, (lo, hi) in bands.items()}
        for s, (lo, hi) in bands.items():  # a narrower band over a wider one, each outlined
            ax.fill_between(y, lo, hi, facecolor=COLOURS[s], alpha=0.25, edgecolor=COLOURS[s],
                            lw=0.8, zorder=1.5 + sum(width[o] > width[s] for o in SOURCES) / 10,
                            label=f"range with a {s} error" if f == forces[0] else None)
    ax.set_xlabel("tendon length change y (mm)")
    ax.set_ylabel("estimated tip force F_z (gF)")
    ax.set_title("Estimated tip force with length, tension and friction errors, one tendon")
    ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.13), ncol=3)
    return _save(fig, path)


def ellipsoids(entries, path):
    """Fig. 3b: estimates of 3-D tip forces under the 27 per-tendon error combinations, with
    their 2-σ ellipsoids, one colour per error source; beside it, each ellipsoid's longest
    2-σ semi-axis (gF), so that ellipsoids hidden inside others are read too."""
    fig = plt.figure(figsize=(12, 6))
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    bars = fig.add_subplot(1, 2, 2)
    u, v = np.mgrid[0:2 * np.pi:16j, 0:np.pi:9j]
    sphere = np.stack([np.cos(u) * np.sin(v), np.sin(u) * np.sin(v), np.cos(v)], -1)
    pts = []
    longest = {s: np.full(len(entries), np.nan) for s in SOURCES}
    for k, e in enumerate(entries):
        F = np.array(e["force_N"]) / GF
        ax.scatter(*F, color="black", s=30, marker="o", label="applied" if k == 0 else None)
        pts.append(F[None])
        for s in SOURCES:
            est = np.array(e[s]["estimates_N"], float).reshape(-1, 3) / GF  # (none: [])
            est = est[np.all(np.isfinite(est), axis=1)]
            if len(est) < 4:
                continue
            c = est.mean(0)
            w, V = np.linalg.eigh(np.cov(est.T))
            longest[s][k] = 2 * np.sqrt(max(w.max(), 0.0))
            surf = c + 2 * (sphere * np.sqrt(np.maximum(w, 0))) @ V.T
            ax.plot_wireframe(*np.moveaxis(surf, -1, 0), color=COLOURS[s], lw=0.4, alpha=0.6,
                              label=f"{s} error" if k == 0 else None)
            pts.append(est)
    _equal_3d(ax, np.concatenate(pts))
    ax.set_xlabel("F_x (gF)")
    ax.set_ylabel("F_y (gF)")
    ax.set_zlabel("F_z (gF)")
    for axis in (ax.xaxis, ax.yaxis, ax.zaxis):  # (seven ticks ran into each other)
        axis.set_major_locator(MaxNLocator(5))
    ax.set_title("Estimated tip forces (2-σ ellipsoids; a small one\nhides inside a larger: "
                 "their sizes at the right)", fontsize=9)
    fig.suptitle("3-D tip forces estimated from three tendons under per-tendon errors")
    ax.legend(handles=[Line2D([], [], ls="", marker="o", color="black", label="applied")]
              + [Line2D([], [], color=COLOURS[s], lw=2, label=f"{s} error") for s in SOURCES],
              fontsize=8, loc="upper left", bbox_to_anchor=(0.0, 0.95))
    width = 0.8 / len(SOURCES)
    idx = np.arange(len(entries))
    for i, s in enumerate(SOURCES):
        bars.bar(idx + (i - (len(SOURCES) - 1) / 2) * width, longest[s], width,
                 color=COLOURS[s], label=f"{s} error")
    bars.set_xticks(idx, ["(" + ", ".join(f"{v:+.0f}" for v in np.array(e["force_N"]) / GF)
                          + ")" for e in entries], rotation=45, ha="right", fontsize=8)
    bars.set_xlabel("applied tip force (gF)")
    bars.set_ylabel("longest 2-σ semi-axis (gF)")
    bars.set_title("Size of each ellipsoid")
    bars.set_ylim(0.0, 1.3 * np.nanmax([np.nanmax(v) for v in longest.values()] + [1e-9]))
    bars.legend(fontsize=8, loc="upper center", ncol=len(SOURCES))
    fig.tight_layout()
    return _save(fig, path, tight=False)


def resolution(rows, path):
    """§IV resolution: each axis' smallest detectable force change over the applied forces
    (a box of the forces solved), from 0, the paper's mean ± standard deviation beneath."""
    from .analyses import PAPER_RESOLUTION_G
    fig, ax = plt.subplots(figsize=(6, 4))
    data = [[v for r in rows if np.isfinite(v := r[f"resolution_{a}_g"])] for a in "xyz"]
    ax.boxplot(data, tick_labels=[f"Δ{a}\n(paper: {m:.2f} ± {sd:.2f})"
                                  for a, (m, sd) in PAPER_RESOLUTION_G.items()])
    ax.set_ylim(0, None)
    ax.set_ylabel("smallest detectable increment (gF)")
    ax.set_title(f"Smallest detectable force change per axis, over {len(data[0])} tip forces"
                 f"\n(tension sensors resolving ±(2.5/3) %)")
    return _save(fig, path)


def comparison(table: dict[str, list], path):
    """Fig. 6: mean relative force error per model and experiment group."""
    models = list(table)
    groups = sorted({r.case.rsplit("-", 1)[0] for r in next(iter(table.values()))})
    fig, ax = plt.subplots(figsize=(7, 4))
    rows = next(iter(table.values()))
    series = [(m, [r.error(r.ours) for r in table[m]], table[m]) for m in models]
    if any(r.paper is not None for r in rows):  # the paper's own estimates, where it gives them
        series.append(("the paper's estimates", [r.error(r.paper) for r in rows], rows))
    width = 0.8 / len(series)
    for i, (name, errors, of) in enumerate(series):
        means = []
        for k, g in enumerate(groups):
            e = [e for e, r in zip(errors, of) if r.case.rsplit("-", 1)[0] == g and np.isfinite(e)]
            means.append(100 * np.mean(e) if e else np.nan)
            if not e and name != "the paper's estimates":  # every row failed: said, not blank
                ax.text(k + i * width, 0, "no estimate", rotation=90, ha="center",
                        va="bottom", fontsize=7, color="red")
        ax.bar(np.arange(len(groups)) + i * width, means, width, label=name,
               color="0.6" if name == "the paper's estimates" else None)
    ax.set_xlim(-0.6 * width - 0.1, len(groups) - 1 + (len(series) - 0.4) * width + 0.1)
    counts = [sum(r.case.rsplit("-", 1)[0] == g for r in rows) for g in groups]
    done = [min(sum(r.converged and r.case.rsplit("-", 1)[0] == g for r in table[m])
                for m in models) for g in groups]
    ax.set_xticks(np.arange(len(groups)) + width * (len(series) - 1) / 2,
                  [f"{g.replace('_', ' ')}\n({n} row{'' if n == 1 else 's'}"
                   + (f", {d} estimated" if d < n else "") + ")"
                   for g, n, d in zip(groups, counts, done)])
    ax.set_xlabel("the paper's experiment (load case)")
    ax.set_ylabel("mean relative error of the estimate (%)")
    ax.set_title("Estimation error of each rod model on the paper's experiments\n(forces; "
                 "the scale of gravity where it is the unknown)", fontsize=10)
    ax.legend()
    return _save(fig, path)


def location_profile(result, path, length_noise: float | None = None):
    """The tendon-length misfit over the X of a force of unknown location (each point the best
    magnitudes with the force held there), the estimate and its 1-σ band, as a PNG; stamped
    NOT CONVERGED (and the reason) when the estimate did not converge. ``length_noise`` (m,
    1 σ), the noise the band assumes, is drawn as a level: a profile that varies less than
    it does not place the force."""
    prof = result.extra["location_profile"]
    X, misfit = np.asarray(prof["X"]), np.asarray(prof["misfit"]) * 1e3
    if X.ndim != 1:
        raise ValueError("a misfit profile is drawn for one force of unknown location")
    loc = [v for v in result.extra["locations"] if v is not None][0]
    sig = [v for v in result.extra["location_sigma"] if v is not None][0]
    order = np.argsort(X)
    fig, ax = plt.subplots(figsize=(6.5, 4))
    ax.plot(X[order] * 1e3, misfit[order], "o-", color="tab:blue", ms=3,
            label="best fit with the force held at X")
    span = (X.max() - X.min()) * 1e3
    wide = 2 * sig * 1e3 > span
    ax.axvspan((loc - sig) * 1e3, (loc + sig) * 1e3, color="tab:red", alpha=0.15,
               label="estimate ± 1 σ" + (" (wider than the range: X not determined)"
                                         if wide else ""))
    ax.axvline(loc * 1e3, color="tab:red",
               label=f"estimate X = {loc * 1e3:.1f} ± {sig * 1e3:.3g} mm")
    if length_noise:
        ax.axhline(length_noise * 1e3, color="0.4", ls=":",
                   label=f"length noise assumed, {length_noise * 1e3:g} mm (1 σ)")
    pad = 0.03 * span  # an estimate at an end of the range stays visible
    ax.set_xlim(X.min() * 1e3 - pad, X.max() * 1e3 + pad)
    # the noise's level inside the frame, not on its edge
    top = np.nanmax([*misfit[np.isfinite(misfit)], (length_noise or 0.0) * 1e3, 0.0])
    if top > 0:  # (a minimum at 0 off the frame's edge too)
        ax.set_ylim(-0.04 * top, 1.1 * top)
    ax.set_xlabel("X where the force acts (mm from the base)")
    ax.set_ylabel("RMS tendon-length misfit (mm)")
    ax.set_title("Where does the force act? Tendon-length misfit over X")
    # below the axes: a profile rises on both sides, and a legend inside would cover it
    ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.17), ncol=2,
              frameon=False)
    fig.set_size_inches(6.5, 4.8)
    fig.tight_layout()
    if not result.converged:
        _stamp(fig, [ax], result.note)
    return _save(fig, path, tight=False)


def calibration(fit, path, source: str | None = None):
    """Per snapshot: the misfit after the fit and, with cross-validation, the error of its
    prediction by the parameters fitted without it (marker and tendon-length errors in mm),
    beside what the noise the fit assumed leaves (a marker's 1-σ per coordinate is √3 σ as
    an RMS distance);
    ``source`` (e.g. the snapshots file) goes in the title with the robot's name and the
    parameters fitted."""
    kinds = [(col, kind) for col, kind in enumerate(("marker", "displacement"))
             if any(e[col] is not None for e in fit.snapshot_errors)]
    parameters = ", ".join(
        f"{k} = {v:.4g}" + ("" if fit.sigma.get(k) is None else f" ± {fit.sigma[k]:.2g}")
        + parameter_words(k)[1] for k, v in fit.parameters.items())
    what = "per-snapshot error" + (" and leave-one-out prediction" if fit.crossval else "")
    if fit.warning:  # said on the figure too, not on standard error alone
        what += "\nWARNING printed with the fit" + (
            f": residuals {fit.misfit:.2g} × the noise assumed" if fit.misfit else "")
    title = "\n".join([f"Calibration of {fit.robot.name}" + (f" from {source}" if source else ""),
                       textwrap.fill(f"fitted {parameters} (1 σ)", 80), what])
    # the title's lines above the panels, not taken from them
    fig, axes = plt.subplots(len(kinds), 1, squeeze=False, figsize=(
        7, 2.8 * len(kinds) + 0.17 * title.count("\n")))
    idx = np.arange(1, len(fit.snapshot_errors) + 1)
    for ax, (col, kind) in zip(axes[:, 0], kinds):
        fitted = np.array([np.nan if e[col] is None else e[col] for e in fit.snapshot_errors])
        width = 0.4 if fit.crossval else 0.8
        ax.bar(idx - (width / 2 if fit.crossval else 0), fitted * 1e3, width,
               color="tab:blue", label="after the fit (every snapshot)")
        top = np.nanmax(np.append(fitted, 0.0))
        if fit.crossval:
            left = np.array([np.nan if getattr(c, f"{kind}_error") is None
                             else getattr(c, f"{kind}_error") for c in fit.crossval])
            ax.bar(idx + width / 2, left * 1e3, width, color="tab:orange",
                   label="predicted, fitted without it")
            top = max(top, np.nanmax(np.append(left, 0.0)))
        if fit.noise is not None:  # what the noise alone leaves, in the same RMS
            level = fit.noise[col] * (np.sqrt(3.0) if kind == "marker" else 1.0)
            ax.axhline(level * 1e3, color="black", ls="--", lw=1, label=(
                f"noise assumed ({'√3 × ' if kind == 'marker' else ''}"
                f"{fit.noise[col] * 1e3:.3g} mm)"))
            top = max(top, level)
        if top > 0:  # (room for the legend above the bars and the noise's line)
            ax.set_ylim(0.0, 1.5 * top * 1e3)
        ax.set_ylabel(f"RMS {'marker' if kind == 'marker' else 'tendon-length'} error (mm)")
        if idx.size <= 30:
            ax.set_xticks(idx)
        else:  # numbers that stay readable
            ax.xaxis.set_major_locator(MaxNLocator(nbins=15, integer=True))
        ax.legend(fontsize=8, loc="upper center", ncol=2)
    axes[-1, 0].set_xlabel("snapshot")
    axes[0, 0].set_title(title, fontsize=9)
    fig.tight_layout()
    return _save(fig, path)


#: the axes of a marker's motion, in colours no tendon takes
AXIS_COLOURS = {"x": "tab:red", "y": "tab:purple", "z": "tab:brown"}


def _repeats(curve, drawn) -> str | None:
    """The name of an earlier curve of ``drawn`` [(name, curve)] that ``curve`` repeats (to
    0.1 µm, 1e-7 N), or None."""
    return next((m for m, c in drawn if np.allclose(curve, c, rtol=0, atol=1e-7,
                                                     equal_nan=True)), None)


def simulation(sim, path, title: str = "simulated motion", given: str = ""):
    """A simulated motion over time: the tensions (N; solid pulled in, dotted stuck at the
    anchor, dashed paid out) and the tendon length changes (mm), a tendon whose curve repeats
    an earlier one's drawn dashed over it, and the last marker's position relative to its
    start (mm);
    samples that did not converge shaded, their shapes left out (no curve through them, as
    the log leaves their cells empty). ``given`` is a second title line."""
    t = sim.time
    bad = ~np.asarray(sim.converged)
    # a converged sample between failed ones: a dot (a line through one point is not drawn)
    alone = np.flatnonzero(~bad & ~np.r_[False, ~bad[:-1]] & ~np.r_[~bad[1:], False]).tolist()
    dots = dict(marker=".", markevery=alone) if alone else {}
    fig, axes = plt.subplots(3, 1, figsize=(7.5, 7), sharex=True)
    drawn = []
    for n, T in sim.tensions.items():
        s = sim.friction_state[n]
        again = _repeats(np.stack([T, s]), drawn)
        drawn.append((n, np.stack([T, s])))
        if again:  # drawn over the earlier one, its gaps showing it
            axes[0].plot(t, T, linestyle=(0, (4, 4)), label=f"{n} (as {again})")
            continue
        # (the state of the anchor's turn: the tendon may slide nearer its actuator)
        phases = [(s >= 1 - EDGE, "-", n),
                  (np.abs(s) < 1 - EDGE, ":", f"{n} stuck at its anchor"),
                  (s <= -1 + EDGE, "--", f"{n} paid out")]
        color = None
        for mask, style, label in phases:
            if mask.any():  # each phase joined to the samples next to it
                near = mask | np.roll(mask, 1) & (np.arange(t.size) > 0)
                line, = axes[0].plot(t, np.where(near, T, np.nan), style, color=color,
                                     label=label)
                color = line.get_color()
    axes[0].set_ylabel("tension (N)")
    drawn = []
    for n, y in sim.displacements.items():
        y = np.where(bad, np.nan, y)
        again = _repeats(y, drawn)
        axes[1].plot(t, y * 1e3, "--" if again else "-", **dots,
                     label=n if again is None else f"{n} (as {again})")
        drawn.append((n, y))
    axes[1].set_ylabel("length change (mm)\n(negative = pulled in)")
    if sim.markers:
        name, p = list(sim.markers.items())[-1]
        for i, a in enumerate("xyz"):
            axes[2].plot(t, np.where(bad, np.nan, p[:, i] - p[0, i]) * 1e3, **dots,
                         color=AXIS_COLOURS[a], label=a)
        axes[2].set_ylabel(f"marker {name}:\nmove from start (mm)")
    else:
        axes[2].set_visible(False)
        axes[1].tick_params(labelbottom=True)  # (the shared axis's numbers were below axes[2])
    for ax in axes[1:]:  # a span under a micrometre: ±0.5 mm, not an offset of 1e-14
        lo, hi = ax.get_ylim()
        if hi - lo < 1e-3:
            ax.set_ylim((lo + hi) / 2 - 0.5, (lo + hi) / 2 + 0.5)
    for ax in axes:
        if bad.any():
            for k in np.flatnonzero(bad):
                ax.axvspan(t[max(k - 1, 0)], t[k], color="tab:red", alpha=0.2, lw=0)
        if ax.get_visible():
            ax.legend(fontsize=8, loc="best")
            ax.grid(alpha=0.3)
    axes[-1 if sim.markers else 1].set_xlabel("time (s)")
    axes[0].set_title(title + ("" if not bad.any() else
                               f" — NOT CONVERGED at {int(bad.sum())} samples (shaded)")
                      + (f"\n{given}" if given else ""), fontsize=10, pad=10)
    fig.tight_layout()
    return _save(fig, path)
