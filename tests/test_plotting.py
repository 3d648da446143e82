import dataclasses
from types import SimpleNamespace

import matplotlib
import numpy as np
import pytest

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.collections import LineCollection  # noqa: E402
from matplotlib.colors import to_rgba  # noqa: E402

from tendonsense import plotting  # noqa: E402
from tendonsense.forward import model_for, solve  # noqa: E402
from tendonsense.kinematics import frames_fn  # noqa: E402
from tendonsense.units import newtons, spread  # noqa: E402

TIP = (0.25, np.array([0.0, 0.0, -0.1]))
ESTIMATED = (0.25, np.array([0.0, 0.0, -0.0759]), 0.0027)


@pytest.fixture(scope="module")
def solved(prototype):
    return solve(prototype, {"t1": 2.0}, [(0.25, (0, 0, -0.1))])


@pytest.fixture
def figure(solved, prototype):
    fig = plotting.shape_figure(solved, prototype, forces=[TIP], estimated=[ESTIMATED],
                                title="prototype: shape", given="given: t1 tension 2 N")
    fig.canvas.draw()
    yield fig
    plt.close(fig)


def test_shape_figures_kept_by_nobody_are_freed(solved, prototype, tmp_path):
    """``shape_figure`` made its figure with pyplot, which held every one until ``plt.close``:
    a notebook or a sweep that drew 200 grew by 3.9 MB each. Its figures are now its own:
    none is left with pyplot and one no longer referenced is freed; it still draws and
    saves."""
    import gc
    import weakref
    before = plt.get_fignums()
    fig = plotting.shape_figure(solved, prototype, forces=[TIP])
    assert plt.get_fignums() == before
    fig.savefig(tmp_path / "shape.png")
    assert (tmp_path / "shape.png").stat().st_size > 10_000
    gone = weakref.ref(fig)
    del fig
    gc.collect()
    assert gone() is None


def views(fig):
    return fig.axes[:2]


def texts(ax):
    return [t.get_text() for t in ax.texts if t.get_text()]


def test_frames_fn_gives_the_backbone(solved, prototype):
    model = model_for(prototype)
    X = np.linspace(0.0, prototype.rod.length, len(solved.backbone))
    g = np.asarray(frames_fn(model.structure)(model.values, solved.q, X))
    assert g.shape == (len(X), 4, 4)
    assert np.allclose(g[:, :3, 3], solved.backbone, atol=1e-9)
    assert np.allclose(g[:, :3, :3] @ np.swapaxes(g[:, :3, :3], 1, 2), np.eye(3), atol=1e-9)


def test_shape_writes_a_png(solved, prototype, tmp_path):
    path = plotting.shape(solved, tmp_path / "s.png", prototype, forces=[TIP])
    data = path.read_bytes()
    assert path == tmp_path / "s.png" and data[:8] == b"\x89PNG\r\n\x1a\n"
    width, height = (int.from_bytes(data[k:k + 4], "big") for k in (16, 20))
    assert 600 < width < 1600 and 400 < height < 1400
    assert len(data) > 20_000


