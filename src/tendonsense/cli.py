"""The ``tendonsense`` command line, a thin layer over the Python API.

Every argument, the robot file, input files and output paths are checked before JAX starts
(:mod:`tendonsense.inputs`): a slip is answered at once. Exit status: 0 success, 1 bad input
(one line on stderr, nothing on stdout, no file written), 2 bad usage, 3 a solve that did not
converge (no shape printed or written unless asked; ``--json`` carries ``converged: false``
and the reason in ``note``).
"""

from __future__ import annotations

import argparse
import csv
import glob
import importlib.util
import io
import json
import math
import os
import re
import sys
import time
import warnings
from datetime import datetime, timezone
from functools import partial
from importlib import resources
from pathlib import Path

import numpy as np

from . import __version__, inputs, settings
from .inputs import GravityUnknown, Noise, PointForceUnknown
from .readings import ReadingsError, special
from .robot import RobotFileError, load_robot
from .settings import pin
from .units import GF, between, newtons

DESCRIPTION = """\
Shape and external forces of a tendon-driven soft robot from its tendon readings, with a
Cosserat-rod model. Lengths in metres, forces in newtons, positions in the global frame.
Exit status: 0 success, 1 bad input, 2 bad usage, 3 a solve that did not converge.
Run 'tendonsense COMMAND --help' for the options of one command."""

#: the paper's robots and experiments, shipped with the package (the analyses' defaults)
DATA = resources.files("tendonsense") / "data"

UNKNOWN_HELP = ("an unknown load: 'X,DX,DY,DZ' a force of unknown size along the global "
                "direction (DX, DY, DZ) acting at X m from the base; X may be '?' (somewhere "
                "on the rod) or 'A:B' (somewhere in [A, B] m), which estimates where it acts "
                "too and takes one more measured tendon; or 'gravity' for an unknown scale of "
                "the robot's weight; repeatable")

#: options whose values may start with a minus sign ("--point-force -0.1,0,0,-1")
VALUE_OPTIONS = ("--point-force", "--unknown", "--tension", "--displacement", "--length-noise",
                 "--tension-noise", "--marker-noise", "--noise-length", "--noise-tension",
                 "--duration", "--output-dt", "--max-step", "--force-walk", "--max-force",
                 "--max-tension", "--points", "--seed", "--task-size", "--workers", "--cpu",
                 "--port")


class UsageError(Exception):
    pass


def _shown(parser, action) -> str:
    """The option of ``action`` as --help shows it (a hidden alias by its visible option)."""
    return "/".join(next((a for a in parser._actions if a.dest == action.dest
                          and a.help != argparse.SUPPRESS), action).option_strings)


def _given_once(action, parser, namespace):
    """A usage error where the option of ``action`` was given before."""
    given = namespace.__dict__.setdefault("_given", set())
    if action.dest in given:
        parser.error(f"{_shown(parser, action)} given twice")
    given.add(action.dest)


class _Once(argparse._StoreAction):
    """An option with a value that may be given once (a second one is a usage error, never
    silently the last)."""

    def __call__(self, parser, namespace, values, option_string=None):
        _given_once(self, parser, namespace)
        super().__call__(parser, namespace, values, option_string)


class _OnceFlag(argparse._StoreTrueAction):
    """A switch that may be given once (``--dynamic --dynamic`` is a slip)."""

    def __call__(self, parser, namespace, values, option_string=None):
        _given_once(self, parser, namespace)
        super().__call__(parser, namespace, values, option_string)


class BadValue(ValueError):
    """An option's value that its type or choices refuse: bad input (exit status 1), as a bad
    value found after parsing is, where a malformed command line is bad usage (2)."""


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, no usage dump
        raise UsageError(f"{self.prog}: {message}")

    def _get_value(self, action, arg_string):
        try:
            return super()._get_value(action, arg_string)
        except argparse.ArgumentError as exc:
            raise BadValue(f"{self.prog}: {exc}") from None

    def _check_value(self, action, value):
        if isinstance(action, argparse._SubParsersAction):  # a command mistyped: usage
            return super()._check_value(action, value)
        try:
            super()._check_value(action, value)
        except argparse.ArgumentError as exc:
            raise BadValue(f"{self.prog}: {exc}") from None

    def parse_args(self, args=None, namespace=None):
        """As argparse's, an unrecognized argument named with the command it was given to (and
        the option it may be a slip for), also where a required option then seems missing."""
        args = sys.argv[1:] if args is None else [str(a) for a in args]
        try:
            known, extras = self.parse_known_args(args, namespace)
        except UsageError as exc:
            if "the following arguments are required" in str(exc):
                self._unrecognized(args)
            raise
        if extras:
            self._unrecognized(args, getattr(known, "command", None), extras)
        return known

    def _unrecognized(self, args, command=None, extras=None):
        """Raise the usage error naming ``extras``, or the ``--options`` among ``args`` that
        the command does not have (none: return)."""
        sub = next((a.choices for a in self._actions
                    if isinstance(a, argparse._SubParsersAction)), {})
        command = command or next((a for a in args if a in sub), None)
        parser = sub[command] if command in sub else self
        options = parser._option_string_actions
        bad = [a.split("=")[0] for a in args if a.startswith("--") and a != "--" and not any(
            o.startswith(a.split("=")[0]) for o in options)]
        if extras is None and not bad:
            return
        import difflib
        prog = " ".join(filter(None, (self.prog, command)))
        slips = [f"{b}: did you mean {_shown(parser, options[m[0]])}? " for b in bad
                 if (m := difflib.get_close_matches(b, list(options), n=1))]
        raise UsageError(f"{prog}: unrecognized arguments: {' '.join(extras or bad)} "
                         f"({''.join(slips)}see {prog} --help)")

    def add_argument(self, *names, **kwargs):
        if names and names[0].startswith("-"):
            kwargs["action"] = {"store": _Once, "store_true": _OnceFlag}.get(
                kwargs.get("action", "store"), kwargs.get("action"))
        return super().add_argument(*names, **kwargs)


def _assignment(text: str) -> tuple[str, float]:
    name, sep, value = text.partition("=")
    if not sep or not name:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got {text!r}")
    try:
        return name, float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{name}: not a number: {value!r}") from None


def _direction(text: str, allowed=inputs.SLIDING):
    name, sep, value = text.partition("=")
    value = value.strip().lower()  # as a log's cell is read
    if not sep or not name:
        raise argparse.ArgumentTypeError(f"expected NAME={'|'.join(allowed)}, got {text!r}")
    if value not in allowed:
        raise argparse.ArgumentTypeError(f"{name}={value!r}: the direction is "
                                         f"{', '.join(allowed[:-1])} or {allowed[-1]}")
    return name, value


def _simulated_direction(text: str):
    return _direction(text, inputs.SIMULATED_SLIDING)


def _forward_direction(text: str):
    """in or out (stuck is parsed, to be refused with its reason: a solve needs a profile)."""
    name, _, value = text.partition("=")
    return (name, "stuck") if name and value.strip().lower() == "stuck" else _direction(
        text, ("in", "out"))


SLIDING_HELP = ("the direction tendon NAME slides through its guides, which sets the sense of "
                "its friction: in (pulled in, the tension fades toward the anchor; the "
                "default), out (paid out, it grows toward the anchor){}; once per tendon")


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


def _unknown(text: str):
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
    try:
        d = _numbers(3, what)(rest)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
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


def _fraction(text: str) -> float:
    v = _positive(text)
    if v >= 1:
        raise argparse.ArgumentTypeError(f"{inputs.FRACTION}, got {text!r}")
    return v


def _core(text: str) -> int:
    n = os.cpu_count() or 1
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a core number: {text!r}") from None
    if not 0 <= v < n:
        raise argparse.ArgumentTypeError(f"core {v}: this machine's cores are 0 to {n - 1}")
    return v


def _robot_argument(p, default: str | None = None):
    if default is None:
        p.add_argument("robot", help="the robot file (TOML)")
    else:
        p.add_argument("robot", nargs="?", default=str(DATA / default),
                       help=f"the robot file (TOML; default: the paper's {default}, shipped "
                            f"with tendonsense)")
        p.add_argument("--robot", dest="robot_option", help=argparse.SUPPRESS)


SHAPE_PLOT = ("also draw the rod's shape (side and top views), its markers, tendons and forces "
              "into a PNG file{}; a solve that did not converge is drawn stamped NOT "
              "CONVERGED")


def _common(p: argparse.ArgumentParser,
            plot: tuple[str, str] = ("SHAPE.png", SHAPE_PLOT.format(""))):
    _robot_argument(p)
    p.add_argument("--point-force", action="append", default=[], metavar="X,FX,FY,FZ",
                   type=_numbers(4, "X,FX,FY,FZ"),
                   help="a known force FX, FY, FZ (N, global frame) acting at the distance X "
                        "(m) from the base along the rod; repeatable")
    p.add_argument("--json", action="store_true",
                   help="print the result as one JSON object instead of text")
    p.add_argument("--plot", metavar=plot[0], help=plot[1])


def _analysis(sub, name, summary, description, robot_default):
    p = sub.add_parser(name, help=summary, description=description)
    _robot_argument(p, robot_default)
    p.add_argument("-o", "--out-dir", default="tendonsense_results", metavar="FOLDER",
                   help="the folder for the tables (CSV, JSON), the figures (PNG) and a "
                        "summary (JSON); made if missing, in a folder that exists (default: "
                        "tendonsense_results)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("--quiet", action="store_true",
                   help="do not show a progress bar (nor say that programs are compiling)")
    return p


