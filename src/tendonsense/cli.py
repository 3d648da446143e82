"""The ``tendonsense`` command line, a thin layer over the Python API.

Exit status: 0 success, 1 bad input (one line on stderr, nothing on stdout), 2 bad usage,
3 a solve that did not converge (its result is still printed, marked ``converged: false``).
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import sys
import time
from pathlib import Path

import numpy as np

from .robot import RobotFileError, load_robot

DESCRIPTION = """\
Shape and external forces of a tendon-driven soft robot from its tendon readings, with a
Cosserat-rod model. Lengths in metres, forces in newtons, positions in the global frame.
Exit status: 0 success, 1 bad input, 2 bad usage, 3 a solve that did not converge.
Run 'tendonsense COMMAND --help' for the options of one command."""

#: 1 gram-force in newtons
GF = 9.80665e-3


class UsageError(Exception):
    pass


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, no usage dump
        raise UsageError(f"{self.prog}: {message}")


def _assignment(text: str) -> tuple[str, float]:
    name, sep, value = text.partition("=")
    if not sep or not name:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got {text!r}")
    try:
        return name, float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{name}: not a number: {value!r}") from None


def _numbers(n: int, what: str):
    def parse(text: str):
        parts = text.split(",")
        if len(parts) != n:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
        try:
            return tuple(float(p) for p in parts)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what} (numbers), got {text!r}") from None
    return parse


def _common(p: argparse.ArgumentParser):
    p.add_argument("robot", help="the robot file (TOML)")
    p.add_argument("--point-force", action="append", default=[], metavar="X,FX,FY,FZ",
                   type=_numbers(4, "X,FX,FY,FZ"),
                   help="a known force FX, FY, FZ (N, global frame) acting at the distance X "
                        "(m) from the base along the rod; repeatable")
    p.add_argument("--json", action="store_true",
                   help="print the result as one JSON object instead of text")
    p.add_argument("--plot", metavar="SHAPE.png",
                   help="also draw the rod's 3-D shape, its markers and forces into a PNG file "
                        "(and, for a force of unknown location, the misfit over X into "
                        "SHAPE_location.png)")


def _analysis(sub, name, help_text, robot_default):
    p = sub.add_parser(name, help=help_text)
    p.add_argument("--robot", default=robot_default,
                   help=f"the robot file (default: {robot_default})")
    p.add_argument("-o", "--out-dir", default="tendonsense_results",
                   help="folder for the table (CSV and JSON) and the figure (PNG) "
                        "(default: tendonsense_results)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("--quiet", action="store_true", help="do not show a progress bar")
    return p


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="tendonsense", description=DESCRIPTION,
                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    def command(name, summary, description):
        return sub.add_parser(name, help=summary, description=description)

    p = command("solve", "shape from tendon tensions (forward statics)",
                "Compute the rod's shape, tendon length changes and marker positions from the "
                "tendon tensions and any known forces.")
    _common(p)
    p.add_argument("--tension", action="append", default=[], type=_assignment,
                   metavar="NAME=N",
                   help="a tendon's tension in newtons; repeatable; tendons not named are slack")

    p = command("fk", "shape and tensions from tendon length changes (forward kinematics)",
                "Compute the rod's shape and the tensions needed for the given tendon length "
                "changes (negative = pulled in).")
    _common(p)
    p.add_argument("--displacement", action="append", default=[], type=_assignment,
                   metavar="NAME=M",
                   help="a tendon's length change in metres (negative = pulled in); repeatable")
    p.add_argument("--tension", action="append", default=[], type=_assignment,
                   metavar="NAME=N",
                   help="the tension (N) of a tendon whose length change is not given")

    p = command("estimate", "shape and unknown forces from tendon readings (estimation)",
                "Estimate the rod's shape and the size of unknown loads from measured tendon "
                "length changes and tensions: one reading given on the command line, or every "
                "row of a readings log (--readings). Each unknown needs one measured tendon; "
                "with more measured tendons than unknowns the estimate is a least-squares fit. "
                "Every magnitude comes with a 1-sigma band for sensor noise.")
    _common(p)
    p.add_argument("--displacement", action="append", default=[], type=_assignment,
                   metavar="NAME=M",
                   help="a measured tendon length change in metres (negative = pulled in)")
    p.add_argument("--tension", action="append", default=[], type=_assignment,
                   metavar="NAME=N", help="a measured tendon tension in newtons")
    p.add_argument("--unknown", action="append", default=[], type=_unknown, required=True,
                   metavar="X,DX,DY,DZ|gravity",
                   help="an unknown load: a force of unknown size along the global direction "
                        "(DX, DY, DZ) acting at the distance X (m) from the base, or 'gravity' "
                        "for an unknown scale of the robot's weight; repeatable")
    p.add_argument("--readings", metavar="READINGS.csv",
                   help="estimate every row of a readings log (CSV); '-' reads the log live "
                        "from standard input")
    p.add_argument("-o", "--output", metavar="OUT.csv",
                   help="with --readings: write the results to this CSV file once every row "
                        "is done; without it, or with '-', each result row goes to standard "
                        "output as soon as it is estimated")
    p.add_argument("--length-noise", type=_positive, default=1e-4, metavar="M",
                   help="standard deviation of the tendon length sensors in metres, for the "
                        "uncertainty band (default 0.0001 m = 0.1 mm)")
    p.add_argument("--tension-noise", type=_positive, default=0.025 / 3, metavar="FRACTION",
                   help="standard deviation of the tension sensors as a fraction of the "
                        "reading (default 0.00833, i.e. 2.5 %% / 3)")
    p.add_argument("--quiet", action="store_true", help="do not show a progress bar")
    p.add_argument("--view", action="store_true",
                   help="with --readings: show the estimates live in a 3-D view in the browser "
                        "(needs the optional package viser); a file log is replayed at its "
                        "time stamps")
    _view_options(p)

    p = command("view", "explore a robot in a live 3-D view in the browser",
                "Serve an interactive view of the robot's forward statics: a slider per tendon "
                "tension and one point force (X, direction, size); the shape, disks, tendons "
                "and markers are redrawn as they change. Needs the optional package viser "
                "(pip install 'tendonsense[view]'). Ctrl-C ends it.")
    p.add_argument("robot", help="the robot file (TOML)")
    _view_options(p)
    p.add_argument("--max-tension", type=_positive, default=5.0, metavar="N",
                   help="the tension sliders' range, N (default 5)")
    p.add_argument("--max-force", type=_positive, default=1.0, metavar="N",
                   help="the point force slider's range, N (default 1)")

    p = command("identify", "fit stiffness, density or friction to measured poses (calibration)",
                "Fit the Young's modulus, density and/or friction coefficients of the robot "
                "file to static poses (snapshots): marker positions, the tendons' own length "
                "readings (no camera needed), or both.")
    p.add_argument("robot", help="the robot file (TOML); its values are the starting guess")
    p.add_argument("--snapshots", required=True, metavar="SNAPSHOTS.csv",
                   help="the measured poses: tensions, an optional known load, marker "
                        "positions and/or tendon length changes, one row per pose")
    p.add_argument("--param", action="append", metavar="NAME",
                   help="a parameter to fit: young_modulus, density, friction (one μ for every "
                        "tendon) or friction_<tendon>; repeatable (default: young_modulus and "
                        "density)")
    p.add_argument("--marker-noise", type=_positive, default=1e-3, metavar="M",
                   help="standard deviation of a marker coordinate, m (default 0.001)")
    p.add_argument("--length-noise", type=_positive, default=1e-4, metavar="M",
                   help="standard deviation of a tendon length reading, m (default 0.0001)")
    p.add_argument("--crossval", action="store_true",
                   help="also refit without each snapshot and report how well it is predicted")
    p.add_argument("--plot", metavar="FIGURE.png",
                   help="write a figure of the per-snapshot errors (and the cross-validation)")
    p.add_argument("-o", "--output", metavar="FITTED.toml",
                   help="write a copy of the robot file with the fitted values")
    p.add_argument("--json", action="store_true",
                   help="print the result as one JSON object instead of text")

    p = _analysis(sub, "sensitivity", "how errors in tendon length, tension and friction "
                  "change the estimated force (the paper's Fig. 3a and 3b)",
                  "examples/paper_simulation.toml")
    p.add_argument("--points", type=int, default=9,
                   help="tendon length changes per force in the one-tendon study (default 9)")
    _analysis(sub, "resolution", "the smallest force change the tension sensors can resolve "
              "(the paper's Section IV)", "examples/paper_simulation.toml")
    p = _analysis(sub, "compare", "this model against the paper's simpler rod models on the "
                  "paper's experiments (the paper's Fig. 6)", "examples/paper_prototype.toml")
    p.add_argument("csv", nargs="?", default="examples/paper_experiments.csv",
                   help="the experiments table (default: examples/paper_experiments.csv)")

    p = command("experiments", "re-run the paper's experiments (its Tables II to IV)",
                "Estimate every row of the paper's experiments and compare with the applied "
                "loads and the paper's own estimates.")
    p.add_argument("csv", nargs="?", default="examples/paper_experiments.csv",
                   help="the experiments table (default: examples/paper_experiments.csv)")
    p.add_argument("--robot", default="examples/paper_prototype.toml",
                   help="the robot file (default: examples/paper_prototype.toml)")
    p.add_argument("--json", action="store_true",
                   help="print the result as one JSON object instead of text")
    return parser


def _unknown(text: str):
    from .estimation import GravityUnknown, PointForceUnknown
    if text.strip().lower() == "gravity":
        return GravityUnknown()
    what = "X,DX,DY,DZ (X a number, '?' or A:B) or gravity"
    where, _, rest = text.partition(",")
    where = where.strip()
    try:
        if where == "?":
            X = None
        elif ":" in where:
            X = tuple(float(v) for v in where.split(":"))
        else:
            X = float(where)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
    d = _numbers(3, what)(rest)
    try:
        return PointForceUnknown(X, tuple(d))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _view_options(p):
    p.add_argument("--port", type=int, default=8080, metavar="N",
                   help="the view's port (default 8080)")
    p.add_argument("--host", default="127.0.0.1",
                   help="the address to serve the view on (default 127.0.0.1, this machine "
                        "only); another address exposes it to the network")


def _open_view(args, robot, title=None, pause=False):
    from .view import ViewProcess, explore
    if not 0 < args.port < 65536:
        raise UsageError(f"tendonsense {args.command}: --port {args.port}: not a port number")
    if args.host not in ("127.0.0.1", "localhost", "::1"):
        print(f"tendonsense: warning: the view is served on {args.host}:{args.port}, visible "
              f"to other machines on the network", file=sys.stderr)
    if args.command == "view":
        viewer = explore(robot, args.port, args.host, args.max_tension, args.max_force)
    else:
        viewer = ViewProcess(robot, args.port, args.host, title, pause)
    print(f"tendonsense: view at http://{args.host}:{args.port}", file=sys.stderr)
    return viewer


def _view(args, robot):
    """Serve until Ctrl-C."""
    viewer = _open_view(args, robot)
    try:
        while True:
            time.sleep(0.5)
    except KeyboardInterrupt:
        pass
    finally:
        viewer.close()


def _positive(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (v > 0 and v < float("inf")):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text!r}")
    return v


def _beside(path: str, suffix: str) -> str:
    """``shape.png`` → ``shape_location.png``."""
    p = Path(path)
    return str(p.with_name(p.stem + suffix + p.suffix))


def _point_forces(args):
    return [(pf[0], pf[1:]) for pf in args.point_force]


def _plot_shape(args, robot, result, unknowns=()):
    if not getattr(args, "plot", None):
        return
    from . import plotting
    from .estimation import PointForceUnknown
    estimated = []
    if result.magnitudes is not None:
        where = result.extra.get("locations") or [None] * len(unknowns)
        estimated = [(u.X if where[i] is None else where[i],
                      result.magnitudes[i] * np.asarray(u.direction))
                     for i, u in enumerate(unknowns) if isinstance(u, PointForceUnknown)]
    if "location_profile" in result.extra:
        plotting.location_profile(result, _beside(args.plot, "_location"))
    what = {"solve": "shape under the given tensions (forward statics)",
            "fk": "shape for the given tendon length changes (forward kinematics)",
            "estimate": "shape and force estimated from tendon readings"}[args.command]
    X = np.linspace(0.0, robot.rod.length, 2)
    rest = np.asarray(robot.base_position) + X[:, None] * np.asarray(robot.base_rotation)[:, 0]
    plotting.shape(result, args.plot, robot.rod.length, _point_forces(args),
                   title=f"{robot.name}: {what}",
                   kind="estimated" if args.command == "estimate" else "computed",
                   estimated_forces=estimated, rest=rest,
                   tensions={k: v for k, v in result.tensions.items() if v > 0})


class _Progress:
    """A tqdm bar on stderr, shown on a terminal unless --quiet."""

    def __init__(self, args, what):
        from tqdm import tqdm
        self.bar = tqdm(total=0, desc=what, file=sys.stderr, leave=False,
                        disable=getattr(args, "quiet", False) or not sys.stderr.isatty())

    def __call__(self, done, total):
        self.bar.total = total
        self.bar.n = done
        self.bar.refresh()

    def close(self):
        self.bar.close()


def _analysis_run(args):
    from pathlib import Path

    from . import analyses, plotting
    from .readings import write_csv_atomic, write_text_atomic
    robot = load_robot(args.robot)
    out = Path(args.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    prog = _Progress(args, args.command)
    files = []
    if args.command == "sensitivity":
        rows = analyses.sensitivity_single(robot, n_y=args.points, progress=prog)
        entries = analyses.sensitivity_3d(robot, progress=prog)
        summary = {"single_tendon": analyses.single_summary(rows),
                   "three_tendons": analyses.summary_3d(entries)}
        keys = sorted({k for r in rows for k in r})
        write_csv_atomic(out / "sensitivity_single.csv", keys,
                         [[r.get(k, "") for k in keys] for r in rows])
        write_text_atomic(out / "sensitivity_3d.json", json.dumps(entries))
        ok = all("note" not in r and all(np.isfinite(v) for k, v in r.items()
                                           if k.endswith("_N")) for r in rows) \
            and all(e["converged"] for e in entries)
        files += [out / "sensitivity_single.csv", out / "sensitivity_3d.json",
                  plotting.sensitivity_single(rows, out / "sensitivity_single.png"),
                  plotting.ellipsoids(entries, out / "sensitivity_3d.png")]
    elif args.command == "resolution":
        rows = analyses.resolution(robot, progress=prog)
        summary = analyses.resolution_summary(rows)
        ok = all(r["converged"] for r in rows)
        keys = ["force_gF", "resolution_x_g", "resolution_y_g", "resolution_z_g", "converged"]
        write_csv_atomic(out / "resolution.csv", keys,
                         [[" ".join(map(str, r[k])) if k == "force_gF" else r[k] for k in keys]
                          for r in rows])
        files += [out / "resolution.csv", plotting.resolution(rows, out / "resolution.png")]
    else:
        from . import experiments
        table = analyses.compare(robot, args.csv, progress=prog)
        summary = {m: experiments.summary(rows) for m, rows in table.items()}
        ok = all(r.converged for rows in table.values() for r in rows)
        write_csv_atomic(out / "compare.csv", ["model", "case", "applied", "estimate", "error"],
                         [[m, r.case, " ".join(map(str, r.applied)),
                           "" if r.ours is None else " ".join(map(str, r.ours)), r.error(r.ours)]
                          for m, rows in table.items() for r in rows])
        files += [out / "compare.csv", plotting.comparison(table, out / "compare.png")]
    prog.close()
    write_text_atomic(out / f"{args.command}_summary.json", json.dumps(summary, indent=1))
    files.append(out / f"{args.command}_summary.json")
    if args.json:
        print(json.dumps({"summary": summary, "files": [str(f) for f in files]}))
    else:
        print(_summary_text(args.command, summary))
        print("wrote " + ", ".join(str(f) for f in files))
    return ok


def _summary_text(command: str, summary: dict) -> str:
    """The summary of an analysis in words, with units, beside the paper's figures."""
    pct = lambda v: f"{100 * v:.1f} %"  # noqa: E731
    lines = []
    if command == "sensitivity":
        lines.append("one tendon: relative error of the estimated tip force under each error "
                     "(this run; the paper)")
        for src, v in summary["single_tendon"].items():
            lines.append(f"  {src} error: mean {pct(v['mean'])}, max {pct(v['max'])} "
                         f"(paper: mean {pct(v['paper_mean'])}, max {pct(v['paper_max'])})")
        lines.append("three tendons: mean relative error of the estimated 3-D tip force "
                     "(over the applied forces)")
        for src, v in summary["three_tendons"].items():
            lo, hi = v["paper_range"]
            lines.append(f"  {src} error: mean {pct(v['mean'])}, from "
                         f"{pct(v['min_over_forces'])} to {pct(v['max_over_forces'])} "
                         f"(paper: {pct(lo)} to {pct(hi)})")
    elif command == "resolution":
        lines.append("smallest detectable change of each tip-force component "
                     "(mean ± standard deviation over the applied forces)")
        for axis, v in summary.items():
            m, sd = v["mean_g"], v["std_g"]
            lines.append(f"  along {axis}: {m * GF:.3g} N ({m:.2f} gF) ± {sd * GF:.3g} N "
                         f"({sd:.2f} gF) (paper: {v['paper_mean_g']:.2f} ± "
                         f"{v['paper_std_g']:.2f} gF)")
    else:
        lines.append("mean relative error of the estimated loads on the paper's experiments")
        for model, v in summary.items():
            lines.append(f"  {model}: {pct(v['mean_relative_error_ours'])} "
                         f"({v['converged']}/{v['rows']} rows converged; the paper's own "
                         f"estimates: {pct(v['mean_relative_error_paper'])})")
    return "\n".join(lines)


