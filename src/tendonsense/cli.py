"""The ``tendonsense`` command line (SPEC §4), a thin layer over the Python API.

Exit status: 0 success, 1 bad input (one line on stderr, nothing on stdout), 2 bad usage,
3 a solve that did not converge (its result is still printed, marked ``converged: false``).
"""

from __future__ import annotations

import argparse
import csv
import json
import sys

import numpy as np

from .robot import RobotFileError, load_robot


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
    p.add_argument("robot", help="robot description file (TOML, SPEC §3)")
    p.add_argument("--point-force", action="append", default=[], metavar="X,FX,FY,FZ",
                   type=_numbers(4, "X,FX,FY,FZ"),
                   help="known point force (global frame, N) at material abscissa X (m)")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.add_argument("--plot", metavar="SHAPE.png", help="draw the 3-D shape with its forces")


def _analysis(sub, name, help_text, robot_default):
    p = sub.add_parser(name, help=help_text)
    p.add_argument("--robot", default=robot_default, help=f"robot file (default: {robot_default})")
    p.add_argument("-o", "--out-dir", default="tendonsense_results",
                   help="folder for the table (CSV and JSON) and the figure (PNG)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON on stdout")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="tendonsense", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    p = sub.add_parser("solve", help="forward statics: tensions -> shape")
    _common(p)
    p.add_argument("--tension", action="append", default=[], type=_assignment,
                   metavar="NAME=N", help="tendon tension (N); tendons not named are slack")

    p = sub.add_parser("fk", help="forward kinematics (eq. 16): tendon length changes -> shape, tensions")
    _common(p)
    p.add_argument("--displacement", action="append", default=[], type=_assignment,
                   metavar="NAME=M", help="tendon length change (m, negative = pulled in)")
    p.add_argument("--tension", action="append", default=[], type=_assignment,
                   metavar="NAME=N", help="tension of a tendon whose length is not given")

    p = sub.add_parser("estimate", help="estimation (eq. 17): tendon lengths and tensions -> "
                                        "shape and unknown load magnitudes")
    _common(p)
    p.add_argument("--displacement", action="append", default=[], type=_assignment,
                   metavar="NAME=M", help="measured tendon length change (m)")
    p.add_argument("--tension", action="append", default=[], type=_assignment,
                   metavar="NAME=N", help="measured tendon tension (N)")
    p.add_argument("--unknown", action="append", default=[], type=_unknown, required=True,
                   metavar="X,DX,DY,DZ|gravity",
                   help="unknown load: a point force of unknown magnitude along global "
                        "(DX, DY, DZ) at X, or the gravity scale")
    p.add_argument("--readings", metavar="READINGS.csv",
                   help="estimate every row of a log; '-' reads it live from standard input")
    p.add_argument("-o", "--output", metavar="OUT.csv",
                   help="output file for --readings (written at the end, atomically); without "
                        "it, or '-', each row goes to standard output as soon as it is estimated")
    p.add_argument("--length-noise", type=_positive, default=1e-4, metavar="M",
                   help="1-σ tendon length noise for the uncertainty band (default 1e-4 m)")
    p.add_argument("--tension-noise", type=_positive, default=0.025 / 3, metavar="FRACTION",
                   help="1-σ relative tension noise (default 0.025/3)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")

    p = sub.add_parser("identify", help="identification (eq. 19): snapshots -> E, density, μ")
    p.add_argument("robot", help="robot description file (TOML); its values are the start")
    p.add_argument("--snapshots", required=True, metavar="SNAPSHOTS.csv")
    p.add_argument("--param", action="append", choices=("young_modulus", "density", "friction"),
                   help="parameter to fit (repeatable; default young_modulus and density)")
    p.add_argument("-o", "--output", metavar="FITTED.toml", help="write the fitted robot file")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")

    p = _analysis(sub, "sensitivity", "sensitivity to length, tension and friction errors "
                  "(§IV, Fig. 3a and 3b)", "examples/paper_simulation.toml")
    p.add_argument("--points", type=int, default=9, help="tendon length changes per force (3a)")
    _analysis(sub, "resolution", "force resolution at the tension sensors' resolution (§IV)",
              "examples/paper_simulation.toml")
    p = _analysis(sub, "compare", "GVS vs 3D-PC vs 3D-PC+E on the paper's experiments "
                  "(§V-B4, Fig. 6)", "examples/paper_prototype.toml")
    p.add_argument("csv", nargs="?", default="examples/paper_experiments.csv",
                   help="experiments CSV (default: examples/paper_experiments.csv)")

    p = sub.add_parser("experiments", help="re-run the paper's experiments (Tables II-IV)")
    p.add_argument("csv", nargs="?", default="examples/paper_experiments.csv",
                   help="experiments CSV (default: examples/paper_experiments.csv)")
    p.add_argument("--robot", default="examples/paper_prototype.toml",
                   help="robot file (default: examples/paper_prototype.toml)")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    return parser