def _experiments_table(p):
    p.add_argument("csv", nargs="?", default=str(DATA / "paper_experiments.csv"),
                   metavar="EXPERIMENTS.csv",
                   help="the experiments table (default: the paper's, shipped with "
                        "tendonsense; the columns: case, tendon, unknown, tension_N, "
                        "displacement_m, applied, and force_X, direction, paper_estimate where "
                        "they apply, as in the manual's conventions)")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="tendonsense", description=DESCRIPTION,
                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"tendonsense {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser,
                                metavar="COMMAND")

    def command(name, summary, description):
        return sub.add_parser(name, help=summary, description=description)

    p = command("solve", "shape from tendon tensions (forward statics)",
                "Compute the rod's shape, tendon length changes and marker positions from the "
                "tendon tensions and any known forces.")
    _common(p)
    p.add_argument("--tension", action="append", default=[], type=_assignment,
                   metavar="NAME=N",
                   help="a tendon's tension in newtons (>= 0); once per tendon; tendons not "
                        "named are slack")
    p.add_argument("--sliding", action="append", default=[], type=_forward_direction,
                   metavar="NAME=in|out", help=SLIDING_HELP.format(""))
    p.add_argument("--settle", action="store_true",
                   help="where the shape solved for is an unstable equilibrium (or none is "
                        "found), give instead the stable state the rod comes to rest in from "
                        "it (a solve from the straight rod keeps the plane of its loads; the "
                        "robot may leave it)")

    p = command("fk", "shape and tensions from tendon length changes (forward kinematics)",
                "Compute the rod's shape and the tensions needed for the given tendon length "
                "changes (negative = pulled in).")
    _common(p)
    p.add_argument("--displacement", action="append", default=[], type=_assignment,
                   metavar="NAME=M",
                   help="a tendon's length change in metres (negative = pulled in); once per "
                        "tendon")
    p.add_argument("--tension", action="append", default=[], type=_assignment,
                   metavar="NAME=N",
                   help="the tension (N, >= 0) of a tendon whose length change is not given; "
                        "tendons not named are slack")
    p.add_argument("--sliding", action="append", default=[], type=_forward_direction,
                   metavar="NAME=in|out", help=SLIDING_HELP.format(""))

    p = command("estimate", "shape and unknown forces from tendon readings (estimation)",
                "Estimate the rod's shape and the size of unknown loads from measured tendon "
                "length changes and tensions: one reading given on the command line, or every "
                "row of a readings log (--readings). Each unknown needs one measured tendon "
                "(a located one two); with more measured tendons than unknowns the estimate is "
                "a least-squares fit. Every magnitude comes with a 1-sigma band for sensor "
                "noise. A measured tendon needs its length change and its tension; in a log "
                "every tendon has a tension_<name> column (zeros for a slack one).")
    _common(p, ("SHAPE.png", SHAPE_PLOT.format(" (and, for a force of unknown location, the "
                                               "misfit over X into SHAPE_location.png)")))
    p.add_argument("--displacement", action="append", default=[], type=_assignment,
                   metavar="NAME=M",
                   help="a measured tendon length change in metres (negative = pulled in); "
                        "needs the same tendon's --tension")
    p.add_argument("--tension", action="append", default=[], type=_assignment,
                   metavar="NAME=N",
                   help="a measured tendon tension in newtons (>= 0); tendons not named are "
                        "slack")
    p.add_argument("--sliding", action="append", default=[], type=_direction,
                   metavar="NAME=in|out|stuck",
                   help=SLIDING_HELP.format(" or stuck (anywhere between: the estimate gives "
                                            "the range of forces)"))
    p.add_argument("--unknown", action="append", default=[], type=_unknown, required=True,
                   metavar="X,DX,DY,DZ|?,DX,DY,DZ|A:B,DX,DY,DZ|gravity", help=UNKNOWN_HELP)
    p.add_argument("--readings", nargs="+", metavar="READINGS.csv",
                   help="estimate every row of a readings log (CSV); '-' reads the log live "
                        "from standard input; several logs (files, or a quoted pattern such as "
                        "'logs/*.csv') go with -o OUTDIR/")
    p.add_argument("-o", "--estimates", metavar="ESTIMATES.csv|OUTDIR/",
                   help="with --readings: write the estimates to this CSV file (atomically, "
                        "when every row is done); without it, or with '-', each result row goes "
                        "to standard output as soon as it is estimated; with several logs a "
                        "folder OUTDIR/ (made if missing, in a folder that exists), one output "
                        "per log under the log's name")
    _cluster_options(p, "several logs (a log per task)", "the logs and OUTDIR")
    p.add_argument("--output", dest="estimates", help=argparse.SUPPRESS)
    p.add_argument("--length-noise", type=_positive, default=1e-4, metavar="M",
                   help="standard deviation of the tendon length sensors in metres, for the "
                        "uncertainty band (default 0.0001 m = 0.1 mm)")
    p.add_argument("--tension-noise", type=_fraction, default=0.025 / 3, metavar="FRACTION",
                   help="standard deviation of the tension sensors as a fraction of the "
                        "reading (default 0.00833, i.e. 2.5 %% / 3)")
    p.add_argument("--dynamic", action="store_true",
                   help="with --readings: estimate over the log's time stamps with the damped "
                        "model ([rod] damping), right while the robot moves (an extended "
                        "Kalman filter; the log needs a time column)")
    p.add_argument("--force-walk", type=_positive, default=None, metavar="N/SQRT(S)",
                   help="with --dynamic: how fast the unknown forces may change, a random walk "
                        "per square root of a second (default 0.12): larger follows a change "
                        "sooner, smaller averages the noise longer")
    p.add_argument("--quiet", action="store_true",
                   help="do not show a progress bar (nor say that programs are compiling)")
    p.add_argument("--cpu", type=_core, default=None, metavar="CORE",
                   help="with --readings -: keep the process on this core, so that every row "
                        "is answered in its usual time (beside a robot; XLA's threads then "
                        "never wait for an idle core to wake)")
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
    _robot_argument(p)
    _view_options(p)
    p.add_argument("--max-tension", type=_positive, default=5.0, metavar="N",
                   help="the tension sliders' range, N (default 5)")
    p.add_argument("--max-force", type=_positive, default=1.0, metavar="N",
                   help="the point force slider's range, N (default 1)")

    p = command("identify", "fit stiffness, density, friction or damping to measurements "
                "(calibration)",
                "Fit the Young's modulus, density and/or friction coefficients of the robot "
                "file to static poses (snapshots): marker positions, the tendons' own length "
                "readings (no camera needed), or both; or its damping to a readings log of a "
                "motion (--readings, --param damping). Every tendon has a tension_<name> "
                "column (zeros for a slack one).")
    p.add_argument("robot", help="the robot file (TOML); its values are the starting guess")
    p.add_argument("--snapshots", metavar="SNAPSHOTS.csv",
                   help="the measured poses: tensions, an optional known load, marker "
                        "positions and/or tendon length changes, one row per pose")
    p.add_argument("--readings", metavar="LOG.csv",
                   help="instead of --snapshots, for --param damping: a readings log with "
                        "time stamps of a motion from rest (a step or a ramp of the tensions "
                        "under known --point-force loads)")
    p.add_argument("--param", action="append", metavar="NAME",
                   help="a parameter to fit: young_modulus, density, friction (one μ for every "
                        "tendon) or friction_<tendon>; repeatable (default: young_modulus and "
                        "density); or damping (Pa·s), alone, with --readings")
    p.add_argument("--point-force", action="append", default=[], metavar="X,FX,FY,FZ",
                   type=_numbers(4, "X,FX,FY,FZ"),
                   help="with --readings: a known force FX, FY, FZ (N, global frame) at X (m) "
                        "during the whole log; repeatable")
    p.add_argument("--no-inertia", action="store_true",
                   help="with --readings: simulate the motion without inertia (the "
                        "quasi-static limit with damping: faster, right for slow motions)")
    p.add_argument("--marker-noise", type=_positive, default=1e-3, metavar="M",
                   help="standard deviation of a marker coordinate, m (default 0.001)")
    p.add_argument("--length-noise", type=_positive, default=1e-4, metavar="M",
                   help="standard deviation of a tendon length reading, m (default 0.0001)")
    p.add_argument("--crossval", action="store_true",
                   help="also refit without each snapshot and report how well it is predicted")
    p.add_argument("--plot", metavar="FIGURE.png",
                   help="write a figure of the per-snapshot errors (and the cross-validation)")
    p.add_argument("-o", "--fitted-robot", metavar="FITTED.toml",
                   help="write the robot file with the fitted values (its comments kept, a "
                        "header saying how it was fitted); only if the fit converged")
    p.add_argument("--output", dest="fitted_robot", help=argparse.SUPPRESS)
    p.add_argument("--json", action="store_true",
                   help="print the result as one JSON object instead of text")

    p = _analysis(sub, "sensitivity", "how errors in tendon length, tension and friction "
                  "change the estimated force (the paper's Fig. 3a and 3b)",
                  "Estimate a tip force from readings with a length, tension or friction "
                  "error, on one tendon over a range of length changes (the paper's Fig. 3a) "
                  "and on three tendons for 27 combinations of errors (its Fig. 3b, with 2-σ "
                  "ellipsoids); writes the tables, a summary and the figures.",
                  "paper_simulation.toml")
    p.add_argument("--points", type=int, default=9,
                   help="tendon length changes per force in the one-tendon study, evenly "
                        "from -20 mm to 0 (one: -20 mm alone; default 9)")
    _analysis(sub, "resolution", "the smallest force change the tension sensors can resolve "
              "(the paper's Section IV)",
              "For a range of applied tip forces, the smallest change of each force component "
              "that the tension sensors' resolution can detect (the paper's Section IV); "
              "writes the table, a summary and the figure.", "paper_simulation.toml")
    p = _analysis(sub, "compare", "this model against the paper's simpler rod models on the "
                  "paper's experiments (the paper's Fig. 6)",
                  "Estimate the paper's experiments with this model (GVS: the robot file's "
                  "strain basis) and with the paper's simpler rod models (3D-PC, 3D-PC+E) and "
                  "compare their errors (the paper's Fig. 6); writes the table, a summary and "
                  "the figure.",
                  "paper_prototype.toml")
    _experiments_table(p)

    p = command("simulate", "the rod's motion under tensions over time, and the readings log it "
                "gives (forward dynamics)",
                "Simulate the robot from the straight rod at rest at t = 0 (gravity and the given "
                "loads acting from then on) with its inertia and [rod] damping, and write the "
                "readings log a robot would record: time, tension_<name>, displacement_<name>, "
                "marker_<name>_x/_y/_z, the format estimate --readings reads. Read-out noise "
                "on request, to rehearse an experiment.")
    _common(p, ("MOTION.png", "also draw the tensions, the length changes and the last "
                              "marker's motion over time into a PNG file (without the log's "
                              "read-out noise; its title says so)"))
    p.add_argument("--tension", action="append", default=[], type=_assignment,
                   metavar="NAME=N",
                   help="a tendon's tension in newtons (>= 0), held constant; tendons not named "
                        "(here or in --tensions) are slack")
    p.add_argument("--tensions", metavar="TENSIONS.csv",
                   help="tensions over time: a CSV with time (s) and tension_<name> columns, "
                        "linear between rows, the last row held")
    p.add_argument("--duration", type=_positive, required=True, metavar="S",
                   help="simulated time, s")
    p.add_argument("--output-dt", type=_positive, default=0.01, metavar="S",
                   help="time between two rows of the log, s (default 0.01)")
    p.add_argument("--max-step", type=_positive, default=inputs.MAX_STEP, metavar="S",
                   help="the integration step, s (default 0.002; halved where a solve fails; "
                        "a warning where it is longer than a fifth of the rod's relaxation "
                        "time 3η/E); rows between steps are interpolated")
    p.add_argument("--no-inertia", action="store_true",
                   help="leave out inertia (the quasi-static limit with damping; needs "
                        "[rod] damping > 0)")
    p.add_argument("--from-equilibrium", action="store_true",
                   help="start at rest in the static equilibrium of the tensions and loads at "
                        "t = 0 (default: the straight rod at rest, the loads applied at t = 0)")
    p.add_argument("--sliding", action="append", default=[], type=_simulated_direction,
                   metavar="NAME=in|out|follow",
                   help="the sense of tendon NAME's friction: follow (the default, as the "
                        "estimators take it: pulled in while its tension rises, stuck when it "
                        "turns, paid out once it has fallen through the friction band), in "
                        "(always pulled in, the tension fading toward the anchor: eq. 10 as "
                        "written) or out (always paid out); once per tendon")
    p.add_argument("--noise-length", type=float, default=0.0, metavar="M",
                   help="read-out noise of the length changes, standard deviation in m "
                        "(default 0)")
    p.add_argument("--noise-tension", type=float, default=0.0, metavar="FRACTION",
                   help="read-out noise of the tensions, relative standard deviation "
                        "(default 0)")
    p.add_argument("--seed", type=int, default=None, help="the noise's random seed")
    p.add_argument("-o", "--log", required=True, metavar="LOG.csv",
                   help="the readings log to write (atomically; - writes it to standard "
                        "output)")

    p = command("sweep", "forward statics over many parameter sets (a design sweep, a Monte "
                "Carlo), on a Dask cluster if asked",
                "Solve the forward statics once per row of a parameter-set table (tensions, "
                "E, ν, ρ, μ and a known load per set; a value not given is the robot file's) "
                "and write one result row per set: the set's own columns, its markers, its "
                "tendons' length changes and whether it converged. Every set is solved by "
                "one compiled program, whatever its numbers.")
    _robot_argument(p)
    p.add_argument("sets", metavar="SETS.csv",
                   help="the parameter sets, one per row: tension_<tendon> (N), "
                        "young_modulus (Pa), poisson_ratio, density (kg/m³), friction, "
                        "friction_<tendon>, load_X (m) and load_fx/_fy/_fz (N, global), and "
                        "descriptive columns (id, name, note) copied to the results")
    p.add_argument("-o", "--results", required=True, metavar="RESULTS.csv",
                   help="the results, one row per set (written atomically)")
    p.add_argument("--point-force", action="append", default=[], metavar="X,FX,FY,FZ",
                   type=_numbers(4, "X,FX,FY,FZ"),
                   help="a known force (N, global) at X m from the base, the same in every "
                        "set; repeatable")
    p.add_argument("--sliding", action="append", default=[], type=_forward_direction,
                   metavar="NAME=in|out", help=SLIDING_HELP.format(", in every set"))
    p.add_argument("--skip-stability", action="store_true",
                   help="do not check whether each set's equilibrium is stable (column "
                        "unstable left blank; a large sweep takes about half the time)")
    p.add_argument("--settle", action="store_true",
                   help="a set whose equilibrium is unstable (or not found) is instead the "
                        "stable state the rod comes to rest in from it, as solve --settle")
    _cluster_options(p, "the sets")
    p.add_argument("--task-size", type=int, metavar="N",
                   help="with --workers or --scheduler: sets per task (default 1000)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.add_argument("--quiet", action="store_true",
                   help="do not show a progress bar (nor say that programs are compiling)")

    p = command("experiments", "re-run the paper's experiments (its Tables II to IV)",
                "Estimate every row of the paper's experiments and compare with the applied "
                "loads and the paper's own estimates.")
    _robot_argument(p, "paper_prototype.toml")
    _experiments_table(p)
    p.add_argument("--json", action="store_true",
                   help="print the result as one JSON object instead of text")
    return parser