def _vector(v) -> str:
    return "(" + ", ".join(f"{x:.4g}" for x in v) + ")"


def unknown_label(u) -> str:
    """Words for an unknown load, e.g. "force at X = 0.25 m along (0, 0, -1)"."""
    from .estimation import PointForceUnknown
    if isinstance(u, PointForceUnknown):
        where = ("somewhere on the rod" if u.X is None else
                 f"somewhere in X = {u.X[0]:g}:{u.X[1]:g} m" if u.located else f"at X = {u.X:g} m")
        return f"force {where} along {_vector(u.direction)}"
    return "gravity scale (1 = the robot file's gravity)"


def magnitude_text(u, value: float, sigma=None) -> str:
    """A magnitude with its unit, e.g. "0.0759 N (7.7 gF) ± 0.0027 N (1 sigma)"."""
    from .estimation import PointForceUnknown
    band = ""
    if isinstance(u, PointForceUnknown):
        if sigma is not None:
            band = f" ± {sigma:.2g} N (1 σ)"
        return f"{value:.4g} N ({value / GF:.1f} gF){band}"
    if sigma is not None:
        band = f" ± {sigma:.2g} (1 σ)"
    return f"{value:.4g}{band}"


def _print_result(result, as_json: bool, title: str, robot, unknowns=()):
    if as_json:
        print(json.dumps(result.to_json()))
        return
    state = "converged" if result.converged else "NOT CONVERGED"
    print(f"{title} ({robot.name}): {state} in {result.iterations} iterations "
          f"(relative residual {result.residual:.1e})")
    if result.magnitudes is not None:
        print("estimated loads:")
        for i, m in enumerate(result.magnitudes):
            s = result.sigma[i] if result.sigma is not None else None
            u = unknowns[i] if i < len(unknowns) else None
            label = unknown_label(u) if u is not None else f"magnitude {i + 1}"
            print(f"  {label}: {magnitude_text(u, m, s)}")
            X = result.extra.get("locations", [None] * (i + 1))[i]
            if X is not None:
                sx = result.extra["location_sigma"][i]
                print(f"    acting at X = {X:.4g} m ± {sx * 1e3:.2g} mm (1 σ)")
    if result.extra.get("note"):
        print(f"note: {result.extra['note']}")
    print("tendons (length change: negative = pulled in):")
    for name in result.tensions:
        T, y = result.tensions[name], result.displacements[name]
        print(f"  {name}: tension {T:.4f} N ({T / GF:.1f} gF), "
              f"length change {y:+.6f} m ({y * 1e3:+.3f} mm)")
    print("markers (global frame, x y z):")
    X = {m.name: m.X for m in robot.markers}
    for name, p in result.markers.items():
        print(f"  {name} (X = {X.get(name, float('nan')):g} m): "
              f"{' '.join(f'{v:+.4f}' for v in p)} m  "
              f"({' '.join(f'{v * 1e3:+.1f}' for v in p)} mm)")


