"""A live 3-D view in the browser (viser, an optional extra: ``pip install tendonsense[view]``).

:class:`Viewer` serves a scene of the robot — backbone, disks, tendons coloured by their
tension along them (eq. 10, as the shape figures),
markers, force arrows (a located force at its X with its 1-σ band along the rod) — with the
numbers beside it and a time plot of the last seconds. :meth:`Viewer.push` only stores the
newest result; a drawing thread redraws it at a bounded rate, so that the estimator it
watches is never slowed. :func:`explore` adds sliders for the tensions and one point force
(``tendonsense view``).
"""

from __future__ import annotations

import contextlib
import math
import os
import socket
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass, field

import jax.numpy as jnp
import numpy as np

from . import inputs
from .forward import model_for, solve
from .kinematics import frames_fn
from .robot import Robot
from .tendons import turning_along

#: redraws per second at most
RATE = 25.0

#: seconds of history in the time plot
HISTORY = 10.0

#: points drawn along a located force's 1-σ band
BAND_POINTS = 25
ALERT = 3.0  # s a refused or non-converged sample stays marked

BACKBONE = (230, 110, 0)
DISKS = (60, 90, 200)
MARKERS = (20, 20, 20)
FORCE = (200, 20, 60)
BAND = (255, 60, 90)


class ViewError(OSError):
    """The view cannot start (viser missing, the port taken); the message says why."""


def _viser():
    try:
        import viser
    except ImportError:
        raise ViewError("the 3-D view needs the optional package viser: "
                        "pip install 'tendonsense[view]'") from None
    return viser


@dataclass
class Shown:
    """What one redraw shows: the shape (q), tensions, forces [(X, f N global)], located
    forces' σ bands [(X, σ)], the text beside the scene, one time-plot sample and each
    tendon's friction sign (:func:`~tendonsense.inputs.friction_signs`; None: pulled in)."""

    q: np.ndarray
    tensions: np.ndarray
    forces: list = field(default_factory=list)
    bands: list = field(default_factory=list)
    text: str = ""
    plot: dict | None = None  # {"t": s, series name: value}
    ok: bool = True
    signs: np.ndarray | None = None