def _cluster_options(p, what: str, reach: str = ""):
    p.add_argument("--workers", type=int, metavar="N",
                   help=f"run {what} on a local Dask cluster of N worker processes (default: "
                        f"here, in this process; needs pip install 'tendonsense[distributed]')")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help=f"run {what} on the running Dask cluster whose scheduler is at ADDRESS "
                        f"(e.g. tcp://10.0.0.5:8786)" + (f"; {reach} must be reachable by its "
                                                         f"workers at the same paths" if reach
                                                         else ""))


def _view_options(p):
    p.add_argument("--port", type=int, default=8080, metavar="N",
                   help="the view's port (default 8080)")
    p.add_argument("--host", default="127.0.0.1",
                   help="the address to serve the view on (default 127.0.0.1, this machine "
                        "only); another address exposes it to the network")


# --------------------------------------------------------------------- checks before computing

def _join_negative_values(argv: list[str]) -> list[str]:
    """``--point-force -0.1,0,0,-1`` → ``--point-force=-0.1,0,0,-1`` (argparse takes a value
    that starts with '-' for an option)."""
    out, i = [], 0
    while i < len(argv):
        a = argv[i]
        if (a in VALUE_OPTIONS and i + 1 < len(argv) and argv[i + 1][:1] == "-"
                and argv[i + 1][1:2] in tuple("0123456789.")):
            out.append(f"{a}={argv[i + 1]}")
            i += 2
        else:
            out.append(a)
            i += 1
    return out


def _once(pairs, flag: str) -> dict[str, float]:
    """NAME=VALUE flags as a dict; a name given twice is a usage error."""
    out: dict = {}
    for name, value in pairs:
        if name in out:
            raise UsageError(f"tendonsense: {flag} {name} given twice ({out[name]:g} and "
                             f"{value:g})" if isinstance(value, float) else
                             f"tendonsense: {flag} {name} given twice ({out[name]} and "
                             f"{value})")
        out[name] = value
    return out


def _folder_exists(given: str, folder: Path, why: str = "") -> None:
    """A ValueError "GIVEN: no folder 'FOLDER'WHY" (or that a file stands where a folder of
    its path should be) unless ``folder`` is one."""
    if not folder.is_dir():
        there = next((f for f in (folder, *folder.parents) if f.exists()), None)
        if there is not None and not there.is_dir():
            raise ValueError(f"{given}: {str(there)!r} is a file, not a folder")
        raise ValueError(f"{given}: no folder {str(folder)!r}{why}")


def _writable(path, what: str) -> None:
    """An output file's folder exists and can be written, before any computation."""
    if not str(path).strip():
        raise ValueError(f"{what}: an empty name (a file name is needed)")
    p = Path(path)
    if p.is_dir():
        raise ValueError(f"{what} {path}: is a folder, not a file")
    if special(p):  # a device or a named pipe: written into, its folder untouched
        if not os.access(p, os.W_OK):
            raise ValueError(f"{what} {path}: cannot write (no permission)")
        return
    # (a symbolic link: its target is written, beside it)
    folder = Path(os.path.realpath(p)).parent if p.is_symlink() else p.parent
    _folder_exists(f"{what} {path}", folder)
    if not os.access(folder, os.W_OK):
        raise ValueError(f"{what} {path}: the folder {str(folder)!r} is not writable")


def _check(args, robot) -> None:
    """Every argument against the robot, and every output path, by the rules of
    :mod:`tendonsense.inputs` (nothing computed, JAX not started); the notes the checks
    find are said once every check has passed."""
    cmd = args.command
    args.notes = []
    if cmd in ("solve", "fk", "estimate", "sweep"):
        args.sliding = _once(args.sliding, "--sliding")
        inputs.sliding(robot, args.sliding)
        stuck = [n for n, d in args.sliding.items() if d == "stuck"]
        if stuck and cmd != "estimate":
            raise ValueError(f"tendonsense {cmd}: --sliding {stuck[0]}=stuck: the tension inside "
                             f"a stuck tendon depends on its history; give in or out "
                             f"(estimate takes stuck and gives the range of forces)")
        if args.sliding and getattr(args, "readings", None) is not None:
            raise UsageError("tendonsense estimate: --sliding goes with a single reading (in "
                             "a log, a sliding_<tendon> column gives it per row; without it "
                             "the direction follows each tendon's history)")
    if cmd in ("solve", "fk", "estimate"):
        tensions = _once(args.tension, "--tension")
        displacements = _once(getattr(args, "displacement", []), "--displacement")
        inputs.check_point_forces(robot, _point_forces(args))
        if cmd == "solve":
            inputs.tensions(robot, tensions)
        elif cmd == "fk":
            if not displacements:
                raise UsageError("tendonsense fk: give at least one --displacement NAME=M")
            clash = [n for n in displacements if n in tensions]
            if clash:
                raise UsageError(f"tendonsense fk: tendon {clash[0]}: give its --displacement "
                                 f"or its --tension, not both")
            inputs.displacements(robot, displacements)
            inputs.tensions(robot, tensions)
        else:
            _check_estimate(args, robot, tensions, displacements)
        args.tension, args.displacement = tensions, displacements
        if args.plot:
            _writable(args.plot, "--plot")
    elif cmd == "simulate":
        _check_simulate(args, robot)
    elif cmd == "sweep":
        from .readings import read_parameter_sets
        _check_cluster(args)
        if args.settle and args.skip_stability:
            raise UsageError("tendonsense sweep: --settle needs the stability check (not "
                             "--skip-stability): it settles the sets found unstable")
        if args.task_size is not None:
            if args.workers is None and args.scheduler is None:
                raise UsageError("tendonsense sweep: --task-size goes with --workers or "
                                 "--scheduler (here every set is solved by one batch)")
            if args.task_size < 1:
                raise ValueError(f"tendonsense sweep: --task-size {args.task_size}: at least 1")
        forces = _point_forces(args)
        inputs.check_point_forces(robot, forces, math.inf)  # bounded below by each set's E
        _writable(args.results, "-o/--results")
        args.sets_read = sets = read_parameter_sets(args.sets, robot)
        E = sets.values.get("young_modulus", np.full(len(sets.rows), robot.rod.young_modulus))
        for i, (X, F) in enumerate(forces):
            if bad := inputs.first_force_error(robot, f"--point-force {i + 1}", X, F, E):
                raise ValueError(f"{args.sets}: set {bad[0] + 1}: {bad[1]}")
    elif cmd == "identify":
        _check_identify(args, robot)
    if cmd in ("experiments", "compare"):
        from .experiments import read_experiments
        args.table = read_experiments(args.csv, robot)
    if cmd in ("sensitivity", "resolution", "compare"):
        _check_analysis(args, robot)
    if (cmd == "view" or getattr(args, "view", False)) and not 0 < args.port < 65536:
        raise ValueError(f"tendonsense {cmd}: --port {args.port}: not a port number")
    for name, flag in (("length_noise", "--length-noise"), ("noise_length", "--noise-length")):
        if getattr(args, name, None) and (
                error := inputs.length_noise_error(robot, flag, getattr(args, name))):
            raise ValueError(error)
    if getattr(args, "marker_noise", None) and (
            error := inputs.marker_noise_error(robot, "--marker-noise", args.marker_noise)):
        raise ValueError(error)
    _not_an_input(args)
    _file_kinds(args)
    for note in args.notes:
        print(f"tendonsense: {note}", file=sys.stderr)


def _file_kinds(args) -> None:
    """A figure's suffix names a format matplotlib writes, a table's is not a figure's, a
    fitted robot's is .toml."""
    plot = getattr(args, "plot", None)
    if plot and (kind := Path(plot).suffix.lower()[1:]) and kind not in FIGURE_FORMATS:
        raise ValueError(f"--plot {plot}: .{kind} is not a figure format (one of "
                         f"{', '.join('.' + f for f in FIGURE_FORMATS)})")
    for name, flag in (("results", "-o/--results"), ("estimates", "-o/--estimates"),
                       ("log", "-o/--log")):
        table = getattr(args, name, None)
        if isinstance(table, str) and Path(table).suffix.lower()[1:] in FIGURE_FORMATS:
            raise ValueError(f"{flag} {table}: writes a CSV table, not a figure (a figure is "
                             f"--plot): name it *.csv")
    fitted = getattr(args, "fitted_robot", None)
    if fitted and Path(fitted).suffix.lower() != ".toml":
        raise ValueError(f"-o/--fitted-robot {fitted}: the fitted robot is a robot file, "
                         f"written as TOML: name it *.toml")