def _estimate(args, robot):
    from .estimation import Noise, estimate
    noise = Noise(args.length_noise, args.tension_noise)
    if args.readings is None:
        if args.view:
            raise UsageError("tendonsense estimate: --view goes with --readings")
        if args.output:
            raise UsageError("tendonsense estimate: -o/--output goes with --readings")
        result = estimate(robot, dict(args.displacement), dict(args.tension), args.unknown,
                          _point_forces(args), noise)
        _print_result(result, args.json, "estimation", robot, args.unknown)
        _plot_shape(args, robot, result, args.unknown)
        return result.converged
    from . import readings as rd
    if args.displacement or args.tension:
        raise UsageError("tendonsense estimate: --readings replaces --displacement/--tension")
    if args.output in (None, "-"):
        return _stream(args, robot, noise)
    if args.view:
        raise UsageError("tendonsense estimate: --view streams the rows to standard output; "
                         "leave out -o (or redirect standard output)")
    if args.readings == "-":
        lines = sys.stdin
        try:
            columns = rd.parse_header(next(csv.reader(lines)), robot, "<stdin>")
        except StopIteration:
            raise rd.ReadingsError("<stdin>: no header row") from None
        samples = []
        try:
            for i, raw in enumerate(csv.reader(lines), start=1):
                if any(c.strip() for c in raw):
                    samples.append(rd.parse_row(i, raw, columns, robot))
        except KeyboardInterrupt:
            pass  # estimate what has been read
        measured = columns.measured
    else:
        measured, samples = rd.read_readings(args.readings, robot)
    prog = _Progress(args, "estimate")
    results = rd.estimate_readings(robot, measured, samples, args.unknown, _point_forces(args),
                                   noise, progress=prog)
    prog.close()
    for s in samples:
        if s.error:
            print(f"tendonsense: {args.readings}: row {s.row} skipped: {s.error}",
                  file=sys.stderr)
    header, rows = rd.output_rows(robot, samples, results, len(args.unknown),
                                  rd.located(args.unknown))
    rd.write_csv_atomic(args.output, header, rows)
    ok = [r for r in results if r is not None and r.converged]
    summary = {"samples": len(samples), "converged": len(ok),
               "skipped": sum(r is None for r in results), "output": str(args.output)}
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"estimated {len(samples)} samples: {len(ok)} converged, "
              f"{summary['skipped']} skipped; wrote {args.output}")
    return len(ok) == len(samples)