class Viewer:
    """A browser view of ``robot`` at http://HOST:PORT (127.0.0.1 unless ``host`` says
    otherwise; port 0 takes any free one, :attr:`port` tells). Push any result
    (:meth:`push`); the scene shows the newest at ≤ ``rate`` Hz."""

    def __init__(self, robot: Robot, port: int = 8080, host: str = "127.0.0.1",
                 rate: float = RATE, title: str | None = None):
        viser = _viser()
        with socket.socket() as s:  # viser would silently move to the next free port
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                s.bind((host, port))
            except OSError as exc:
                raise ViewError(f"cannot serve the view on {host}:{port}: "
                                f"{exc.strerror or exc}") from None
            port = s.getsockname()[1]  # port 0: any free one
        with contextlib.redirect_stdout(sys.stderr):  # stdout may carry a CSV stream
            self.server = viser.ViserServer(host=host, port=port, verbose=False)
        if self.server.get_port() != port:  # taken between the check and the start
            with contextlib.redirect_stdout(sys.stderr):
                self.server.stop()
            raise ViewError(f"cannot serve the view on {host}:{port}: the port is taken")
        self.robot, self.model = robot, model_for(robot)
        self.port, self.host = port, host
        self._geometry = frames_fn(self.model.structure)
        L = robot.rod.length
        self._X = np.linspace(0.0, L, 101)
        self._setup_scene(title or robot.name)
        self.history: deque = deque()
        self.samples = deque(maxlen=200)  # arrival times, for samples/s
        self.paused = False
        self._drawing = threading.Lock()
        self._latest: tuple | None = None  # the newest push, not drawn yet
        self._last: tuple | None = None  # (Shown, tip) drawn last
        self._alert: tuple | None = None  # (reason, time) of the last refused sample
        self._connected = False  # a browser connected since the last redraw
        self._cond = threading.Condition()
        self._period = 1.0 / rate
        self._stop = False
        self.draws = 0
        self._thread = threading.Thread(target=self._loop, name="tendonsense-view", daemon=True)
        self._thread.start()
        self.server.on_client_connect(self._show_last)

    # ------------------------------------------------------------------ scene
    def _setup_scene(self, title):
        sv, robot = self.server, self.robot
        sv.gui.configure_theme(show_share_button=False, control_width="large")
        sv.request_share_url = lambda *a, **k: None  # never open a tunnel to a relay
        g = np.asarray(robot.gravity, float)
        up = -g / np.linalg.norm(g) if np.linalg.norm(g) > 0 else np.array([0.0, 0.0, 1.0])
        sv.scene.set_up_direction(tuple(up))
        R, p0, L = np.asarray(robot.base_rotation), np.asarray(robot.base_position), robot.rod.length
        centre = p0 + R[:, 0] * L / 2
        side = np.cross(R[:, 0], up)  # seen from the side, the base on the left
        side = side / np.linalg.norm(side) if np.linalg.norm(side) > 1e-9 else R[:, 1]
        sv.initial_camera.look_at = tuple(centre)
        sv.initial_camera.position = tuple(centre + 0.9 * L * side + 0.35 * L * up)
        sv.initial_camera.near = 1e-3 * L
        self._title = sv.gui.add_markdown(f"**{title}**")
        r = max(k[1] for k in robot.rod.radius_knots)
        straight = p0 + np.outer(self._X, R[:, 0])
        self.backbone = sv.scene.add_spline_catmull_rom(
            "/backbone", points=straight, color=BACKBONE, thickness=6.0,
            thickness_units="screen")
        self.markers = sv.scene.add_point_cloud(
            "/markers", points=np.zeros((max(len(robot.markers), 1), 3)), colors=MARKERS,
            point_size=0.6 * r, point_shape="circle", visible=bool(robot.markers))
        disks = sorted({x for t in robot.tendons if not t.continuous for x in t.disks})
        self._disk_X = np.array(disks, float)
        self.disks = sv.scene.add_point_cloud(
            "/disks", points=np.zeros((max(len(disks), 1), 3)), colors=DISKS,
            point_size=0.5 * r, point_shape="circle", visible=bool(disks))
        self.tendons = []  # a segment between two points of its route: its own tension
        for t in robot.tendons:
            n = len(self._X) if t.continuous else len(t.disks)
            segments = np.stack([straight[:n - 1], straight[1:n]], axis=1)
            self.tendons.append(sv.scene.add_line_segments(
                f"/tendons/{t.name}", points=segments,
                colors=np.full(segments.shape, 120, np.uint8), thickness=2.0,
                thickness_units="screen"))
        self.arrows = None
        self.bands = []
        self.text = sv.gui.add_markdown("")
        self.plot = None
        self._plot_keys: tuple = ()

    # ------------------------------------------------------------------ input
    def push(self, result, tensions=None, forces=(), unknowns=(), time_s=None,
             note: str = "") -> None:
        """Show ``result`` (a :class:`~tendonsense.result.Result` or a
        :class:`~tendonsense.tracking.SampleEstimate`) at the next redraw; returns at once.
        ``tensions`` ({tendon: N}) default to the result's; ``forces`` are known point forces
        [(X, f)]; ``unknowns`` the estimated ones, in the order of the result's magnitudes;
        ``note`` marks a refused sample (``result`` None) with its reason."""
        now = time.monotonic()
        self.samples.append(now)
        if result is None or not bool(result.converged):  # marked for a while, even if a
            self._alert = (_reason(result, note), now)  # newer sample is drawn first
        with self._cond:  # turned into a scene by the drawing thread
            self._latest = (result, tensions, forces, unknowns, time_s, note, now)
            self._cond.notify()

    def _shown(self, result, tensions, forces, unknowns, time_s, note, now):
        robot, nq = self.robot, self.model.nq
        if result is None:
            return None
        x = np.asarray(getattr(result, "x", None) if getattr(result, "q", None) is None
                       else result.q, float)
        T = dict(getattr(result, "tensions", {}) or {})
        T.update(tensions or {})
        Tv = np.array([float(T.get(n, 0.0)) for n in robot.tendon_names])
        shown_forces = [(float(X), np.asarray(f, float)) for X, f in forces]
        lines, bands, plot = [], [], {"t": now if time_s is None else float(time_s)}
        mags = getattr(result, "magnitudes", None)
        converged = bool(result.converged)
        if mags is not None and converged:
            sig = np.asarray(getattr(result, "sigma", np.zeros(len(mags))), float)
            extra = getattr(result, "extra", {}) or {}
            per_unknown = "locations" in extra  # a Result: one entry per unknown
            locs = extra.get("locations", getattr(result, "locations", ()))
            loc_sig = extra.get("location_sigma", getattr(result, "location_sigma", ()))
            k_loc = 0
            for i, (u, m, s) in enumerate(zip(unknowns, mags, sig)):
                where = ""
                direction = np.asarray(getattr(u, "direction", (0, 0, 0)), float)
                X = getattr(u, "X", None)
                if getattr(u, "located", False):
                    j = i if per_unknown else k_loc  # a SampleEstimate: located ones only
                    X, sX = float(locs[j]), float(loc_sig[j])
                    k_loc += 1
                    bands.append((float(X), float(sX)))
                    where = f" at X = {X * 1e3:.1f} ± {sX * 1e3:.1f} mm"
                elif X is not None:
                    where = f" at X = {float(X) * 1e3:.1f} mm"
                if X is not None and np.linalg.norm(direction) > 0:
                    shown_forces.append((float(X), m * direction))
                lines.append(f"F{i + 1} = {m:.4f} ± {s:.4f} N{where}")
                plot[f"F{i + 1} (N)"] = float(m)
                plot[f"F{i + 1} − σ"] = float(m - s)
                plot[f"F{i + 1} + σ"] = float(m + s)
        for n, v in zip(robot.tendon_names, Tv):
            plot[f"T {n} (N)"] = float(v)
        q = x[:nq]
        if not np.all(np.isfinite(q)):  # a sample that failed: the last shape stays
            q = self._last[0].q if self._last is not None else np.zeros(nq)
        tip = None
        if getattr(result, "backbone", None) is not None:
            tip = np.asarray(result.backbone)[-1]
        status = "converged" if converged else f"⚠ NOT CONVERGED: {_reason(result, note)}"
        disp = getattr(result, "displacements", None)
        rows = [f"**{status}**", *lines]
        if disp:
            rows.append("length changes: " + ", ".join(
                f"{n} {v * 1e3:+.3f} mm" for n, v in disp.items()))
        rows.append("tensions: " + ", ".join(f"{n} {v:.3f} N"
                                             for n, v in zip(robot.tendon_names, Tv)))
        said = getattr(result, "sliding", ()) or ()  # a series' sample: each tendon's
        signs = inputs.friction_signs(robot, dict(zip(robot.tendon_names, said)) or None)
        return Shown(q, Tv, shown_forces, bands, "  \n".join(rows), plot, converged,
                     signs), tip

    # ------------------------------------------------------------------ drawing
    def _loop(self):
        while True:
            with self._cond:
                while ((self._latest is None and not self._connected) or self.paused
                       ) and not self._stop:
                    self._cond.wait(0.25)
                if self._stop:
                    return
                latest, self._latest, self._connected = self._latest, None, False
            start = time.monotonic()
            try:
                if latest is None:  # a browser connected: the newest scene, not drawn yet
                    if self._last is not None:
                        self.draw(*self._last)
                    continue
                shown = self._shown(*latest)
                if shown is None and self._last is not None:  # the last shape, refused
                    shown = _refused(self._last, latest[5], latest[4] or latest[6])
                if shown is not None:
                    self._last = shown
                    if self.server.get_clients():
                        self.draw(*shown)
                    else:  # nobody watching: only the time plot's history
                        self._record(shown[0].plot)
            except Exception as exc:  # the view must never take the estimator down
                print(f"tendonsense view: redraw failed: {exc}", file=sys.stderr)
            time.sleep(max(0.0, self._period - (time.monotonic() - start)))

    def _show_last(self, _client):
        with self._cond:
            self._connected = True
            self._cond.notify()

    def draw(self, shown: Shown, tip=None) -> None:
        """Redraw the scene for ``shown`` (the drawing thread's work; public for timing)."""
        with self._drawing:
            self._draw(shown, tip)

    def _draw(self, shown: Shown, tip) -> None:
        robot, values = self.robot, self.model.values
        L = robot.rod.length
        band_X = [np.linspace(max(X - s, 0.0), min(X + s, L), BAND_POINTS)
                  for X, s in shown.bands]
        X = np.concatenate([self._X, self._disk_X, [m.X for m in robot.markers],
                            [f[0] for f in shown.forces], *band_X]).astype(float)
        g = np.asarray(self._geometry(values, jnp.asarray(shown.q), jnp.asarray(X)))
        p, R = g[:, :3, 3], g[:, :3, :3]
        n, nd, nm, nf = len(self._X), len(self._disk_X), len(robot.markers), len(shown.forces)
        backbone = p[:n]
        with self.server.atomic():
            self.backbone.points = backbone
            if nd:
                self.disks.points = p[n:n + nd]
            if nm:
                off = np.array([m.offset for m in robot.markers], float)
                self.markers.points = p[n + nd:n + nd + nm] + np.einsum(
                    "nij,nj->ni", R[n + nd:n + nd + nm], off)
            paths, along = [], []
            signs = np.ones(len(robot.tendons)) if shown.signs is None else shown.signs
            for j, t in enumerate(robot.tendons):
                if t.continuous:
                    Xs, P, Rs = self._X, p[:n], R[:n]
                else:
                    idx = [n + int(np.searchsorted(self._disk_X, x)) for x in t.disks]
                    Xs, P, Rs = np.array(t.disks), p[idx], R[idx]
                paths.append(P + np.einsum("nij,nj->ni", Rs, t.offset(Xs, L)))
                along.append(shown.tensions[j] * np.exp(  # eq. 10, each segment's tension
                    -signs[j] * t.friction * turning_along(paths[-1], Rs[0][:, 0])))
            Tmax = max([float(a.max(initial=0.0)) for a in along] + [1e-12])
            for j, (path, T) in enumerate(zip(paths, along)):
                colours = np.array([_tension_colour(v / Tmax if shown.tensions[j] > 0 else -1)
                                    for v in T], np.uint8)
                self.tendons[j].points = np.stack([path[:-1], path[1:]], axis=1)
                self.tendons[j].colors = np.repeat(colours[:, None], 2, axis=1)
            self._draw_forces(shown, p[n + nd + nm:n + nd + nm + nf], L)
            self._draw_bands(p[n + nd + nm + nf:].reshape(len(band_X), BAND_POINTS, 3))
            if tip is None:
                tip = backbone[-1]
            rate = self._rate()
            alert = ""
            if self._alert is not None and shown.ok:
                why, at = self._alert
                if time.monotonic() - at < ALERT:
                    alert = (f"  \n⚠ {time.monotonic() - at:.1f} s ago a sample was refused or "
                             f"did not converge: {why}")
            self.text.content = (shown.text + f"  \ntip: {tip[0] * 1e3:.1f}, {tip[1] * 1e3:.1f}, "
                                 f"{tip[2] * 1e3:.1f} mm  \n{rate:.1f} samples/s{alert}")
            if shown.plot:
                self._draw_plot(shown.plot)
        self.draws += 1

    def _draw_forces(self, shown, at, L):
        if not shown.forces:
            if self.arrows is not None:
                self.arrows.visible = False
            return
        f = np.array([v for _, v in shown.forces], float)
        size = np.linalg.norm(f, axis=1, keepdims=True)
        length = 0.3 * L * size / max(float(size.max()), 1e-12)
        heads = at - f / np.maximum(size, 1e-12) * length  # the arrow ends at the point
        pts = np.stack([heads, at], axis=1)
        if self.arrows is None or len(self.arrows.points) != len(pts):
            if self.arrows is not None:
                self.arrows.remove()
            self.arrows = self.server.scene.add_arrows(
                "/forces", points=pts, colors=FORCE, shaft_radius=0.006 * L,
                head_radius=0.015 * L, head_length=0.04 * L)
        else:
            self.arrows.points = pts
            self.arrows.visible = True

    def _draw_bands(self, points):
        """The 1-σ band of each located force along the rod."""
        while len(self.bands) > len(points):
            self.bands.pop().remove()
        for k, pts in enumerate(points):
            if k < len(self.bands):
                self.bands[k].points = pts
            else:
                self.bands.append(self.server.scene.add_spline_catmull_rom(
                    f"/bands/{k}", points=pts, color=BAND, thickness=14.0,
                    thickness_units="screen"))

    def _record(self, sample):
        if not sample or (self.history and self.history[-1] is sample):
            return
        self.history.append(sample)
        while self.history and sample["t"] - self.history[0]["t"] > HISTORY:
            self.history.popleft()

    def _draw_plot(self, sample):
        self._record(sample)
        if self.plot is None and len(self.history) < 2:  # no line to draw yet: no empty axes
            return
        keys = tuple(k for k in sample if k != "t")
        t0 = self.history[-1]["t"]
        data = (np.array([h["t"] - t0 for h in self.history]),
                *(np.array([h.get(k, math.nan) for h in self.history]) for k in keys))
        if self.plot is None or keys != self._plot_keys:
            if self.plot is not None:
                self.plot.remove()
            self._plot_keys = keys
            series = ({"label": "time (s)"}, *({"label": k, "stroke": _series_colour(k, i)}
                                               for i, k in enumerate(keys)))
            self.plot = self.server.gui.add_uplot(
                data=data, series=series, scales={"x": {"time": False}},
                title=f"the last {HISTORY:g} s", aspect=1.6)
        else:
            self.plot.data = data

    def add_pause(self):
        """A pause control (a replayed log waits while it is set)."""
        box = self.server.gui.add_checkbox("pause", initial_value=False)

        @box.on_update
        def _(_event):
            self.paused = bool(box.value)

        return box

    def _rate(self) -> float:
        s = self.samples
        if len(s) < 2 or s[-1] == s[0]:
            return 0.0
        return (len(s) - 1) / (s[-1] - s[0])

    def close(self):
        """Stop drawing and serving."""
        with self._cond:
            self._stop = True
            self._cond.notify()
        self._thread.join(timeout=2)
        with contextlib.redirect_stdout(sys.stderr):
            self.server.stop()


