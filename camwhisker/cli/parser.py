"""The ``camwhisker`` parser and ``main``: every command, one error style."""

from __future__ import annotations

import argparse
import importlib
import sys

from camwhisker import __version__
from camwhisker.cli.common import EXIT_CODES, INPUT_ERRORS, HelpFormatter, warnings_above_bars

__all__ = ["build_parser", "main"]

# The commands a researcher runs, in the order of the work (`camwhisker --help`), by name:
# the function of camwhisker.cli.MODULE that adds it, as "MODULE.FUNCTION" (a module is
# imported only where its command is built).
_COMMANDS = {
    "batch": "batch.add_batch",
    "overlay": "overlay.add_overlay",
    "live": "live.add_live",
    "replay": "live.add_replay",
    "list-cameras": "live.add_list_cameras",
    "calibrate-sensor": "calibrate_sensor.add_calibrate_sensor",
    "calibrate": "contact.add_calibrate",
    "calibrate-springs": "springs.add_calibrate_springs",
    "validate": "validate.add_validate",
    "contact": "contact.add_contact",
    "belief": "belief.add_belief",
    "experiment": "experiment.add_experiment",
    "percept": "percept.add_percept",
    "map": "map.add_map",
    "texture": "texture.add_texture",
    "learn": "learn.add_learn",
    "predict": "learn.add_predict",
}

# `camwhisker dev ...`: the simulators and the benchmarks against their truth.
_DEV_COMMANDS = [
    "synth.add_render",
    "synth.add_bound",
    "synth.add_samples",
    "synth.add_describe",
    "synth.add_experiment",
    "synth.add_space_experiment",
    "contact.add_simulate_stage",
    "contact.add_simulate_space",
    "dev.add_simulate_taps",
    "dev.add_simulate_whisk",
    "texture.add_simulate_texture",
    "bench.add_chain",
    "bench.add_bench",
    "bench.add_contact_bench",
    "percept.add_percept_bench",
    "dev.add_bench_scripts",
]


def _add(sub, where: str) -> None:
    """Add the command that camwhisker.cli's ``where`` ("MODULE.FUNCTION") adds."""
    module, function = where.split(".")
    getattr(importlib.import_module(f"camwhisker.cli.{module}"), function)(sub)


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser of every command; with ``command`` one of the user's commands (not
    ``dev``), of that command alone: the others' modules, and the modules their
    defaults and choices come from, cost every run's start-up ~50 ms."""
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
    if command in _COMMANDS:
        _add(sub, _COMMANDS[command])
        sub.choices[command].formatter_class = HelpFormatter
        return parser
    for where in _COMMANDS.values():
        _add(sub, where)
    dev_parser = sub.add_parser(
        "dev", help="simulators and benchmarks: `camwhisker dev --help` lists them",
        description="Simulators with known truth, and the benchmarks that check the "
        "package against it. None of them is needed to process a real sensor's recordings.")
    dev_sub = dev_parser.add_subparsers(dest="dev_command", required=True, metavar="COMMAND")
    for where in _DEV_COMMANDS:
        _add(dev_sub, where)
    for each in [*sub.choices.values(), *dev_sub.choices.values()]:
        each.formatter_class = HelpFormatter
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run one command; bad input prints ``camwhisker CMD: error: ...`` and returns 2."""
    words = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser(words[0] if words else None)
    args, rest = parser.parse_known_args(words)
    args.typed = words  # the exact command, for provenance (common.command_line)
    if getattr(args, "passes_options", False):  # a benchmark script parses its own (cli.dev)
        args.argv = rest
    elif rest:
        parser.error(f"unrecognized arguments: {' '.join(rest)}")
    if args.command == "dev":
        args.command = f"dev {args.dev_command}"
    try:
        with warnings_above_bars(args.command):
            return int(args.func(args) or 0)
    except INPUT_ERRORS as exc:
        print(f"camwhisker {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"camwhisker {args.command}: interrupted", file=sys.stderr)
        return 130