def _stream(args, robot, noise) -> bool:
    """Output rows on stdout as they are estimated; an interrupt ends cleanly."""
    from . import readings as rd

    source = "<stdin>" if args.readings == "-" else args.readings

    def skipped(s):
        print(f"tendonsense: {source}: row {s.row} skipped: {s.error}", file=sys.stderr)

    fh = sys.stdin if args.readings == "-" else open(args.readings, newline="")
    viewer = on_sample = None
    lines, forces = fh, _point_forces(args)
    if args.view:
        replay = args.readings != "-"
        viewer = _open_view(args, robot, f"{robot.name}: " + (
            f"replay of {args.readings}" if replay else "live readings"), pause=replay)

        def push(s, r):
            viewer.push(r, tensions=s.tensions, forces=forces, unknowns=args.unknown,
                        time_s=s.time, note="" if r is not None else s.error)

        on_sample = push

        if replay:
            lines = _paced(fh, viewer)
    rows = good = 0
    try:
        with fh:
            rows, good = rd.stream_readings(robot, lines, sys.stdout, args.unknown, forces,
                                            noise, source, skipped, on_sample)
        if viewer is not None and args.readings != "-":
            print("tendonsense: the log is done; the view stays until Ctrl-C", file=sys.stderr)
            while True:
                time.sleep(0.5)
    except KeyboardInterrupt:
        return True
    except BrokenPipeError:  # the reader went away: stop quietly
        sys.stderr.close()
        return True
    finally:
        if viewer is not None:
            viewer.close()
    return good == rows