#: the suffixes of the figure formats matplotlib writes (a figure without one is a PNG)
FIGURE_FORMATS = ("png", "pdf", "svg", "svgz", "eps", "ps", "jpg", "jpeg", "tif", "tiff",
                  "webp")


#: a command's output files and input files (argument name, as the user knows it)
OUTPUT_FILES = (("plot", "--plot"), ("results", "-o/--results"), ("estimates", "-o/--estimates"),
                ("log", "-o/--log"), ("fitted_robot", "-o/--fitted-robot"))
INPUT_FILES = (("robot", "the robot file"), ("sets", "the parameter sets"),
               ("readings", "--readings"), ("tensions", "--tensions"),
               ("snapshots", "--snapshots"), ("csv", "the table"))


def _not_an_input(args) -> None:
    """No output file is one of the command's input files (it would be overwritten)."""
    def paths(names):
        for name, flag in names:
            value = getattr(args, name, None)
            for v in value if isinstance(value, list) else [value]:
                if isinstance(v, (str, Path)) and str(v) != "-" and Path(v).is_file():
                    yield flag, v
    for out_flag, out in paths(OUTPUT_FILES):
        for in_flag, inp in paths(INPUT_FILES):
            if os.path.samefile(out, inp):
                raise ValueError(f"{out_flag} {out}: is {in_flag} ({inp}): writing it would "
                                 f"overwrite an input")


def _check_identify(args, robot):
    from .readings import has_time, motion_step_error, read_readings, read_snapshots
    if (args.snapshots is None) == (args.readings is None):
        raise UsageError("tendonsense identify: give --snapshots SNAPSHOTS.csv (static poses) "
                         "or --readings LOG.csv (a motion, for --param damping)")
    params = args.param or (("damping",) if args.readings else ())
    allowed = (*inputs.parameter_names(robot), "damping")
    bad = [p for p in params if p not in allowed]
    if bad:
        raise ValueError(f"--param {bad[0]}: not a parameter of this robot (one of "
                         f"{', '.join(allowed)})")
    if twice := next((p for p in params if params.count(p) > 1), None):
        raise UsageError(f"tendonsense identify: --param {twice} given twice")
    if args.readings is not None:
        if list(params) != ["damping"]:
            raise UsageError("tendonsense identify: --readings fits --param damping alone (E, "
                             "density and friction are fitted to static --snapshots)")
        for flag, given in (("--crossval", args.crossval), ("--plot", args.plot)):
            if given:
                raise UsageError(f"tendonsense identify: {flag} goes with --snapshots")
    else:
        if "damping" in params:
            raise UsageError("tendonsense identify: --param damping is fitted to a motion: "
                             "give --readings LOG.csv (with time stamps) instead of "
                             "--snapshots")
        for flag, given in (("--point-force", args.point_force),
                            ("--no-inertia", args.no_inertia)):
            if given:
                raise UsageError(f"tendonsense identify: {flag} goes with --readings (a "
                                 f"snapshot's load is in its load_* columns)")
    inputs.check_point_forces(robot, _point_forces(args))
    for path, what in ((args.fitted_robot, "-o/--fitted-robot"), (args.plot, "--plot")):
        if path:
            _writable(path, what)
    if args.readings is not None:
        if not Path(args.readings).is_file():
            raise ValueError(f"{args.readings}: no such file")
        args.log = read_readings(args.readings, robot)
        if not has_time(args.readings):
            raise ValueError(f"{args.readings}: no time column: the damping is fitted to a "
                             f"motion over time")
        if error := motion_step_error(args.readings, args.log[1], static=""):
            raise ValueError(error)
    else:  # a modulus being fitted bounds no tension (the file's is a guess)
        fitted = args.param or inputs.DEFAULT_PARAMETERS
        args.snapshots_read = read_snapshots(
            args.snapshots, robot, math.inf if "young_modulus" in fitted else None)


def _check_simulate(args, robot):
    from .readings import read_tension_schedule
    args.tension = _once(args.tension, "--tension")
    inputs.tensions(robot, args.tension)
    args.sliding = _once(args.sliding, "--sliding")
    inputs.sliding(robot, args.sliding, inputs.SIMULATED_SLIDING)
    inputs.check_point_forces(robot, _point_forces(args))
    schedule = read_tension_schedule(args.tensions, robot) if args.tensions else {}
    both = [n for n in schedule if n in args.tension]
    if both:
        raise UsageError(f"tendonsense simulate: tendon {both[0]}: in --tensions and --tension")
    firsts = [t[0] for t, _ in schedule.values()]
    nexts = [t[1] for t, _ in schedule.values() if t.size > 1]
    if firsts and min(firsts) >= args.duration:
        args.notes.append(f"note: {args.tensions}: its first row is at {min(firsts):g} s, not "
                          f"before --duration {args.duration:g} s: the tensions stay at that "
                          f"row's throughout (times are in seconds)")
    elif nexts and min(nexts) > args.duration:
        args.notes.append(f"note: {args.tensions}: its second row is at {min(nexts):g} s, "
                          f"after --duration {args.duration:g} s: only part of the stretch "
                          f"between its first two rows is simulated (times are in seconds)")
    args.schedule = {**args.tension, **schedule}
    if error := inputs.duration_error("--duration", args.duration, max(
            [inputs.last_change(t, v) for t, v in schedule.values()], default=0.0)):
        raise ValueError(error)
    for flag, v in (("--noise-length", args.noise_length), ("--noise-tension", args.noise_tension)):
        if not (0 <= v < float("inf")):
            raise ValueError(f"{flag} {v:g}: must be a finite number >= 0")
    if args.noise_tension >= 1:
        raise ValueError(f"--noise-tension {args.noise_tension:g}: {inputs.FRACTION}")
    if args.seed is not None and args.seed < 0:
        raise ValueError(f"--seed {args.seed}: must be a whole number >= 0")
    if args.output_dt > args.duration:
        raise ValueError(f"--output-dt {args.output_dt:g} s is longer than --duration "
                         f"{args.duration:g} s")
    if args.max_step > args.duration:
        raise ValueError(f"--max-step {args.max_step:g} s is longer than --duration "
                         f"{args.duration:g} s")
    if args.no_inertia and robot.rod.damping <= 0:
        raise ValueError(f"--no-inertia needs [rod] damping > 0 in {args.robot} (without "
                         f"inertia or damping every instant is the static equilibrium: use "
                         f"solve)")
    if args.log == "-" and args.json:
        raise UsageError("tendonsense simulate: -o - and --json would both go to standard "
                         "output (write the log into a file, or leave out --json)")
    if args.log != "-":
        _writable(args.log, "-o/--log")
    if args.plot:
        _writable(args.plot, "--plot")


def _check_estimate(args, robot, tensions, displacements):
    if args.force_walk is not None and not args.dynamic:
        raise UsageError("tendonsense estimate: --force-walk goes with --dynamic")
    if args.dynamic:
        if any(getattr(u, "located", False) for u in args.unknown):
            raise UsageError("tendonsense estimate: --dynamic takes forces at known points "
                             "(a location range 'A:B' or '?' is estimated quasi-statically)")
    args.logs = None
    if args.readings is not None and _many_logs(args):
        return _check_logs(args, robot, tensions, displacements)
    for flag, given in (("--workers", args.workers is not None), ("--scheduler", args.scheduler)):
        if given:
            raise UsageError(f"tendonsense estimate: {flag} goes with several logs "
                             f"(--readings PATTERN -o OUTDIR/)")
    if args.readings is not None:
        args.readings = args.readings[0]
    if args.cpu is not None and args.readings != "-":
        raise UsageError("tendonsense estimate: --cpu goes with a live log (--readings -)")
    if args.readings is None:
        for flag, given in (("--view", args.view), ("-o/--estimates", args.estimates),
                            ("--dynamic", args.dynamic)):
            if given:
                raise UsageError(f"tendonsense estimate: {flag} goes with --readings")
        if not displacements:
            raise UsageError("tendonsense estimate: give the readings: --displacement NAME=M "
                             "and --tension NAME=N per measured tendon, or --readings LOG.csv")
        inputs.readings(robot, displacements, tensions)
        inputs.check_unknowns(robot, list(displacements), args.unknown)
        inputs.check_stuck(robot, args.sliding, tensions,
                           any(getattr(u, "located", False) for u in args.unknown))
        return
    if displacements or tensions:
        raise UsageError("tendonsense estimate: --readings replaces --displacement/--tension")
    if args.plot:
        raise UsageError("tendonsense estimate: --plot draws one reading; a log's estimates "
                         "are in its output rows")
    to_file = args.estimates not in (None, "-")
    if to_file:
        if args.view:
            raise UsageError("tendonsense estimate: --view streams the rows to standard "
                             "output; leave out -o (or redirect standard output)")
        _writable(args.estimates, "-o/--estimates")
    elif args.json:
        raise UsageError("tendonsense estimate: --json: the rows go to standard output as "
                         "CSV; give -o OUT.csv for the rows in a file and a JSON summary")
    if args.readings != "-":
        from .readings import (has_time, lagging, motion_step_error, read_readings,
                               released_at_start, stuck_rows_error)
        args.log = read_readings(args.readings, robot)
        inputs.check_unknowns(robot, args.log[0], args.unknown)
        if args.dynamic and not has_time(args.readings):
            raise ReadingsError(f"{args.readings}: no time column: estimation in motion "
                                f"(--dynamic) needs each row's time stamp, s")
        if args.dynamic and (error := motion_step_error(args.readings, args.log[1])):
            raise ReadingsError(error)
        if any(getattr(u, "located", False) for u in args.unknown):
            if error := stuck_rows_error(args.readings, args.log[1]):
                raise ReadingsError(error)
        else:  # (a located force is estimated at rest only: no hint of --dynamic)
            for note in (released_at_start(args.log[1], robot, args.tension_noise),
                         "" if args.dynamic else lagging(args.log[1], robot, args.log[0],
                                                          args.length_noise)):
                if note:
                    args.notes.append(f"{args.readings}: note: {note}")
    _no_damping(args, robot)


def _no_damping(args, robot):
    """The note that --dynamic on a robot without damping filters the quasi-static model."""
    if args.dynamic and robot.rod.damping <= 0:
        args.notes.append(f"note: {args.robot} has no [rod] damping: --dynamic filters the "
                          f"quasi-static model")


#: the characters of a --readings pattern
PATTERN = frozenset("*?[")


def _many_logs(args) -> bool:
    """Whether estimate --readings names several logs: more than one file, a pattern, or an
    output folder (-o OUTDIR/)."""
    out = args.estimates
    return (len(args.readings) > 1 or any(PATTERN & set(r) for r in args.readings)
            or (out not in (None, "-") and (out.endswith(("/", os.sep)) or Path(out).is_dir())))


