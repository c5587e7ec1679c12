"""The ``camwhisker`` parser and ``main``: every command, one error style."""

from __future__ import annotations

import argparse
import sys

from camwhisker import __version__
from camwhisker.cli import batch, bench, calibrate_sensor, contact, live, overlay, synth, validate
from camwhisker.cli.common import INPUT_ERRORS

__all__ = ["build_parser", "main"]

# In the order `camwhisker --help` lists them.
_COMMANDS = [
    synth.add_render,
    synth.add_bound,
    synth.add_samples,
    synth.add_describe,
    synth.add_experiment,
    bench.add_chain,
    contact.add_simulate_stage,
    contact.add_calibrate,
    calibrate_sensor.add_calibrate_sensor,
    contact.add_contact,
    validate.add_validate,
    bench.add_contact_bench,
    batch.add_batch,
    overlay.add_overlay,
    live.add_list_cameras,
    live.add_live,
    live.add_replay,
    bench.add_bench,
]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="camwhisker",
        description="The camwhisker command line: wiring only, every computation lives in "
        "the library.",
    )
    parser.add_argument("--version", action="version", version=f"camwhisker {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    for add in _COMMANDS:
        add(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run one command; bad input prints ``camwhisker CMD: error: ...`` and returns 2."""
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except INPUT_ERRORS as exc:
        print(f"camwhisker {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"camwhisker {args.command}: interrupted", file=sys.stderr)
        return 130
