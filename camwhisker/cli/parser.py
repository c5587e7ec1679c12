"""The ``camwhisker`` parser and ``main``: every command, one error style."""

from __future__ import annotations

import argparse
import sys

from camwhisker import __version__
from camwhisker.cli import (
    batch,
    belief,
    bench,
    calibrate_sensor,
    contact,
    learn,
    live,
    overlay,
    percept,
    springs,
    synth,
    texture,
    validate,
)
from camwhisker.cli.common import EXIT_CODES, INPUT_ERRORS, HelpFormatter

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
    texture.add_simulate_texture,
    contact.add_calibrate,
    calibrate_sensor.add_calibrate_sensor,
    contact.add_contact,
    belief.add_belief,
    springs.add_calibrate_springs,
    percept.add_percept,
    texture.add_texture,
    validate.add_validate,
    learn.add_learn,
    learn.add_predict,
    bench.add_contact_bench,
    percept.add_percept_bench,
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
        description="From webcam video of a camera-based robotic whisker to the plate's pose "
        "(dz, phi, theta) per frame, and from there to contact distance and shape. Start "
        "with `camwhisker batch VIDEO --sensor SENSOR.toml --out OUT.csv`; `camwhisker "
        "COMMAND --help` describes each command.",
        epilog="exit status, the same for every command: "
        + "; ".join(f"{code} {text}" for code, text in EXIT_CODES.items()),
    )
    parser.add_argument("--version", action="version", version=f"camwhisker {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for add in _COMMANDS:
        add(sub)
    for command in sub.choices.values():
        command.formatter_class = HelpFormatter
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