def _check_logs(args, robot, tensions, displacements):
    """estimate over several logs: the patterns expanded, the output folder and the cluster
    options checked, before any log is read or a cluster started."""
    from .readings import log_outputs
    _check_cluster(args)
    if displacements or tensions:
        raise UsageError("tendonsense estimate: --readings replaces --displacement/--tension")
    for flag, given in (("--view", args.view), ("--plot", args.plot)):
        if given:
            raise UsageError(f"tendonsense estimate: {flag} goes with a single log")
    if args.estimates in (None, "-"):
        raise UsageError("tendonsense estimate: several logs (--readings) need -o OUTDIR/, a "
                         "folder for one output per log")
    logs: list[str] = []
    for r in args.readings:
        if r == "-":
            raise UsageError("tendonsense estimate: --readings -: standard input is one live "
                             "log, not one of several")
        found = sorted(glob.glob(r)) if PATTERN & set(r) else [r]
        if found == [r] and args.readings.count(r) > 1:  # (patterns that overlap: each once)
            raise UsageError(f"tendonsense estimate: --readings {r} given twice")
        if not found:
            raise ReadingsError(f"--readings {r}: no file matches")  # a missing input: 1
        logs += [f for f in found if f not in logs]
    out = Path(args.estimates)
    folder = out if out.exists() else out.parent
    if not out.exists() and not args.estimates.endswith(("/", os.sep)):
        raise UsageError(f"tendonsense estimate: -o {args.estimates}: several logs write one "
                         f"output each into a folder: -o {args.estimates}/ makes it")
    if out.exists() and not out.is_dir():
        raise ValueError(f"-o/--estimates {args.estimates}: not a folder (several logs write "
                         f"one output each into a folder)")
    if not folder.is_dir():
        raise ValueError(f"-o/--estimates {args.estimates}: no folder {str(folder)!r}")
    if not os.access(folder, os.W_OK):
        raise ValueError(f"-o/--estimates {args.estimates}: the folder {str(folder)!r} is not "
                         f"writable")
    log_outputs(logs, out)
    inputs.check_unknowns(robot, robot.tendon_names, args.unknown)
    args.logs = logs
    _no_damping(args, robot)


def _check_cluster(args):
    """--workers and --scheduler: one of them at most, a worker at least, Dask installed."""
    if args.workers is not None and args.scheduler is not None:
        raise UsageError(f"tendonsense {args.command}: --workers (a local cluster) or "
                         f"--scheduler (a running one), not both")
    if args.workers is not None and args.workers < 1:
        raise ValueError(f"tendonsense {args.command}: --workers {args.workers}: needs at "
                         f"least one worker process")
    if (args.workers is not None or args.scheduler is not None) and \
            importlib.util.find_spec("distributed") is None:
        raise ValueError("--workers and --scheduler run on Dask: pip install "
                         "'tendonsense[distributed]'")


def _on_cluster(args):
    """A context giving a Dask client (--workers, --scheduler), or None: work here."""
    from contextlib import nullcontext
    if args.workers is None and args.scheduler is None:
        return nullcontext()
    from .distributed import cluster
    return cluster(args.workers or 1, args.scheduler)


def _point_forces(args):
    return [(pf[0], pf[1:]) for pf in args.point_force]


def _resolve_robot(args) -> None:
    """The analyses' robot: positional, or the old ``--robot``; a table given first is the
    table (``experiments TABLE.csv --robot R``, as before)."""
    option = getattr(args, "robot_option", None)
    positional = args.robot
    if positional.endswith(".csv") and hasattr(args, "csv"):
        if args.csv != str(DATA / "paper_experiments.csv"):
            raise UsageError(f"tendonsense {args.command}: the robot file comes first, then "
                             f"the experiments table")
        args.csv = positional
        positional = _robot_default(args)
    if option is not None:
        if positional != _robot_default(args):
            raise UsageError(f"tendonsense {args.command}: the robot file given twice")
        positional = option
    args.robot = positional


def _robot_default(args) -> str:
    return str(DATA / ("paper_simulation.toml" if args.command in ("sensitivity", "resolution")
                       else "paper_prototype.toml"))


# ------------------------------------------------------------------------------ commands

def _beside(path: str, suffix: str) -> str:
    """``shape.png`` → ``shape_location.png``."""
    p = Path(path)
    return str(p.with_name(p.stem + suffix + p.suffix))


def _given(args) -> str:
    """What the user gave, for a figure's title."""
    parts = [f"{n} length change {v * 1e3:+.3f} mm" for n, v in args.displacement.items()]
    parts += [f"{n} tension {v:.3g} N" for n, v in args.tension.items()]
    parts += _forces_text(args)
    parts += [f"{n} {'stuck' if d == 'stuck' else f'sliding {d}'}"
              for n, d in getattr(args, "sliding", {}).items()]
    return "given: " + (", ".join(parts) if parts else "no tension (gravity only)")


def _forces_text(args) -> list[str]:
    return [f"{np.linalg.norm(f):.3g} N known force at X = {X:g} m along "
            f"{_vector(np.asarray(f, float) / np.linalg.norm(f))}" if np.any(f) else
            f"a zero known force at X = {X:g} m" for X, f in _point_forces(args)]


def _plot_shape(args, robot, result, unknowns=()):
    from . import plotting
    estimated = plotting.estimated_forces(result, unknowns)
    written = [args.plot]
    if "location_profile" in result.extra:
        written.append(plotting.location_profile(result, _beside(args.plot, "_location"),
                                                 args.length_noise))
    what = {"solve": "shape under the given loads (forward statics)",
            "fk": "shape for the given tendon length changes (forward kinematics)",
            "estimate": "shape and forces estimated from tendon readings"}[args.command]
    plotting.shape(result, args.plot, robot, forces=_point_forces(args), estimated=estimated,
                   title=f"{robot.name}: {what}", given=_given(args),
                   failed=None if result.converged else result.note,
                   sliding=getattr(args, "sliding", None))
    return written


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


def _check_analysis(args, robot):
    """The analyses' robot (three tendons or more: a 3-D tip force), points and output
    folder (made when the results are written)."""
    if args.command in ("sensitivity", "resolution") and len(robot.tendons) < 3:
        raise ValueError(f"{args.robot}: {args.command} estimates a 3-D tip force, which "
                         f"takes at least 3 tendons; the robot has {len(robot.tendons)}")
    if args.command == "sensitivity" and args.points < 1:
        raise ValueError(f"tendonsense sensitivity: --points {args.points}: at least 1")
    if not args.out_dir.strip():
        raise ValueError("-o/--out-dir: an empty name (a folder name is needed)")
    out = Path(args.out_dir)
    if out.exists() and not out.is_dir():
        raise ValueError(f"-o/--out-dir {args.out_dir}: not a folder")
    parent = out if out.exists() else out.parent  # (made in a folder that exists: a slip in
    # a parent's name makes no tree of folders)
    _folder_exists(f"-o/--out-dir {args.out_dir}", parent,
                   " (the output folder is made in one that exists)")
    if not os.access(parent, os.W_OK):
        raise ValueError(f"-o/--out-dir {args.out_dir}: the folder {str(parent)!r} is not "
                         f"writable")
    for name in (*ANALYSIS_FILES[args.command], f"{args.command}_summary.json"):
        for what, inp in (("the robot file", args.robot),
                          ("the table", getattr(args, "csv", None))):
            if inp and (out / name).is_file() and os.path.samefile(out / name, inp):
                raise ValueError(f"-o/--out-dir {args.out_dir}: writes {name}, which is {what} "
                                 f"({inp}): writing it would overwrite an input")


#: the files an analysis writes into its folder (and ``<command>_summary.json``)
ANALYSIS_FILES = {"sensitivity": ("sensitivity_single.csv", "sensitivity_3d.json",
                                  "sensitivity_single.png", "sensitivity_3d.png"),
                  "resolution": ("resolution.csv", "resolution.png"),
                  "compare": ("compare.csv", "compare.png")}


def _analysis_run(args, robot):
    from . import analyses, plotting
    from .readings import write_csv_atomic, write_text_atomic
    out = Path(args.out_dir)

    def folder():  # made once the results are in: a failed run leaves none
        try:
            out.mkdir(exist_ok=True)
        except OSError as exc:
            raise ValueError(f"-o/--out-dir {args.out_dir}: cannot make the folder "
                             f"({exc.strerror})") from None

    prog = _Progress(args, args.command)
    files = []
    if args.command == "sensitivity":
        rows = analyses.sensitivity_single(robot, n_y=args.points, progress=prog)
        entries = analyses.sensitivity_3d(robot, progress=prog)
        summary = {"single_tendon": analyses.single_summary(rows),
                   "three_tendons": analyses.summary_3d(entries),
                   "left_out": {"single_tendon": sum("estimate_N" not in r for r in rows),
                                "three_tendons": sum(not e["converged"] for e in entries)},
                   "unstable": {"single_tendon": sum(r.get("unstable", False) for r in rows),
                                "three_tendons": sum(e["unstable"] for e in entries)}}
        keys = sorted({k for r in rows for k in r})
        folder()
        table_, json_, png_, png_3d = (out / name for name in ANALYSIS_FILES["sensitivity"])
        write_csv_atomic(table_, keys, [[r.get(k, "") for k in keys] for r in rows])
        write_text_atomic(json_, json.dumps(entries))
        ok = all("note" not in r and all(np.isfinite(v) for k, v in r.items()
                                           if k.endswith("_N")) for r in rows) \
            and all(e["converged"] for e in entries)
        files += [table_, json_, plotting.sensitivity_single(rows, png_),
                  plotting.ellipsoids(entries, png_3d)]
    elif args.command == "resolution":
        rows = analyses.resolution(robot, progress=prog)
        summary = analyses.resolution_summary(rows)
        ok = all(r["converged"] for r in rows)
        keys = ["force_gF", "resolution_x_g", "resolution_y_g", "resolution_z_g", "converged"]
        folder()
        table_, png_ = (out / name for name in ANALYSIS_FILES["resolution"])
        write_csv_atomic(table_, keys,
                         [[" ".join(map(str, r[k])) if k == "force_gF" else r[k] for k in keys]
                          for r in rows])
        files += [table_, plotting.resolution(rows, png_)]
    else:
        from . import experiments
        table = analyses.compare(robot, args.table, progress=prog)
        summary = {m: experiments.summary(rows) for m, rows in table.items()}
        for m, earlier in analyses.same_estimates(table).items():
            summary[m]["same_as"] = earlier
        ok = all(r.converged for rows in table.values() for r in rows)
        folder()
        table_, png_ = (out / name for name in ANALYSIS_FILES["compare"])
        write_csv_atomic(table_, ["model", "case", "applied", "estimate", "error", "converged",
                                  "note"],
                         [[m, r.case, " ".join(map(str, r.applied)),
                           "" if r.ours is None else " ".join(map(str, r.ours)),
                           "" if r.ours is None else r.error(r.ours),
                           "true" if r.converged else "false", r.note]
                          for m, rows in table.items() for r in rows])
        files += [table_, plotting.comparison(table, png_)]
    prog.close()
    write_text_atomic(out / f"{args.command}_summary.json", json.dumps(summary, indent=1))
    files.append(out / f"{args.command}_summary.json")
    if args.json:
        print(json.dumps({"summary": summary, "files": [str(f) for f in files]}))
    else:
        print(_summary_text(args.command, summary))
        if args.command == "compare":
            _other_robot_note(args, robot)
        print("wrote " + ", ".join(str(f) for f in files))
    return ok