def _paced(lines, viewer):
    """The lines of a log file at the pace of its time stamps (column ``time``), held while
    the view is paused."""
    rows = csv.reader(lines)
    header = next(rows, None)
    if header is None:
        return
    yield ",".join(header) + "\n"
    col = header.index("time") if "time" in header else None
    start = first = None
    for raw in rows:
        while viewer.paused:
            time.sleep(0.05)
            start = None  # resume from here
        try:
            t = float(raw[col]) if col is not None else None
        except (ValueError, IndexError):
            t = None
        if t is not None:
            now = time.monotonic()
            if start is None:
                start, first = now, t
            time.sleep(max(0.0, start + (t - first) - now))
        out = io.StringIO()
        csv.writer(out).writerow(raw)
        yield out.getvalue()


def _experiments(args) -> bool:
    from . import experiments
    robot = load_robot(args.robot)
    prog = _Progress(args, "experiments")
    rows = experiments.run(robot, args.csv, progress=prog)
    prog.close()
    summary = experiments.summary(rows)
    if args.json:
        print(json.dumps({"cases": [{"case": r.case, "applied": r.applied.tolist(),
                                    "estimate": None if r.ours is None else r.ours.tolist(),
                                    "paper_estimate": None if r.paper is None else r.paper.tolist(),
                                    "converged": r.converged} for r in rows], **summary}))
        return summary["converged"] == summary["rows"]
    print("estimated load magnitudes (N for forces, a scale factor for gravity) against the "
          "applied ones")
    print(f"{'case':<18} {'applied':>22} {'ours':>22} {'paper':>22} {'err ours':>9} "
          f"{'err paper':>9}")
    fmt = lambda v: "-" if v is None else " ".join(f"{x:.4f}" for x in v)  # noqa: E731
    for r in rows:
        print(f"{r.case:<18} {fmt(r.applied):>22} {fmt(r.ours):>22} {fmt(r.paper):>22} "
              f"{r.error(r.ours):>9.1%} {r.error(r.paper):>9.1%}")
    print(f"mean relative error: ours {summary['mean_relative_error_ours']:.1%}, paper "
          f"{summary['mean_relative_error_paper']:.1%}; {summary['converged']}/"
          f"{summary['rows']} rows converged")
    return summary["converged"] == summary["rows"]