def test_views_are_equal_scale_and_tight(figure, solved):
    side, top = views(figure)
    b = solved.backbone * 1e3
    scales = []
    for ax, (i, j) in ((side, (0, 2)), (top, (0, 1))):
        assert ax.get_aspect() == 1.0
        box = ax.get_window_extent()
        (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
        assert (x1 - x0) / box.width == pytest.approx((y1 - y0) / box.height, rel=0.01)
        scales.append((x1 - x0) / box.width)
        assert x0 < b[:, i].min() and b[:, i].max() < x1
        assert y0 < b[:, j].min() and b[:, j].max() < y1
    assert scales[0] == pytest.approx(scales[1], rel=0.01)
    assert np.ptp(b[:, 0]) / np.ptp(side.get_xlim()) > 0.7


def test_labels_name_markers_and_forces_without_overlapping(figure, prototype):
    side, top = views(figure)
    for ax in (side, top):
        assert set(prototype.marker_names) <= set(texts(ax))
        boxes = [t.get_window_extent() for t in ax.texts if t.get_text()]
        assert not any(a.overlaps(b) for k, a in enumerate(boxes) for b in boxes[k + 1:])
    labels = texts(side) + texts(top)
    assert newtons(0.1) in labels
    assert f"{newtons(0.0759)}\n{spread(0.0027)}" in labels and "±" in spread(0.0027)
    assert "NOT CONVERGED" not in [t.get_text() for t in figure.texts]
    assert {"prototype: shape", "given: t1 tension 2 N"} <= {t.get_text() for t in figure.texts}


def test_tendons_coloured_by_tension(figure):
    colours = [to_rgba(line.get_color()) for line in views(figure)[0].lines]
    slack = colours.count(to_rgba(plotting.SLACK))
    assert slack == 2  # t2 and t3
    (t1,) = [c for c in views(figure)[0].collections if isinstance(c, LineCollection)]
    assert len(t1.get_colors()) == 8  # a colour between every two of its nine disks
    bar = figure.axes[2]
    assert bar.get_ylim()[1] == pytest.approx(2.0)  # t1 at its actuator, the largest tension


@pytest.mark.parametrize("direction", ["in", "out", "stuck"])
def test_a_tendons_colour_follows_its_tension_along_it(prototype, direction):
    """Eq. 10 along the drawn tendon: pulled in it fades toward its anchor, paid out it grows,
    stuck (drawn at its band's middle) it is one tension; the tension at the anchor is named
    on the colour bar, at T exp(∓μφ) with φ the model's own turning of the tendon."""
    from tendonsense.sliding import turning_program
    from tendonsense.tendons import turning_along
    sliding = {"t1": "in" if direction == "stuck" else direction}
    result = solve(prototype, {"t1": 2.0}, [(0.25, (0, 0, -0.1))], sliding=sliding)
    model = model_for(prototype)
    phi = float(np.asarray(turning_program(model.structure)(result.q[None], model.values))[0, 0])
    assert phi > 0.5
    fig = plotting.shape_figure(result, prototype, sliding={"t1": direction})
    fig.canvas.draw()
    side = views(fig)[0]
    (t1,) = [c for c in side.collections if isinstance(c, LineCollection)]
    cmap = plotting.TENSION_CMAP(np.linspace(0.0, 1.0, plotting.TENSION_CMAP.N))
    level = [np.argmin(np.abs(cmap - c).sum(axis=1)) for c in t1.get_colors()]
    assert len(level) == len(prototype.tendons[0].disks) - 1
    sign = {"in": 1, "out": -1, "stuck": 0}[direction]
    anchor = 2.0 * np.exp(-sign * 0.4 * phi)
    (names,) = fig.axes[2].child_axes
    ticks = dict(zip((t.get_text() for t in names.get_yticklabels()), names.get_yticks()))
    plt.close(fig)
    if direction == "stuck":
        assert len(set(level)) == 1 and set(ticks) == {"t1"}
        return
    assert (np.diff(level) <= 0).all() if direction == "in" else (np.diff(level) >= 0).all()
    assert level[0] != level[-1]
    assert ticks["t1 at actuator"] == pytest.approx(2.0) and ticks["t1 at anchor"] == pytest.approx(
        anchor, rel=1e-9)
    # the turning of the drawn path is the model's at every disk (its polyline through them)
    r = np.asarray(frames_fn(model.structure)(model.values, result.q, np.asarray(
        prototype.tendons[0].disks)))
    path = r[:, :3, 3] + np.einsum("nij,nj->ni", r[:, :3, :3],
                                   prototype.tendons[0].offset(prototype.tendons[0].disks, 0.25))
    assert turning_along(path, r[0, :3, 0])[-1] == pytest.approx(phi, rel=1e-12)


@pytest.mark.parametrize("failed", ["strain outside the model's range", None])
def test_failed_results_are_stamped(solved, prototype, failed):
    result = solved if failed else dataclasses.replace(solved, converged=False)
    fig = plotting.shape_figure(result, prototype, failed=failed)
    stamp = [t.get_text() for t in fig.texts]
    plt.close(fig)
    assert "NOT CONVERGED" in stamp
    assert (failed in stamp) if failed else len(stamp) == 1


def test_the_stamp_and_its_reason_stay_inside_the_view(solved, prototype):
    """A long reason is wrapped to the view it is stamped on: it once ran past the view's
    left edge over the axis label ("z (mm)" read "z nm")."""
    why = ("the solver stopped after 106 iterations (its load continuation's stages "
           "included) at relative residual 3.95e-03 (tolerance 1e-10)")
    fig = plotting.shape_figure(solved, prototype, failed=why)
    renderer = fig.canvas.get_renderer()
    view = fig.axes[0].get_window_extent(renderer)
    for t in fig.texts:
        if "NOT CONVERGED" in t.get_text() or "solver stopped" in t.get_text():
            box = t.get_window_extent(renderer)
            assert view.x0 - 1 <= box.x0 and box.x1 <= view.x1 + 1, t.get_text()
    plt.close(fig)


def test_an_unstable_equilibrium_is_stamped(prototype):
    """A solution the robot would leave (10 N with 1.2 N hanging at the tip: out of the plane
    of its loads, tests/test_dynamics.py) is drawn saying so; a stable one is not, and the
    state it settles in (``solve(..., settle=True)``) says SETTLED, not unstable."""
    said = []
    for tension in (3.0, 10.0):
        result = solve(prototype, {"t1": tension}, [(0.25, (0.0, 0.0, -1.2))])
        fig = plotting.shape_figure(result, prototype)
        said.append(" ".join(t.get_text() for t in fig.texts))
    assert "UNSTABLE EQUILIBRIUM" not in said[0] and "UNSTABLE EQUILIBRIUM" in said[1]
    assert "NOT CONVERGED" not in said[1]
    settled = solve(prototype, {"t1": 10.0}, [(0.25, (0.0, 0.0, -1.2))], settle=True)
    fig = plotting.shape_figure(settled, prototype)
    said = " ".join(t.get_text() for t in fig.texts)
    assert "SETTLED" in said and "UNSTABLE" not in said and "NOT CONVERGED" not in said
    assert {ax.spines["top"].get_edgecolor() for ax in fig.axes[:2]} != {(1.0, 0.0, 0.0, 1.0)}


def test_calibration_errors_in_mm(monkeypatch, tmp_path):
    monkeypatch.setattr(plotting, "_save", lambda fig, path: fig)
    fit = SimpleNamespace(snapshot_errors=[(0.001, 2e-5), (0.002, 3e-5)], crossval=None,
                          parameters={"young_modulus": 1.0e6}, sigma={"young_modulus": 2e4},
                          robot=SimpleNamespace(name="proto"), warning="far off", misfit=3.0,
                          noise=(5e-4, 1e-4))
    fig = plotting.calibration(fit, tmp_path / "c.png", "snaps.csv (2 snapshots)")
    markers, lengths = fig.axes
    plt.close(fig)
    assert "(mm)" in markers.get_ylabel() and "(mm)" in lengths.get_ylabel()
    # the noise assumed, as the same RMS: a marker's distance √3 σ, a length σ (in mm)
    assert [ax.lines[0].get_ydata()[0] for ax in (markers, lengths)] == pytest.approx(
        [np.sqrt(3) * 0.5, 0.1])
    # the title says what was fitted (± 1 σ, units), to what, and a warning given
    assert markers.get_title() == ("Calibration of proto from snaps.csv (2 snapshots)\n"
                                   "fitted young_modulus = 1e+06 ± 2e+04 Pa (1 σ)\n"
                                   "per-snapshot error\n"
                                   "WARNING printed with the fit: residuals 3 × the noise "
                                   "assumed")
    assert [p.get_height() for p in lengths.patches] == pytest.approx([0.02, 0.03])


def test_a_calibrations_title_does_not_squash_its_panel(monkeypatch, tmp_path):
    """A camera-free calibration of three parameters with a warning has a five-line title,
    which took its height from the one panel below it (1.2 in of 2.8): the figure grows by
    its title's lines instead."""
    monkeypatch.setattr(plotting, "_save", lambda fig, path: fig)
    fit = SimpleNamespace(snapshot_errors=[(None, 2e-5), (None, 3e-5)], crossval=None,
                          parameters={"young_modulus": 1.0e6, "density": 1340.0,
                                      "friction": 0.4},
                          sigma={"young_modulus": 2e4, "density": 9.8, "friction": 0.0095},
                          robot=SimpleNamespace(name="my-robot"), warning="far off",
                          misfit=3.0, noise=(5e-4, 1e-4))
    fig = plotting.calibration(fit, tmp_path / "c.png",
                               "examples/tutorial/snapshots_tendons.csv (13 snapshots)")
    (ax,) = fig.axes
    height = fig.get_size_inches()[1] * ax.get_position().height
    plt.close(fig)
    assert ax.get_title().count("\n") >= 4 and height > 1.8, height


@pytest.mark.parametrize("converged", [True, False])
def test_location_profile_of_a_failed_estimate_is_stamped(monkeypatch, tmp_path, solved,
                                                           converged):
    monkeypatch.setattr(plotting, "_save", lambda fig, path, tight=True: fig)
    why = "the refinement of the location did not converge"
    X = np.linspace(0.05, 0.25, 9)
    result = dataclasses.replace(solved, converged=converged, extra=dict(
        note=why, locations=[0.15], location_sigma=[0.01],
        location_profile={"X": X, "misfit": (X - 0.15) ** 2}))
    fig = plotting.location_profile(result, tmp_path / "p.png")
    stamp = [t.get_text() for t in fig.texts]
    plt.close(fig)
    assert stamp == ([] if converged else ["NOT CONVERGED", why])


def test_a_location_band_wider_than_the_rod_says_so_beside_the_noise(monkeypatch, tmp_path,
                                                                      solved):
    """A profile that varies less than the length noise does not place the force: the band
    (wider than the range) says so and the noise is drawn as a level."""
    monkeypatch.setattr(plotting, "_save", lambda fig, path, tight=True: fig)
    X = np.linspace(0.05, 0.25, 9)
    result = dataclasses.replace(solved, extra=dict(
        locations=[0.2], location_sigma=[0.317],
        location_profile={"X": X, "misfit": 1e-6 * (X - 0.2) ** 2}))
    fig = plotting.location_profile(result, tmp_path / "p.png", length_noise=1e-4)
    labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    plt.close(fig)
    assert "estimate ± 1 σ (wider than the range: X not determined)" in labels
    assert "estimate X = 200.0 ± 317 mm" in labels
    assert "length noise assumed, 0.1 mm (1 σ)" in labels


def test_an_estimated_forces_label_keeps_its_band_on_a_line_of_its_own():
    e = plotting.Estimated(0.3, (0.04981, 0, 0), 0.1539, None, 0.317)
    assert plotting._estimate_label(e) == ("0.04981 N (5.1 gF)\n± 0.15 N (15.7 gF)\n"
                                           "at X = 300 ± 317 mm")


def test_a_simulation_figure_leaves_out_failed_samples_and_keeps_its_time_axis(monkeypatch,
                                                                            tmp_path):
    """Failed samples were drawn as a still rod (the curves flat at the last converged value,
    the length axis at 1e-14 mm); a robot without markers had no numbers on its time axis."""
    kept = []
    monkeypatch.setattr(plotting, "_save", lambda fig, path, tight=True: kept.append(fig))
    t = np.linspace(0.0, 0.5, 11)
    ok = t < 0.2
    y = np.where(ok, -0.01 * t, 0.0)
    sim = SimpleNamespace(time=t, tensions={"t1": 1 + t}, friction_state={"t1": 1 + 0 * t},
                          displacements={"t1": y}, markers={}, converged=ok)
    plotting.simulation(sim, tmp_path / "m.png")
    fig = kept[-1]
    fig.canvas.draw()
    lengths = fig.axes[1]
    drawn = lengths.lines[0].get_ydata()
    assert np.all(np.isnan(drawn[~ok])) and np.allclose(drawn[ok], y[ok] * 1e3)
    assert [tick.get_text() for tick in lengths.get_xticklabels() if tick.get_text()]
    lonely = SimpleNamespace(**{**vars(sim), "converged": t < 0.01})  # one sample: a dot
    plotting.simulation(lonely, tmp_path / "m.png")
    line = kept[-1].axes[1].lines[0]
    assert line.get_marker() == "." and list(line.get_markevery()) == [0]
    kept[-1].canvas.draw()
    assert kept[-1].axes[1].yaxis.get_offset_text().get_text() == ""  # (was "1e-14")
    flat = SimpleNamespace(**{**vars(sim), "displacements": {"t1": -0.003 + 1e-17 * t},
                              "converged": t >= 0})  # a still tendon: ±0.5 mm, no offset
    plotting.simulation(flat, tmp_path / "m.png")
    kept[-1].canvas.draw()
    assert np.diff(kept[-1].axes[1].get_ylim())[0] == pytest.approx(1.0)
    assert kept[-1].axes[1].yaxis.get_offset_text().get_text() == ""
    for f in kept:
        plt.close(f)


def test_a_shape_that_passes_through_itself_is_said_and_stamped():
    """The model has no contact: paper_simulation pulled at 20 N curls its tip into its base
    (a solution of the model's equations the robot cannot take): the note and the figure say
    so, in red; 2 N does not. Every line above the views stays inside the figure when the
    warning takes two lines (it is unstable as well at 6.9 N with 1.2 N at the tip)."""
    from pathlib import Path

    from tendonsense import load_robot
    from tendonsense.forward import THROUGH_ITSELF
    robot = load_robot(Path(__file__).resolve().parents[1] / "examples" /
                       "paper_simulation.toml")
    curled, bent = (solve(robot, {"t1": t}) for t in (20.0, 2.0))
    assert curled.converged and THROUGH_ITSELF in curled.extra["note"]
    assert "X = 0 m" in curled.extra["note"] and THROUGH_ITSELF not in bent.extra.get("note", "")
    fig = plotting.shape_figure(curled, robot)
    said = " ".join(t.get_text() for t in fig.texts)
    assert "PASSES THROUGH ITSELF" in said and "NOT CONVERGED" not in said
    assert {ax.spines["top"].get_edgecolor() for ax in fig.axes[:2]} == {(1.0, 0.0, 0.0, 1.0)}
    for ax in fig.axes[:2]:  # the two places ringed in red
        rings = [c for c in ax.collections if c.get_offsets().shape == (2, 2)
                 and tuple(c.get_edgecolor()[0]) == (1.0, 0.0, 0.0, 1.0)]
        assert len(rings) == 1
    both = solve(robot, {"t1": 6.9}, [(0.25, (0.0, 0.0, -1.2))])
    fig = plotting.shape_figure(both, robot)
    said = [t for t in fig.texts if "UNSTABLE" in t.get_text()]
    assert said and "PASSES THROUGH ITSELF" in said[0].get_text()
    assert said[0].get_text().count("\n") >= 1
    renderer = fig.canvas.get_renderer()
    for t in fig.texts:
        box = t.get_window_extent(renderer)
        assert box.y1 <= fig.bbox.y1 and box.x1 <= fig.bbox.x1, t.get_text()


def test_the_tension_bar_names_every_tendon_at_one_tension_as_all():
    """Three tendons at one tension: "all at actuator" and "all at anchor" beside the bar
    (their names joined crowded its narrow side), "all tendons" without friction; two, or
    some of three, by name; "at actuator" where the tension fades to the anchor (a bare "t1"
    read as a name, not a place)."""
    fades = np.array([1.5, 1.0])
    names = plotting._bar_names([(t, 1.5, None, fades) for t in ("t1", "t2", "t3")], 1.5)
    assert [n for _, n in names] == ["all at anchor", "all at actuator"]
    names = plotting._bar_names([(t, 1.5, None, fades) for t in ("t1", "t2")]
                                + [("t3", 0.0, None, 0 * fades)], 1.5)
    assert [n for _, n in names] == ["t1, t2 at anchor", "t1, t2 at actuator"]
    # without friction one tension along each: the names alone
    names = plotting._bar_names([(t, 1.5, None, fades[:1]) for t in ("t1", "t2", "t3")], 1.5)
    assert [n for _, n in names] == ["all tendons"]


def test_a_marker_name_keeps_off_another_points_arrow():
    """A marker on a straight stretch is named below it, unless another point's arrow passes
    there in this view (a curled rod's tip force past its mid marker ran through "mid"): then
    above."""
    L = 0.25
    backbone = np.stack([np.linspace(0, 250, 51), np.zeros(51), np.zeros(51)], axis=1)
    mid = np.array([125.0, 0.0, 0.0])
    assert plotting._label_side(backbone, L, 0.125, mid, 0, 2, []) @ [0, -1] > 0.99
    by = [(np.array([125.0, 0.0, -70.0]), np.array([0.0, 0.0, -55.0]), None, "", "b")]
    assert plotting._label_side(backbone, L, 0.125, mid, 0, 2, by) @ [0, 1] > 0.99
    far = [(np.array([200.0, 0.0, -70.0]), np.array([0.0, 0.0, -55.0]), None, "", "b")]
    assert plotting._label_side(backbone, L, 0.125, mid, 0, 2, far) @ [0, -1] > 0.99


def test_a_unit_slips_shape_is_stamped_and_its_crowded_names_lead_to_their_markers(
        prototype, figure):
    """Young's modulus typed in kPa: the rod hangs 94 % longer than it is, the note on
    standard error and now on the figure too, in red; in the top view its three markers lie
    within 20 mm, their names moved apart down the view, each with a line to its marker. A
    figure whose names sit beside their markers draws no such line."""
    soft = solve(prototype.with_parameters(young_modulus=1e3))
    assert soft.converged and "large strain: the centre line is 94% longer" in soft.note
    fig = plotting.shape_figure(soft, prototype)
    fig.canvas.draw()
    said = " ".join(t.get_text() for t in fig.texts)
    assert ("LARGE STRAIN: the centre line is 94% longer than the rod at rest; are the "
            "values in SI units?") in said and "NOT CONVERGED" not in said
    assert {ax.spines["top"].get_edgecolor() for ax in fig.axes[:2]} == {(1.0, 0.0, 0.0, 1.0)}
    _, top = views(fig)
    names = {t.get_text(): t for t in top.texts if t.get_text()}
    leaders = _leaders(top)
    moved = [n for n in prototype.marker_names if names[n].xyann[1] < -30]
    assert len(moved) >= 1 and len(leaders) == len(moved)
    for line in leaders:  # from a moved name to its marker
        assert any(np.allclose(line.xy, names[n].xy) and line.xyann == names[n].xyann
                   for n in moved)
    assert not [t for ax in views(figure) for t in _leaders(ax)]
    plt.close(fig)


def _leaders(ax):
    """The lines from a marker's name to it (the force arrows are empty texts too)."""
    return [t for t in ax.texts
            if not t.get_text() and (t.arrowprops or {}).get("arrowstyle") == "-"]