def _other_robot_note(args, robot):
    """A line under the paper's experiments estimated with another robot than its prototype."""
    from .robot import load_robot
    if args.csv == str(DATA / "paper_experiments.csv") and robot != load_robot(
            _robot_default(args)):
        print(f"tendonsense: note: these are the readings of the paper's prototype; {args.robot} "
              f"is not its robot file, so the errors also say how far that robot is from the "
              f"prototype", file=sys.stderr)


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
        if n := summary.get("left_out", {}).get("single_tendon"):
            lines.append(f"  ({n} cases left out: slack, or not solved; their notes are in "
                         f"the table)")
        if n := summary.get("unstable", {}).get("single_tendon"):
            lines.append(f"  ({n} cases are unstable equilibria, column 'unstable' of "
                         f"the table: the rod would leave the shape solved, e.g. out of the "
                         f"plane of its loads; kept in the means)")
        lines.append("three tendons: mean relative error of the estimated 3-D tip force "
                     "(over the applied forces)")
        for src, v in summary["three_tendons"].items():
            lo, hi = v["paper_range"]
            lines.append(f"  {src} error: mean {pct(v['mean'])}, from "
                         f"{pct(v['min_over_forces'])} to {pct(v['max_over_forces'])} "
                         f"(paper: {pct(lo)} to {pct(hi)})")
        if n := summary.get("unstable", {}).get("three_tendons"):
            lines.append(f"  ({n} of the forces at unstable equilibria, 'unstable' in the "
                         f"JSON; kept in the means)")
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
            if "same_as" in v:
                lines.append(f"    the same estimates as {v['same_as']} on every row: the "
                             f"strain modes between the two carry no load in these rows")
    return "\n".join(lines)


def _signed(v: float, digits: int) -> str:
    """``v`` with its sign and ``digits`` decimals, a value that rounds to zero as +0 (not
    -0.0000)."""
    text = f"{v:+.{digits}f}"
    return "+" + text[1:] if float(text) == 0 else text


def _vector(v) -> str:
    return "(" + ", ".join(f"{x:.4g}" for x in v) + ")"


def unknown_label(u) -> str:
    """Words for an unknown load, e.g. "force at X = 0.25 m along (0, 0, -1)"."""
    if isinstance(u, PointForceUnknown):
        where = ("somewhere on the rod" if u.X is None else
                 f"somewhere in X = {u.X[0]:g}:{u.X[1]:g} m" if u.located else f"at X = {u.X:g} m")
        return f"force {where} along {_vector(u.direction)}"
    return "gravity scale (1 = the robot file's gravity)"


def magnitude_text(u, value: float, sigma=None) -> str:
    """A magnitude with its unit, e.g. "0.0759 N (7.7 gF) ± 0.0027 N (0.3 gF) (1 σ)"."""
    if isinstance(u, PointForceUnknown):
        return newtons(value, sigma) + (" (1 σ)" if sigma is not None else "")
    return f"{value:.4g}" + (f" ± {sigma:.2g} (1 σ)" if sigma is not None else "")


def range_text(u, low: float, high: float) -> str:
    """A magnitude's range over a friction band, open where it is infinite."""
    return between(low, high, newtons if isinstance(u, PointForceUnknown) else "{:.4g}".format)


def _print_result(result, as_json: bool, title: str, robot, unknowns=()):
    if as_json:
        print(json.dumps(result.to_json()))
        return
    if not result.converged:
        print(f"{title} ({robot.name}): NOT CONVERGED: {result.extra.get('note', '')}")
        print("no result: the last iterate is no shape the robot holds (--json gives it, marked "
              "\"converged\": false; --plot draws it, stamped)")
        return
    print(f"{title} ({robot.name}): converged in {result.iterations} "
          f"iteration{'' if result.iterations == 1 else 's'} "
          f"(relative residual {result.residual:.1e})")
    if result.magnitudes is not None:
        print("estimated loads:")
        for i, m in enumerate(result.magnitudes):
            s = result.sigma[i] if result.sigma is not None else None
            u = unknowns[i] if i < len(unknowns) else None
            label = unknown_label(u) if u is not None else f"magnitude {i + 1}"
            if "magnitude_range" in result.extra:  # a stuck tendon: the range, not one value
                print(f"  {label}: {range_text(u, *result.extra['magnitude_range'][i])} "
                      f"(a stuck tendon; {magnitude_text(u, m)} at the middle of its friction "
                      "band)")
            else:
                print(f"  {label}: {magnitude_text(u, m, s)}")
            X = result.extra.get("locations", [None] * (i + 1))[i]
            if X is not None:
                sx = result.extra["location_sigma"][i]
                print(f"    acting at X = {X:.4g} m ± {sx:.2g} m ({X * 1e3:.0f} ± "
                      f"{sx * 1e3:.2g} mm) (1 σ)")
    if result.note:
        print(f"tendonsense: note: {result.note}", file=sys.stderr)
    print("tendons (length change: negative = pulled in):")
    for name in result.tensions:
        T, y = result.tensions[name], result.displacements[name]
        print(f"  {name}: tension {T:.4f} N ({T / GF:.1f} gF), "
              f"length change {y:+.6f} m ({y * 1e3:+.3f} mm)")
    print("markers (global frame, x y z):")
    X = {m.name: m.X for m in robot.markers}
    for name, p in result.markers.items():
        print(f"  {name} (X = {X.get(name, float('nan')):g} m): "
              f"{' '.join(_signed(v, 4) for v in p)} m  "
              f"({' '.join(_signed(v * 1e3, 1) for v in p)} mm)")


def _single(args, robot) -> bool:
    """solve, fk or a single estimate: the result printed, the figure drawn if asked."""
    if args.command != "estimate":  # (estimate refuses a slack tendon stuck, and pays out none)
        measured = getattr(args, "displacement", None) or {}
        for name, direction in (args.sliding or {}).items():
            if direction != "in" and name not in measured and not args.tension.get(name):
                print(f"tendonsense {args.command}: note: --sliding {name}={direction}: {name} "
                      f"is slack (0 N), its friction changes nothing (another tendon meant?)",
                      file=sys.stderr)
    if args.command == "estimate":
        from .estimation import estimate
        result = estimate(robot, args.displacement, args.tension, args.unknown,
                          _point_forces(args), Noise(args.length_noise, args.tension_noise),
                          sliding=args.sliding)
        title = "estimation"
    elif args.command == "solve":
        from .forward import solve
        result = solve(robot, args.tension, _point_forces(args), sliding=args.sliding,
                       settle=args.settle)
        title = "forward statics"
    else:
        from .forward import forward_kinematics
        result = forward_kinematics(robot, args.displacement, args.tension,
                                    _point_forces(args), sliding=args.sliding)
        title = "forward kinematics"
    # the figure first: a reader of standard output that goes away (``| head``) stops the
    # printing, not the figure
    written = _plot_shape(args, robot, result, getattr(args, "unknown", ())) if args.plot \
        else []
    _print_result(result, args.json, title, robot, args.unknown
                  if args.command == "estimate" else ())
    if written and not args.json:
        print("wrote " + ", ".join(str(p) for p in written))
    return result.converged


def _log(args, robot) -> bool:
    """estimate --readings: a file log on the compiled scan, rows out as chunks finish (to
    standard output, or into ESTIMATES.csv atomically); a live log row by row."""
    noise = Noise(args.length_noise, args.tension_noise)
    if args.readings == "-" or args.view:
        if args.cpu is not None:
            pin({args.cpu})
        return _stream(args, robot, noise)
    from . import readings as rd
    from .logs import disagreeing, estimate_chunks, misfit_rows
    measured, samples = args.log
    forces, unknowns = _point_forces(args), args.unknown
    where = rd.located(unknowns)
    follow = rd.with_sliding(robot)
    with_shape = any(s.markers for s in samples)
    to_file = args.estimates not in (None, "-")
    out = rd.AtomicText(args.estimates) if to_file else sys.stdout
    prog = _Progress(args, "estimate")
    good = shown = disagree = 0
    try:
        writer = csv.writer(out, lineterminator="\n")
        writer.writerow(rd.output_header(robot, len(unknowns), with_shape, where, follow))
        for first, estimates in estimate_chunks(robot, measured, samples, unknowns, forces,
                                                noise, args.dynamic, _walk(args)):
            for s, r in zip(samples[first:], estimates):
                if s.error and shown < rd.SKIPPED_SHOWN:  # the rest counted at the end
                    shown += 1
                    _skipped_row(args.readings, s.row, s.error)
                writer.writerow(rd.output_row(robot, s, r, len(unknowns), with_shape, where,
                                              follow))
                good += r.converged
            disagree += disagreeing(estimates)
            out.flush()
            prog(first + len(estimates), len(samples))
        if to_file:
            out.commit()
    except BrokenPipeError:  # the reader went away: stop quietly
        sys.stderr.close()
        return True
    finally:
        prog.close()
        if to_file:
            out.close()
    skipped = sum(bool(s.error) for s in samples)
    _more_skipped(args.readings, skipped - shown)
    if note := misfit_rows(disagree, len(samples)):
        print(f"tendonsense: {args.readings}: note: {note}", file=sys.stderr)
    if to_file:
        summary = {"samples": len(samples), "converged": good, "skipped": skipped,
                   "output": str(args.estimates)}
        if args.json:
            print(json.dumps(summary))
        else:
            print(f"estimated {_counts(len(samples), good, skipped)}; wrote {args.estimates}")
    return good == len(samples)


def _counts(samples: int, converged: int, skipped: int) -> str:
    """"N samples: C converged, F not converged, S skipped" (F only if there are any)."""
    failed = samples - converged - skipped
    return (f"{samples} sample{'' if samples == 1 else 's'}: {converged} converged, "
            + (f"{failed} not converged, " if failed else "") + f"{skipped} skipped")


def _skipped_row(log, row: int, why: str):
    """The line naming a log's skipped row."""
    print(f"tendonsense: {log}: row {row} skipped: {why}", file=sys.stderr)


def _more_skipped(log, n: int, why: str = " (the output's note column says why)"):
    """The line counting a log's skipped rows beyond those named."""
    if n > 0:
        print(f"tendonsense: {log}: {n} more rows skipped{why}", file=sys.stderr)


