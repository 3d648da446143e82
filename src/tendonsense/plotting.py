"""Figures, drawn headlessly (matplotlib, Agg backend) and written as PNG."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .analyses import GF  # noqa: E402

SOURCES = ("length", "tension", "friction")
COLOURS = {"length": "tab:blue", "tension": "tab:orange", "friction": "tab:green"}


def _save(fig, path) -> Path:
    path = Path(path)
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)
    return path


def _equal_3d(ax, pts):
    pts = np.asarray(pts)
    centre = (pts.max(0) + pts.min(0)) / 2
    half = max((pts.max(0) - pts.min(0)).max() / 2, 1e-3)
    for set_lim, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre):
        set_lim(c - half, c + half)


def shape(result, path, length: float, forces=(), measured_markers=None, title="shape",
          kind="computed", estimated_forces=(), rest=None, tensions=None):
    """3-D backbone (mm), markers and force arrows, written as a PNG.

    ``kind`` names how the shape was obtained ("computed" for forward statics or kinematics,
    "estimated" for an estimate from tendon readings) and labels the legend. ``forces`` are
    known loads and ``estimated_forces`` estimated ones, each ``[(X, f_global N)]``, drawn to
    one scale at the backbone point nearest X (the backbone is sampled uniformly in X over a
    rod of ``length``). ``rest`` (n, 3) is the unloaded centre line (m), drawn dashed;
    ``tensions`` ({name: N}) are listed in the title's second line.
    """
    fig = plt.figure(figsize=(6.5, 5.5))
    ax = fig.add_subplot(projection="3d")
    b = np.asarray(result.backbone) * 1e3
    pts = [b]
    if rest is not None:
        r = np.asarray(rest) * 1e3
        ax.plot(*r.T, color="grey", ls="--", lw=1, label="unloaded rod")
        pts.append(r)
    ax.plot(*b.T, color="tab:red", lw=2.5, label=f"{kind} backbone")
    ax.scatter(*b[0], color="black", marker="s", s=30, label="clamped base")
    if result.markers:
        m = np.array(list(result.markers.values())) * 1e3
        ax.scatter(*m.T, color="tab:red", s=30, label=f"{kind} markers")
    if measured_markers:
        m = np.array(list(measured_markers.values())) * 1e3
        ax.scatter(*m.T, color="black", marker="x", s=40, label="measured markers")
    every = [(X, f, "known") for X, f in forces] + [(X, f, "estimated") for X, f in
                                                     estimated_forces]
    scale = 0.25 * np.ptp(b, axis=0).max() / max([np.linalg.norm(f) for _, f, _ in every]
                                                 + [1e-12])
    colours = {"known": "tab:blue", "estimated": "tab:purple"}
    shown = set()
    for X, f, which in every:
        i = int(round(X / length * (len(b) - 1)))
        p, v = b[i], np.asarray(f) * scale
        ax.quiver(*p, *v, color=colours[which], arrow_length_ratio=0.2,
                  label=None if which in shown else f"{which} force")
        shown.add(which)
        pts.append(np.array([p + v]))
        n = np.linalg.norm(f)
        ax.text(*(p + v), f"{n:.3g} N ({n / GF:.0f} gF)", color=colours[which], fontsize=8)
    _equal_3d(ax, np.concatenate(pts))
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_zlabel("z (mm)")
    if tensions:
        title += "\ntensions: " + ", ".join(f"{k} = {v:.3g} N" for k, v in tensions.items())
    ax.set_title(title, fontsize=10)
    ax.legend(loc="upper left", fontsize=8)
    return _save(fig, path)


def sensitivity_single(rows, path):
    """Fig. 3a: estimated force vs tendon length change with the band of each error source."""
    fig, ax = plt.subplots(figsize=(7, 4.5))
    forces = sorted({r["force_gF"] for r in rows})
    for f in forces:
        sel = [r for r in rows if r["force_gF"] == f and "estimate_N" in r]
        y = np.array([r["displacement_m"] for r in sel]) * 1e3
        ax.plot(y, [r["estimate_N"] / GF for r in sel], "k.-", lw=1,
                label="estimate, exact readings" if f == forces[0] else None)
        ax.axhline(f, color="grey", ls=":", lw=0.8,
                   label="applied force" if f == forces[0] else None)
        for s in SOURCES:
            lo = [min(r[f"{s}_plus_N"], r[f"{s}_minus_N"]) / GF for r in sel]
            hi = [max(r[f"{s}_plus_N"], r[f"{s}_minus_N"]) / GF for r in sel]
            ax.fill_between(y, lo, hi, color=COLOURS[s], alpha=0.25,
                            label=f"range with a {s} error" if f == forces[0] else None)
    ax.set_xlabel("tendon length change y (mm)")
    ax.set_ylabel("estimated tip force F_z (gF)")
    ax.set_title("Estimated tip force with length, tension and friction errors, one tendon")
    ax.legend(fontsize=8)
    return _save(fig, path)


def ellipsoids(entries, path):
    """Fig. 3b: estimates of 3-D tip forces under the 27 per-tendon error combinations, with
    their 2-σ ellipsoids, one colour per error source."""
    fig = plt.figure(figsize=(7, 6))
    ax = fig.add_subplot(projection="3d")
    u, v = np.mgrid[0:2 * np.pi:16j, 0:np.pi:9j]
    sphere = np.stack([np.cos(u) * np.sin(v), np.sin(u) * np.sin(v), np.cos(v)], -1)
    pts = []
    for k, e in enumerate(entries):
        F = np.array(e["force_N"]) / GF
        ax.scatter(*F, color="black", s=30, marker="o", label="applied" if k == 0 else None)
        pts.append(F[None])
        for s in SOURCES:
            est = np.array(e[s]["estimates_N"]) / GF
            est = est[np.all(np.isfinite(est), axis=1)]
            if len(est) < 4:
                continue
            c = est.mean(0)
            w, V = np.linalg.eigh(np.cov(est.T))
            surf = c + 2 * (sphere * np.sqrt(np.maximum(w, 0))) @ V.T
            ax.plot_wireframe(*np.moveaxis(surf, -1, 0), color=COLOURS[s], lw=0.4, alpha=0.6,
                              label=f"{s} error" if k == 0 else None)
            pts.append(est)
    _equal_3d(ax, np.concatenate(pts))
    ax.set_xlabel("F_x (gF)")
    ax.set_ylabel("F_y (gF)")
    ax.set_zlabel("F_z (gF)")
    ax.set_title("Estimated 3-D tip forces under per-tendon errors (2-σ ellipsoids)")
    ax.legend(fontsize=8)
    return _save(fig, path)


def resolution(rows, path):
    fig, ax = plt.subplots(figsize=(6, 4))
    data = [[r[f"resolution_{a}_g"] for r in rows] for a in "xyz"]
    ax.boxplot(data, tick_labels=["Δx", "Δy", "Δz"])
    ax.set_ylabel("smallest detectable increment (g)")
    ax.set_title("Smallest detectable force change per axis\n(tension sensors resolving ±(2.5/3) %)")
    return _save(fig, path)


def comparison(table: dict[str, list], path):
    """Fig. 6: mean relative force error per model and experiment group."""
    models = list(table)
    groups = sorted({r.case.rsplit("-", 1)[0] for r in next(iter(table.values()))})
    fig, ax = plt.subplots(figsize=(7, 4))
    width = 0.8 / len(models)
    for i, m in enumerate(models):
        means = [np.nanmean([r.error(r.ours) for r in table[m]
                             if r.case.rsplit("-", 1)[0] == g]) * 100 for g in groups]
        ax.bar(np.arange(len(groups)) + i * width, means, width, label=m)
    ax.set_xticks(np.arange(len(groups)) + width * (len(models) - 1) / 2, groups)
    ax.set_ylabel("mean relative force error (%)")
    ax.set_title("Force error of each rod model on the paper's experiments")
    ax.legend()
    return _save(fig, path)


def location_profile(result, path):
    """The tendon-length misfit over the X of a force of unknown location (each point the best
    magnitudes with the force held there), the estimate and its 1-σ band, as a PNG."""
    prof = result.extra["location_profile"]
    X, misfit = np.asarray(prof["X"]), np.asarray(prof["misfit"]) * 1e6
    if X.ndim != 1:
        raise ValueError("a misfit profile is drawn for one force of unknown location")
    loc = [v for v in result.extra["locations"] if v is not None][0]
    sig = [v for v in result.extra["location_sigma"] if v is not None][0]
    order = np.argsort(X)
    fig, ax = plt.subplots(figsize=(6.5, 4))
    ax.plot(X[order] * 1e3, misfit[order], "o-", color="tab:blue", ms=3,
            label="best fit with the force held at X")
    ax.axvspan((loc - sig) * 1e3, (loc + sig) * 1e3, color="tab:red", alpha=0.15,
               label="estimate ± 1 σ")
    ax.axvline(loc * 1e3, color="tab:red", label=f"estimate X = {loc * 1e3:.1f} mm")
    ax.set_xlim(X.min() * 1e3, X.max() * 1e3)
    ax.set_xlabel("X where the force acts (mm from the base)")
    ax.set_ylabel("RMS tendon-length misfit (µm)")
    ax.set_title("Where does the force act? Tendon-length misfit over X")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def calibration(fit, path):
    """Per snapshot: the misfit after the fit and, with cross-validation, the error of its
    prediction by the parameters fitted without it (markers in mm, tendon lengths in µm)."""
    kinds = [(k, unit, scale) for k, unit, scale in (("marker", "mm", 1e3),
                                                      ("displacement", "µm", 1e6))
             if any(e[i] is not None for e in fit.snapshot_errors
                    for i in [0 if k == "marker" else 1])]
    fig, axes = plt.subplots(len(kinds), 1, figsize=(7, 2.8 * len(kinds)), squeeze=False)
    n = len(fit.snapshot_errors)
    idx = np.arange(1, n + 1)
    for ax, (kind, unit, scale) in zip(axes[:, 0], kinds):
        col = 0 if kind == "marker" else 1
        fitted = np.array([np.nan if e[col] is None else e[col] for e in fit.snapshot_errors])
        width = 0.4 if fit.crossval else 0.8
        ax.bar(idx - (width / 2 if fit.crossval else 0), fitted * scale, width,
               color="tab:blue", label="after the fit (every snapshot)")
        if fit.crossval:
            left = np.array([np.nan if getattr(c, f"{kind}_error") is None
                             else getattr(c, f"{kind}_error") for c in fit.crossval])
            ax.bar(idx + width / 2, left * scale, width, color="tab:orange",
                   label="predicted, fitted without it")
        ax.set_ylabel(f"RMS {'marker' if kind == 'marker' else 'tendon-length'} error ({unit})")
        ax.set_xticks(idx)
        ax.legend(fontsize=8)
    axes[-1, 0].set_xlabel("snapshot")
    axes[0, 0].set_title("Calibration: per-snapshot error" +
                         (" and leave-one-out prediction" if fit.crossval else ""))
    fig.tight_layout()
    return _save(fig, path)