PARAMETER_WORDS = {"young_modulus": ("Young's modulus E", " Pa"),
                   "density": ("density ρ", " kg/m³"),
                   "friction": ("friction coefficient μ", "")}


def _mm(v):
    return "—" if v is None else f"{v * 1e3:.3f} mm"


def _identify(args, robot) -> bool:
    from .identification import identify, read_snapshots
    from .robot import robot_to_toml
    snapshots = read_snapshots(args.snapshots, robot)
    prog = _Progress(args, "identify")
    fit = identify(robot, snapshots, args.param or ("young_modulus", "density"), progress=prog,
                   marker_noise=args.marker_noise, length_noise=args.length_noise,
                   crossval=args.crossval)
    prog.close()
    if args.output:
        from .readings import write_text_atomic
        write_text_atomic(args.output, robot_to_toml(fit.robot))
    if args.plot:
        from . import plotting
        plotting.calibration(fit, args.plot)
    if args.json:
        print(json.dumps(fit.to_json()))
    else:
        print(f"identification ({robot.name}, {len(snapshots)} snapshots): "
              f"{'converged' if fit.converged else 'NOT CONVERGED'} in {fit.iterations} "
              f"iterations")
        for k, v in fit.parameters.items():
            label, unit = PARAMETER_WORDS.get(k, (f"friction coefficient μ of tendon "
                                                  f"{k.partition('_')[2]}", ""))
            print(f"  {label} ({k}): {v:.6g}{unit}")
        if fit.marker_rmse is not None:
            print(f"  marker RMSE: {_mm(fit.marker_rmse)} after the fit, "
                  f"{_mm(fit.initial_marker_rmse)} with the robot file's values")
        if fit.displacement_rmse is not None:
            print(f"  tendon-length RMSE: {_mm(fit.displacement_rmse)} after the fit, "
                  f"{_mm(fit.initial_displacement_rmse)} with the robot file's values")
        if fit.crossval:
            print("  cross-validation (each snapshot predicted by a fit without it):")
            for c in fit.crossval:
                errs = ", ".join(f"{w} {_mm(v)} (fitted {_mm(f)})" for w, v, f in (
                    ("markers", c.marker_error, c.fitted_marker_error),
                    ("lengths", c.displacement_error, c.fitted_displacement_error))
                    if f is not None)
                print(f"    snapshot {c.snapshot}: {errs}" + (f"; {c.note}" if c.note else ""))
        if args.plot:
            print(f"  wrote {args.plot}")
        if args.output:
            print(f"  wrote {args.output}")
    return fit.converged