def _reason(result, note):
    """Why a sample was refused or did not converge."""
    return note or getattr(result, "note", "") or (getattr(result, "extra", {}) or {}).get(
        "note", "")


def _refused(last, note, t):
    shown, tip = last
    text = f"**⚠ SAMPLE REFUSED: {note}**  \n" + shown.text.split("  \n", 1)[-1]
    return Shown(shown.q, shown.tensions, shown.forces, shown.bands, text,
                 {**(shown.plot or {}), "t": t}, False, shown.signs), tip


def _tension_colour(level: float):
    """Grey for a slack tendon, blue → red with the tension's share of the largest."""
    if level < 0:
        return (150, 150, 150)
    return (int(40 + 215 * level), 60, int(230 - 200 * level))


def _series_colour(key: str, i: int) -> str:
    palette = ("#1f77b4", "#2ca02c", "#9467bd", "#8c564b", "#17becf", "#7f7f7f")
    if "σ" in key:
        return "rgba(214, 39, 40, 0.45)"
    if key.startswith("F"):
        return "#d62728"
    return palette[i % len(palette)]


def explore(robot: Robot, port: int = 8080, host: str = "127.0.0.1", max_tension: float = 5.0,
            max_force: float = 1.0) -> Viewer:
    """Interactive forward statics: a slider per tendon tension and one point force (X,
    direction, magnitude); every change solves and redraws (``tendonsense view``). A tension
    slider ends at ``max_tension`` or at the largest tension a reading may have
    (:func:`~tendonsense.inputs.tension_error`), whichever is less."""
    viewer = Viewer(robot, port, host, title=f"{robot.name}: forward statics")
    gui, L = viewer.server.gui, robot.rod.length
    top = {n: min(max_tension, np.floor(100 * inputs.max_tension(robot, n)) / 100)
           for n in robot.tendon_names}
    sliders = {n: gui.add_slider(f"tension {n} (N)", min=0.0, max=top[n], step=0.01,
                                 initial_value=0.0) for n in robot.tendon_names}
    force_X = gui.add_slider("force X (m)", min=0.0, max=L, step=L / 200, initial_value=L)
    force_size = gui.add_slider("force (N)", min=0.0, max=max_force, step=max_force / 200,
                                initial_value=0.0)
    force_dir = gui.add_vector3("force direction", initial_value=(0.0, 0.0, -1.0), step=0.1)
    state = {"q": None, "dirty": True}
    lock = threading.Lock()

    def changed(_=None):
        with lock:
            state["dirty"] = True

    for w in (*sliders.values(), force_X, force_size, force_dir):
        w.on_update(changed)

    def solver():
        while not viewer._stop:
            with lock:
                dirty, state["dirty"] = state["dirty"], False
            if not dirty:
                time.sleep(0.02)
                continue
            T = {n: float(s.value) for n, s in sliders.items()}
            d = np.asarray(force_dir.value, float)
            f = (d / np.linalg.norm(d) if np.linalg.norm(d) > 0 else d) * float(force_size.value)
            forces = [(float(force_X.value), f)] if np.linalg.norm(f) > 0 else []
            res = solve(robot, T, forces, q0=state["q"])
            if res.converged:
                state["q"] = res.q
            viewer.push(res, forces=forces)

    threading.Thread(target=solver, name="tendonsense-explore", daemon=True).start()
    return viewer


