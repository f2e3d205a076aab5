"""Command line: ``balance-opt SUBCOMMAND ...``.

Exit codes: 0 success, 2 bad input, 1 solver failure.
"""

from __future__ import annotations

import argparse
import logging
import sys

EXIT_OK, EXIT_SOLVER, EXIT_INPUT = 0, 1, 2


def _cmd_inspect(args) -> int:
    from .inspection import robot_summary
    from .robots import paper_robot

    robot = paper_robot()
    print(robot_summary(robot))
    return EXIT_OK


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="balance-opt", description=__doc__.splitlines()[0])
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    parser.add_argument("-q", "--quiet", action="store_true", help="print errors only")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("inspect", help="print a robot summary and its coupling measures")
    p.set_defaults(run=_cmd_inspect)
    return parser


def main(argv=None) -> int:
    from .errors import InputError, SolverError

    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.WARNING if args.quiet else logging.INFO,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        return args.run(args)
    except InputError as exc:
        print(f"balance-opt: error: {exc}", file=sys.stderr)
        return EXIT_INPUT
    except SolverError as exc:
        print(f"balance-opt: solver failure: {exc}", file=sys.stderr)
        return EXIT_SOLVER


if __name__ == "__main__":
    sys.exit(main())