def main(argv=None) -> int:
    try:
        args = build_parser().parse_args(argv)
        if args.command == "experiments":
            return 0 if _experiments(args) else 3
        if args.command in ("sensitivity", "resolution", "compare"):
            return 0 if _analysis_run(args) else 3
        robot = load_robot(args.robot)
        if args.command == "identify":
            return 0 if _identify(args, robot) else _not_converged()
        if args.command == "view":
            _view(args, robot)
            return 0
        from . import forward
        if args.command == "estimate":
            return 0 if _estimate(args, robot) else _not_converged()
        if args.command == "solve":
            result = forward.solve(robot, dict(args.tension), _point_forces(args))
            _print_result(result, args.json, "forward statics", robot)
            _plot_shape(args, robot, result)
        elif args.command == "fk":
            result = forward.forward_kinematics(robot, dict(args.displacement),
                                                dict(args.tension), _point_forces(args))
            _print_result(result, args.json, "forward kinematics", robot)
            _plot_shape(args, robot, result)
    except UsageError as exc:
        print(exc, file=sys.stderr)
        return 2
    except (RobotFileError, ValueError, OSError) as exc:  # a ViewError is an OSError
        print(f"tendonsense: error: {exc}", file=sys.stderr)
        return 1
    return 0 if result.converged else _not_converged()


def _not_converged() -> int:
    print("tendonsense: not every solve converged (marked converged = false)", file=sys.stderr)
    return 3


if __name__ == "__main__":
    sys.exit(main())