class ViewProcess:
    """A :class:`Viewer` in a process of its own (``estimate --view``), so that the redraws
    never hold this process's interpreter and an estimator beside it keeps its pace.
    :meth:`push` only keeps the sample: a thread sends the newest one at the view's rate
    (a refused or non-converged one at once), so that a fast stream does not pickle every
    row."""

    def __init__(self, robot: Robot, port: int = 8080, host: str = "127.0.0.1",
                 title: str | None = None, pause: bool = False):
        import multiprocessing
        ctx = multiprocessing.get_context("spawn")
        self._conn, child = ctx.Pipe()
        self._proc = ctx.Process(target=_serve, args=(robot, port, host, title, pause, child),
                                 name="tendonsense-view", daemon=True)
        self._proc.start()
        child.close()
        kind, value = self._conn.recv()
        if kind == "error":
            self._proc.join(timeout=5)
            raise ViewError(value)
        self.port, self._paused = value, False
        self._cond, self._sending = threading.Condition(), threading.Lock()
        self._pending, self._count, self._closed = None, 0, False
        self._sender = threading.Thread(target=self._send_newest, name="tendonsense-view-send",
                                        daemon=True)
        self._sender.start()

    def push(self, result, **kwargs) -> None:
        """As :meth:`Viewer.push`; returns at once."""
        with self._cond:
            self._count += 1
            if result is not None and bool(result.converged):
                self._pending = (result, kwargs)
                self._cond.notify()
                return
            msg, self._pending, self._count = (result, kwargs, self._count), None, 0
        self._send(msg)

    def _send_newest(self):
        while True:
            with self._cond:
                while self._pending is None and not self._closed:
                    self._cond.wait()
                if self._pending is None:
                    return
                msg = (*self._pending, self._count)
                self._pending, self._count = None, 0
            self._send(msg)
            time.sleep(1.0 / RATE)

    def _send(self, msg):
        with self._sending:
            with contextlib.suppress(OSError):  # the view went away: the estimates go on
                self._conn.send(msg)

    @property
    def paused(self) -> bool:
        """Whether the view's pause control is set."""
        while self._conn.poll():
            self._paused = self._conn.recv()
        return self._paused

    def close(self):
        """Send the newest sample, then stop the view process."""
        with self._cond:
            self._closed = True
            self._cond.notify()
        self._sender.join(timeout=5)
        self._send(None)
        self._proc.join(timeout=5)
        if self._proc.is_alive():
            self._proc.terminate()


def _serve(robot, port, host, title, pause, conn):
    """The view process: push what arrives, the newest drawn at the viewer's rate; at a lower
    priority than the estimator, so that on a busy machine its redraws wait, not the rows."""
    sys.stdout = sys.stderr  # the parent's standard output may carry a CSV stream
    with contextlib.suppress(OSError, AttributeError):
        os.nice(10)
    try:
        viewer = Viewer(robot, port, host, title=title)
    except ViewError as exc:
        conn.send(("error", str(exc)))
        return
    if pause:
        box = viewer.add_pause()
        box.on_update(lambda _: conn.send(bool(box.value)))
    conn.send(("ready", viewer.port))
    try:
        while (msg := conn.recv()) is not None:
            result, kwargs, count = msg
            viewer.samples.extend([time.monotonic()] * (count - 1))  # sent as one
            viewer.push(result, **kwargs)
    except (EOFError, OSError):  # the parent went away
        pass
    viewer.close()
