"""The ``camwhisker`` command line: wiring only, every computation lives in the library."""

from __future__ import annotations

import argparse
import sys

from camwhisker import __version__
from camwhisker.sensor import SensorFileError


class CommandError(RuntimeError):
    """A user-facing failure: printed without a traceback, exit status 2."""


def _sensor_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("--sensor", metavar="FILE", help="sensor file (TOML); default: Table I values")


# --- synthetic data ------------------------------------------------------------------------


# --- vision front end ------------------------------------------------------------------------


# --- contact back end -------------------------------------------------------------------------


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="camwhisker", description=__doc__)
    parser.add_argument("--version", action="version", version=f"camwhisker {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    for add in _COMMANDS:
        add(sub)
    return parser


_COMMANDS: list = []


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (CommandError, SensorFileError, FileNotFoundError) as exc:
        print(f"camwhisker {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"camwhisker {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