def _logs(args, robot) -> int:
    """estimate over several logs (:func:`tendonsense.distributed.estimate_logs`): one output
    per log in OUTDIR, on a Dask cluster with --workers or --scheduler, else here one after
    another; a log that cannot be used is named on stderr and the others written. Exit
    status 1 if a log failed, 3 if a row did not converge."""
    from .distributed import estimate_logs
    out = Path(args.estimates)
    with _on_cluster(args) as client:  # before the bar's thread: a local cluster may fork
        prog = _Progress(args, "estimate")
        made = not out.exists()
        try:
            try:
                out.mkdir(exist_ok=True)
            except OSError as exc:
                raise ValueError(f"-o/--estimates {args.estimates}: cannot make the folder "
                                 f"({exc.strerror})") from None
            done = estimate_logs(
                client, robot, args.logs, out, args.unknown, _point_forces(args),
                Noise(args.length_noise, args.tension_noise), args.dynamic, _walk(args), prog)
        finally:
            prog.close()
    failed = [s for s in done if s.error]
    wrote = f"wrote into {out}"
    if len(failed) == len(done):  # no output: no folder made for it
        if made and not any(out.iterdir()):
            out.rmdir()
        wrote = "nothing written"
    for s in done:
        if s.error:  # (the others written: the command goes on)
            print(f"tendonsense estimate: error: {s.error}", file=sys.stderr)
        if s.note:
            print(f"tendonsense: {s.log}: note: {s.note}", file=sys.stderr)
        for row, why in s.skipped_rows:
            _skipped_row(s.log, row, why)
        _more_skipped(s.log, s.skipped - len(s.skipped_rows))
    total = {k: sum(getattr(s, k) for s in done) for k in ("samples", "converged", "skipped")}
    if args.json:
        print(json.dumps({"logs": [s.to_json() for s in done], **total,
                          "failed": [s.log for s in failed],
                          "output": "" if len(failed) == len(done) else str(out)}))
    else:
        print(f"estimated {len(done) - len(failed)} of {len(done)} logs ("
              f"{_counts(total['samples'], total['converged'], total['skipped'])})"
              + (f"; {len(failed)} failed" if failed else "") + f"; {wrote}")
    if failed:
        return 1
    return 0 if total["converged"] == total["samples"] else _not_converged()


def _walk(args) -> float:
    from .inputs import WALK
    return WALK if args.force_walk is None else args.force_walk


def _stream(args, robot, noise) -> bool:
    """Output rows on stdout as they are estimated (or into ESTIMATES.csv, atomically at the
    end); an interrupt ends cleanly, every row read so far answered."""
    from . import readings as rd
    from .logs import stream_readings

    source = "<stdin>" if args.readings == "-" else args.readings
    count = dict(rows=0, converged=0, skipped=0)  # as rows are answered: an interrupt keeps it

    def skipped(s):  # the first rows named, the rest counted at the end (as a file's)
        count["skipped"] += 1
        if count["skipped"] <= rd.SKIPPED_SHOWN:
            _skipped_row(source, s.row, s.error)

    def answered(s, r):
        count["rows"] += 1
        count["converged"] += bool(r is not None and r.converged)
        if viewer is not None:
            viewer.push(r, tensions=s.tensions, forces=forces, unknowns=args.unknown,
                        time_s=s.time, note="" if r is not None else s.error)

    if args.readings == "-" and hasattr(sys.stdin, "reconfigure"):
        # whatever the locale: a byte that is not UTF-8 skips its row
        sys.stdin.reconfigure(encoding=rd.CSV_ENCODING, errors="surrogateescape")
    fh = (sys.stdin if args.readings == "-"
          else open(args.readings, newline="", encoding=rd.CSV_ENCODING))
    viewer = None
    lines, forces = fh, _point_forces(args)
    if args.view:
        replay = args.readings != "-"
        viewer = _open_view(args, robot, f"{robot.name}: " + (
            f"replay of {args.readings}" if replay else "live readings"), pause=replay)
        if replay:
            lines = _paced(fh, viewer)
    to_file = args.estimates not in (None, "-")
    out = rd.AtomicText(args.estimates) if to_file else sys.stdout
    done = False  # the input ended or was interrupted (else an error: nothing written)
    try:
        with fh:
            stream_readings(robot, lines, out, args.unknown, forces, noise, source, skipped,
                            answered, args.dynamic, _walk(args), lambda note: print(
                                f"tendonsense: {source}: note: {note}", file=sys.stderr))
        if not count["rows"]:
            raise ReadingsError(f"{source}: no data rows below the header")
        done = True
        if viewer is not None and args.readings != "-":
            print("tendonsense: the log is done; the view stays until Ctrl-C", file=sys.stderr)
            while True:
                time.sleep(0.5)
    except KeyboardInterrupt:  # the rows answered so far stand
        done = True
    except BrokenPipeError:  # the reader went away: stop quietly
        done = True
        sys.stderr.close()
        return True
    finally:
        if viewer is not None:
            viewer.close()
        if to_file:
            if done and count["rows"]:
                out.commit()
            out.close()
    _more_skipped(source, count["skipped"] - rd.SKIPPED_SHOWN)
    if to_file:
        if not count["rows"]:
            print(f"tendonsense: {source}: no row answered; nothing written", file=sys.stderr)
            return True
        summary = {"samples": count["rows"], "converged": count["converged"],
                   "skipped": count["skipped"], "output": str(args.estimates)}
        print(json.dumps(summary) if args.json else
              f"estimated {_counts(count['rows'], count['converged'], count['skipped'])}; "
              f"wrote {args.estimates}")
    return count["converged"] == count["rows"]


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
        csv.writer(out, lineterminator="\n").writerow(raw)
        yield out.getvalue()


def _open_view(args, robot, title=None, pause=False):
    from .view import ViewProcess, explore
    if args.command == "view":
        viewer = explore(robot, args.port, args.host, args.max_tension, args.max_force)
    else:
        viewer = ViewProcess(robot, args.port, args.host, title, pause)
    if args.host not in ("127.0.0.1", "localhost", "::1"):  # once it is served
        print(f"tendonsense: warning: the view is served on {args.host}:{args.port}, visible "
              f"to other machines on the network", file=sys.stderr)
    print(f"tendonsense: view at http://{args.host}:{args.port}", file=sys.stderr)
    return viewer


def _view(args, robot) -> bool:
    """Serve until Ctrl-C."""
    viewer = _open_view(args, robot)
    try:
        while True:
            time.sleep(0.5)
    except KeyboardInterrupt:
        pass
    finally:
        viewer.close()
    return True


def _experiments(args, robot) -> bool:
    from . import experiments
    prog = _Progress(args, "experiments")
    rows = experiments.run(robot, args.table, progress=prog)
    prog.close()
    summary = experiments.summary(rows)
    if args.json:
        print(json.dumps({"cases": [{"case": r.case, "applied": r.applied.tolist(),
                                    "estimate": None if r.ours is None else r.ours.tolist(),
                                    "paper_estimate": None if r.paper is None else r.paper.tolist(),
                                    "converged": r.converged, "note": r.note}
                                   for r in rows], **summary}))
        return summary["converged"] == summary["rows"]
    print("estimated load magnitudes (N for forces, a scale factor for gravity) against the "
          "applied ones")
    print(f"{'case':<18} {'applied':>22} {'ours':>22} {'paper':>22} {'err ours':>9} "
          f"{'err paper':>9}")
    fmt = lambda v: "-" if v is None else " ".join(f"{x:.4f}" for x in v)  # noqa: E731
    pct = lambda v: "n/a" if np.isnan(v) else f"{v:.1%}"  # noqa: E731
    for r in rows:
        print(f"{r.case:<18} {fmt(r.applied):>22} {fmt(r.ours):>22} {fmt(r.paper):>22} "
              f"{pct(r.error(r.ours)):>9} {pct(r.error(r.paper)):>9}")
    print(f"mean relative error: ours {pct(summary['mean_relative_error_ours'])}, paper "
          f"{pct(summary['mean_relative_error_paper'])}; {summary['converged']}/"
          f"{summary['rows']} rows converged")
    for r in rows:
        if not r.converged:
            print(f"tendonsense: case {r.case}: no estimate: {r.note or 'not converged'}",
                  file=sys.stderr)
    _other_robot_note(args, robot)
    return summary["converged"] == summary["rows"]


def _mm(v):
    return "—" if v is None else f"{v * 1e3:.3f} mm"


def _parameter_text(k: str, v: float, sigma: float | None = None) -> str:
    label, unit = inputs.parameter_words(k)
    band = "" if sigma is None else f" ± {sigma:.2g}{unit} (1 σ)"
    return f"{label} ({k}): {v:.6g}{unit}{band}"


def _fitted_header(args, robot, fit, source: str) -> list[str]:
    """The comment block on top of FITTED.toml: how it was made."""
    from .robot import FITTED_HEADER_MARK
    now = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    lines = [f"{FITTED_HEADER_MARK.lstrip('# ')} {__version__} on {now}",
             f"from {source}; robot file {args.robot}",
             "parameters fitted: " + ", ".join(f"{k} = {v:.6g}" for k, v in
                                               fit.parameters.items())]
    for what, after, before in (("marker", fit.marker_rmse, fit.initial_marker_rmse),
                                ("tendon-length", fit.displacement_rmse,
                                 fit.initial_displacement_rmse)):
        if after is not None:  # (no "before" where the file's values give no motion to fit)
            lines.append(f"{what} RMSE {_mm(after)}" + (
                "" if before is None else f" (with the robot file's values {_mm(before)})"))
    if fit.warning:
        lines.append(f"WARNING: {fit.warning}")
    return lines


