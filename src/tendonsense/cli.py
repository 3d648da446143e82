"""The ``tendonsense`` command line (SPEC §4), a thin layer over the Python API.

Exit status: 0 success, 1 bad input (one line on stderr, nothing on stdout), 2 bad usage,
3 a solve that did not converge (its result is still printed, marked ``converged: false``).
"""

from __future__ import annotations

import argparse
import json
import sys

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
    return parser


def _point_forces(args):
    return [(pf[0], pf[1:]) for pf in args.point_force]


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


def main(argv=None) -> int:
    try:
        args = build_parser().parse_args(argv)
        robot = load_robot(args.robot)
        from . import forward
        if args.command == "solve":
            result = forward.solve(robot, dict(args.tension), _point_forces(args))
            _print_result(result, args.json, "forward statics")
        elif args.command == "fk":
            result = forward.forward_kinematics(robot, dict(args.displacement),
                                                dict(args.tension), _point_forces(args))
            _print_result(result, args.json, "forward kinematics")
    except UsageError as exc:
        print(exc, file=sys.stderr)
        return 2
    except (RobotFileError, ValueError) as exc:
        print(f"tendonsense: error: {exc}", file=sys.stderr)
        return 1
    if not result.converged:
        print("tendonsense: the solve did not converge", file=sys.stderr)
        return 3
    return 0


if __name__ == "__main__":
    sys.exit(main())