def _unknown(text: str):
    from .estimation import GravityUnknown, PointForceUnknown
    if text.strip().lower() == "gravity":
        return GravityUnknown()
    X, *d = _numbers(4, "X,DX,DY,DZ or gravity")(text)
    try:
        return PointForceUnknown(X, tuple(d))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _positive(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (v > 0 and v < float("inf")):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text!r}")
    return v


def _point_forces(args):
    return [(pf[0], pf[1:]) for pf in args.point_force]


def _plot_shape(args, robot, result, unknowns=()):
    if not getattr(args, "plot", None):
        return
    from . import plotting
    from .estimation import PointForceUnknown
    forces = _point_forces(args)
    if result.magnitudes is not None:
        forces += [(u.X, result.magnitudes[i] * np.asarray(u.direction))
                   for i, u in enumerate(unknowns) if isinstance(u, PointForceUnknown)]
    plotting.shape(result, args.plot, robot.rod.length, forces, title=f"{robot.name}")


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
        print(json.dumps(summary, indent=1))
        print("wrote " + ", ".join(str(f) for f in files))
    return ok


def _print_result(result, as_json: bool, title: str):
    if as_json:
        print(json.dumps(result.to_json()))
        return
    print(f"{title}: {'converged' if result.converged else 'NOT CONVERGED'} in "
          f"{result.iterations} iterations (relative residual {result.residual:.1e})")
    if result.magnitudes is not None:
        for i, m in enumerate(result.magnitudes):
            band = f" ± {result.sigma[i]:.4g}" if result.sigma is not None else ""
            print(f"  magnitude {i + 1}: {m:.6g}{band}")
    for name in result.tensions:
        print(f"  tendon {name}: tension {result.tensions[name]:.4f} N, "
              f"length change {result.displacements[name] * 1e3:+.3f} mm")
    for name, p in result.markers.items():
        print(f"  marker {name}: [{', '.join(f'{v:+.4f}' for v in p)}] m")


def _estimate(args, robot):
    from .estimation import Noise, estimate
    noise = Noise(args.length_noise, args.tension_noise)
    if args.readings is None:
        if args.output:
            raise UsageError("tendonsense estimate: -o/--output goes with --readings")
        result = estimate(robot, dict(args.displacement), dict(args.tension), args.unknown,
                          _point_forces(args), noise)
        _print_result(result, args.json, "estimation")
        _plot_shape(args, robot, result, args.unknown)
        return result.converged
    from . import readings as rd
    if args.displacement or args.tension:
        raise UsageError("tendonsense estimate: --readings replaces --displacement/--tension")
    if args.output in (None, "-"):
        return _stream(args, robot, noise)
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
    header, rows = rd.output_rows(robot, samples, results, len(args.unknown))
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
    rows = good = 0
    try:
        with fh:
            rows, good = rd.stream_readings(robot, fh, sys.stdout, args.unknown,
                                            _point_forces(args), noise, source, skipped)
    except KeyboardInterrupt:
        return True
    except BrokenPipeError:  # the reader went away: stop quietly
        sys.stderr.close()
        return True
    return good == rows


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


def _identify(args, robot) -> bool:
    from .identification import identify, read_snapshots
    from .robot import robot_to_toml
    snapshots = read_snapshots(args.snapshots, robot)
    prog = _Progress(args, "identify")
    fit = identify(robot, snapshots, args.param or ("young_modulus", "density"), progress=prog)
    prog.close()
    if args.output:
        from .readings import write_text_atomic
        write_text_atomic(args.output, robot_to_toml(fit.robot))
    if args.json:
        print(json.dumps(fit.to_json()))
    else:
        for k, v in fit.parameters.items():
            print(f"{k} = {v:.6g}")
        print(f"marker RMSE {fit.marker_rmse * 1e3:.2f} mm (robot file's values: "
              f"{fit.initial_rmse * 1e3:.2f} mm); "
              f"{'converged' if fit.converged else 'NOT CONVERGED'} in {fit.iterations} "
              f"iterations")
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
        from . import forward
        if args.command == "estimate":
            return 0 if _estimate(args, robot) else _not_converged()
        if args.command == "solve":
            result = forward.solve(robot, dict(args.tension), _point_forces(args))
            _print_result(result, args.json, "forward statics")
            _plot_shape(args, robot, result)
        elif args.command == "fk":
            result = forward.forward_kinematics(robot, dict(args.displacement),
                                                dict(args.tension), _point_forces(args))
            _print_result(result, args.json, "forward kinematics")
            _plot_shape(args, robot, result)
    except UsageError as exc:
        print(exc, file=sys.stderr)
        return 2
    except (RobotFileError, ValueError, OSError) as exc:
        print(f"tendonsense: error: {exc}", file=sys.stderr)
        return 1
    return 0 if result.converged else _not_converged()


def _not_converged() -> int:
    print("tendonsense: not every solve converged (marked converged = false)", file=sys.stderr)
    return 3


if __name__ == "__main__":
    sys.exit(main())