def _identify(args, robot) -> bool:
    from .identification import identify, identify_damping
    from .readings import SKIPPED_SHOWN, write_text_atomic
    from .robot import fitted_toml
    prog = _Progress(args, "identify")
    if args.readings is not None:
        skipped = [r for r in args.log[1] if r.error]
        for r in skipped[:SKIPPED_SHOWN]:
            _skipped_row(args.readings, r.row, r.error)
        _more_skipped(args.readings, len(skipped) - SKIPPED_SHOWN, "")
        fit = identify_damping(robot, args.log[1], _point_forces(args),
                               inertia=not args.no_inertia, marker_noise=args.marker_noise,
                               length_noise=args.length_noise, progress=prog)
        source = (f"{args.readings} ({len(args.log[1]) - len(skipped)} rows"
                  + (f", {len(skipped)} skipped" if skipped else "") + ")")
    else:
        fit = identify(robot, args.snapshots_read, args.param or inputs.DEFAULT_PARAMETERS,
                       progress=prog, marker_noise=args.marker_noise,
                       length_noise=args.length_noise, crossval=args.crossval)
        n = len(args.snapshots_read)
        source = f"{args.snapshots} ({n} snapshot{'s' if n != 1 else ''})"
    prog.close()
    written = []
    if fit.converged:
        if args.fitted_robot:
            text = Path(args.robot).read_text(encoding="utf-8-sig")
            write_text_atomic(args.fitted_robot,
                              fitted_toml(text, fit.robot,
                                          _fitted_header(args, robot, fit, source)))
            written.append(args.fitted_robot)
        if args.plot:
            from . import plotting
            plotting.calibration(fit, args.plot, source)
            written.append(args.plot)
    if args.json:
        print(json.dumps(fit.to_json()))
        return fit.converged
    print(f"identification of {robot.name} from {source}: "
          f"{'converged' if fit.converged else 'NOT CONVERGED'} in {fit.iterations} "
          f"{'simulations' if args.readings else 'iterations'}"
          + (f": {fit.note}" if fit.note else ""))
    for k, v in fit.parameters.items():
        print(f"  {_parameter_text(k, v, fit.sigma.get(k))}")
    if "damping" in fit.parameters:
        fitted = robot.with_parameters(damping=fit.parameters["damping"]).rod
        print(f"  relaxation time τ = 3η/E: {fitted.relaxation_time * 1e3:.4g} ms")
    for what, after, before in (("marker", fit.marker_rmse, fit.initial_marker_rmse),
                                ("tendon-length", fit.displacement_rmse,
                                 fit.initial_displacement_rmse)):
        if after is not None:  # (no "before" where the file's values give no motion to fit)
            print(f"  {what} RMSE: {_mm(after)} after the fit"
                  + ("" if before is None else f", {_mm(before)} with the robot file's values"))
    if fit.misfit is not None:
        print(f"  residuals: {fit.misfit:.2g} times the noise assumed (RMS; about 1 when the model "
              f"explains the data)")
    if fit.warning:
        print(f"tendonsense identify: warning: {fit.warning}", file=sys.stderr)
    if fit.crossval:
        print("  cross-validation (each snapshot predicted by a fit without it):")
        for c in fit.crossval:
            errs = ", ".join(f"{w} {_mm(v)} (fitted {_mm(f)})" for w, v, f in (
                ("markers", c.marker_error, c.fitted_marker_error),
                ("lengths", c.displacement_error, c.fitted_displacement_error))
                if f is not None)
            print(f"    snapshot {c.snapshot}: {errs}" + (f"; {c.note}" if c.note else ""))
    for path in written:
        print(f"  wrote {path}")
    if not fit.converged and (args.fitted_robot or args.plot):
        print("  nothing written: the fit did not converge")
    return fit.converged


def _simulate(args, robot) -> bool:
    from .readings import write_csv_atomic
    from .simulation import simulate
    if coarse := inputs.coarse_step(robot, args.max_step):
        print(f"tendonsense simulate: warning: {coarse}", file=sys.stderr)
    if robot.rod.damping <= 0 and not args.no_inertia:
        print(f"tendonsense simulate: note: {args.robot} has no damping ([rod] damping = 0): "
              f"nothing takes the motion's energy out and the rod rings on, sampled every "
              f"--output-dt (a robot's damping: identify --readings LOG --param damping)",
              file=sys.stderr)
    q0 = None
    if args.from_equilibrium:
        from .forward import solve
        first = {n: float(np.interp(0.0, *e)) if isinstance(e, tuple) else e
                 for n, e in args.schedule.items()}
        # each tendon's friction as the motion starts (follow: pulled in at first)
        rest = solve(robot, first, _point_forces(args), sliding={
            n: d for n, d in (args.sliding or {}).items() if d != "follow"})
        if not rest.converged:
            print(f"tendonsense simulate: the equilibrium at t = 0 did not converge "
                  f"({rest.note}); nothing written", file=sys.stderr)
            return False
        q0 = rest.q
    with warnings.catch_warnings():  # a coarse step: said before computing
        warnings.simplefilter("ignore")
        sim = simulate(robot, args.schedule, _point_forces(args), duration=args.duration,
                       output_dt=args.output_dt, max_step=args.max_step,
                       inertia=not args.no_inertia, sliding=args.sliding, q0=q0)
    cols = sim.readings(args.noise_length, args.noise_tension, args.seed)
    rows = [["" if math.isnan(v) else v for v in row]  # a sample not converged: shape empty
            for row in np.column_stack(list(cols.values())).tolist()]
    if args.log == "-":
        out = csv.writer(sys.stdout, lineterminator="\n")
        out.writerow(list(cols))
        out.writerows(rows)
    else:
        write_csv_atomic(args.log, list(cols), rows)
    if args.plot:
        from . import plotting
        plotting.simulation(sim, args.plot, title=f"{robot.name}: simulated motion",
                            given="given: the tensions over time (top)"
                            + "".join(f", {f}" for f in _forces_text(args))
                            + (", from the equilibrium at t = 0" if args.from_equilibrium
                               else ", from the straight rod at rest")
                            + ("; drawn without the read-out noise of the log"
                               if args.noise_length or args.noise_tension else ""))
    if args.json:
        print(json.dumps({"time": sim.time.tolist(),
                          "markers": {m: p.tolist() for m, p in sim.markers.items()},
                          "displacements": {n: y.tolist() for n, y in sim.displacements.items()},
                          "friction_state": {n: v.tolist()
                                             for n, v in sim.friction_state.items()},
                          "converged": sim.ok}))
    elif args.log != "-":  # (standard output holds the log)
        tip = robot.marker_names[-1] if robot.marker_names else None
        last = sim.time[-1] - sim.time[-2] if sim.time.size > 1 else args.output_dt
        uneven = f" (the last after {last:g} s)" if abs(last - args.output_dt) > 1e-9 else ""
        print(f"simulated {sim.time[-1]:g} s, {sim.time.size} rows every {args.output_dt:g} s"
              f"{uneven}; wrote {args.log}" + (f", {args.plot}" if args.plot else ""))
        good = np.flatnonzero(sim.converged)  # (a sample not converged has no shape)
        k = good[-1] if good.size else None
        at = (None if k is None else "at the end" if k == sim.time.size - 1
              else f"at t = {sim.time[k]:g} s, the last converged sample")
        if tip and at:
            print(f"marker {tip} {at}: {_vector(sim.markers[tip][k])} m")
        for n, y in sim.displacements.items() if at else ():
            print(f"tendon {n}: length change {at} {y[k] * 1e3:+.3f} mm")
        for n, s in sim.friction_state.items() if good.size else ():
            s = s[good]
            pulled, out = np.mean(s >= 1 - inputs.EDGE), np.mean(s <= -1 + inputs.EDGE)
            if pulled < 1:
                print(f"tendon {n}: friction by the samples: pulled in {pulled:.0%}, stuck "
                      f"{1 - pulled - out:.0%}, paid out {out:.0%}")
        if not sim.ok:
            print(f"NOT CONVERGED at {int(np.sum(~sim.converged))} of {sim.time.size} samples "
                  f"(from t = {sim.time[np.argmin(sim.converged)]:g} s): their lengths and "
                  f"markers are empty in {args.log}")
    elif not sim.ok:
        print(f"tendonsense simulate: NOT CONVERGED at {int(np.sum(~sim.converged))} of "
              f"{sim.time.size} samples: their lengths and markers are empty in the log",
              file=sys.stderr)
    return sim.ok


def _sweep(args, robot) -> bool:
    """Forward statics per parameter set, here (:func:`tendonsense.tracking.solve_batch`) or
    on a Dask cluster (:func:`tendonsense.distributed.solve_batch`); RESULTS.csv written
    atomically."""
    from .readings import sweep_rows, write_csv_atomic
    from .stability import SETTLED_NOTE
    sets = args.sets_read
    forces = _point_forces(args) + sets.loads
    with _on_cluster(args) as client:  # before the bar's thread: a local cluster may fork
        prog = _Progress(args, "sweep")
        try:
            if client is None:
                from .tracking import solve_batch
                out = solve_batch(robot, sets.tensions, forces, sets.values,
                                  sliding=args.sliding, stability=not args.skip_stability,
                                  settle=args.settle)
            else:
                from .distributed import TASK_SIZE, solve_batch
                out = solve_batch(client, robot, sets.tensions, forces, sets.values,
                                  args.task_size or TASK_SIZE, prog, sliding=args.sliding,
                                  stability=not args.skip_stability, settle=args.settle)
        finally:
            prog.close()
    write_csv_atomic(args.results, *sweep_rows(robot, sets, out, _point_forces(args),
                                               args.sliding))
    n, good = len(sets.rows), int(out.converged.sum())
    shaky = None if out.unstable is None else int(out.unstable.sum())
    rested = int(sum(str(note).startswith(SETTLED_NOTE) for note in out.notes))
    if args.json:
        print(json.dumps({"sets": n, "converged": good, "unstable": shaky,
                          **({"settled": rested} if args.settle else {}),
                          "output": str(args.results)}))
    else:
        print(f"solved {n} parameter set{'' if n == 1 else 's'}: {good} converged"
              + (f", {shaky} of them at unstable equilibria (the rod would leave those "
                 f"shapes: column unstable, and their solver_note)" if shaky else "")
              + (f", {rested} settled (the state the rod comes to rest in from an unstable "
                 f"or unfound one: their solver_note)" if rested else "")
              + f"; wrote {args.results}")
    return good == n


def _error(args, message: str) -> None:
    """One line on standard error, ``tendonsense COMMAND: error: MESSAGE`` (argparse's form),
    whatever raised it."""
    said = re.match(r"tendonsense( [a-z]+)?: (.*)", message, re.S)
    prog = "tendonsense" + ((said.group(1) or "") if said else "")
    if args is not None and getattr(args, "command", None):
        prog = f"tendonsense {args.command}"
    print(f"{prog}: error: {said.group(2) if said else message}", file=sys.stderr)


RUN = {"solve": _single, "fk": _single, "view": _view, "identify": _identify,
       "experiments": _experiments, "simulate": _simulate, "sweep": _sweep}


def main(argv=None) -> int:
    with warnings.catch_warnings():  # (said before computing: :func:`_no_damping`)
        warnings.simplefilter("ignore", inputs.NoDampingWarning)
        return _main(argv)


def _main(argv) -> int:
    argv = sys.argv[1:] if argv is None else [str(a) for a in argv]
    parser = build_parser()
    hook = settings.on_first_compile
    if not argv:
        parser.print_help(sys.stderr)
        return 2
    args = None
    try:
        args = parser.parse_args(_join_negative_values(argv))
        if args.command in ("sensitivity", "resolution", "compare", "experiments"):
            _resolve_robot(args)
        robot = load_robot(args.robot)
        _check(args, robot)
        if sys.stderr.isatty() and not getattr(args, "quiet", False):
            settings.on_first_compile = partial(print, file=sys.stderr, flush=True)
        if args.command in ("sensitivity", "resolution", "compare"):
            return 0 if _analysis_run(args, robot) else _not_converged()
        if args.command == "estimate" and args.logs is not None:
            return _logs(args, robot)
        if args.command == "estimate":
            ok = (_single if args.readings is None else _log)(args, robot)
        else:
            ok = RUN[args.command](args, robot)
    except UsageError as exc:
        _error(args, str(exc))
        return 2
    except BrokenPipeError:  # the reader of standard output went away: stop quietly
        sys.stdout = open(os.devnull, "w")
        return 0
    except (RobotFileError, ValueError, OSError) as exc:  # a ViewError is an OSError
        _error(args, str(exc))
        return 1
    finally:
        settings.on_first_compile = hook
    return 0 if ok else _not_converged()


def _not_converged() -> int:
    print("tendonsense: not every solve converged (marked converged = false)", file=sys.stderr)
    return 3


if __name__ == "__main__":
    sys.exit(main())
