"""What every command shares: its error, the errors it reports as bad input, shared options."""

from __future__ import annotations

import argparse
import contextlib
import logging
import shlex
import sys

__all__ = ["CommandError", "INPUT_ERRORS", "EXIT_CODES", "HelpFormatter", "sensor_arg",
           "features_arg", "feature_hints", "springs_arg", "springs_of", "mode_arg", "runs_arg",
           "paired_runs", "command_line"]


class CommandError(RuntimeError):
    """A user-facing failure: printed without a traceback, exit status 2 (EXIT_CODES)."""


# The library reports bad input (a file, key, row or frame it cannot use) as a
# ValueError subclass naming it, and a missing or unreadable file as an OSError.
INPUT_ERRORS = (CommandError, ValueError, OSError)

#: Every command's exit status (README, "Exit status"; `camwhisker --help`).
EXIT_CODES = {
    0: "done, nothing went wrong",
    1: "finished, but something failed: named on stderr (a video that could not be "
       "processed, frames lost, no row ok); what was done is written",
    2: "usage or bad input: the file, key, row or frame named on stderr; nothing written",
    130: "interrupted (Ctrl-C; batch also by SIGTERM)",
}


class HelpFormatter(argparse.HelpFormatter):
    """Shows each option's default after its help, where it has one and the help does
    not already say it (``ArgumentDefaultsHelpFormatter`` also prints 'default: None')."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if "default" in text or any(action.default is v for v in (None, False, argparse.SUPPRESS)):
            return text
        return text + " (default: %(default)s)"


SENSOR_HELP = "sensor file (TOML); default: Table I values"


def sensor_arg(p: argparse.ArgumentParser, help_text: str = SENSOR_HELP) -> None:
    """The ``--sensor FILE`` option, read with :func:`camwhisker.sensor.file.load_sensor`."""
    p.add_argument("--sensor", metavar="FILE", help=help_text)


def features_arg(p: argparse.ArgumentParser) -> None:
    """``--features FILE``: rough positions of the features in the rest frame."""
    p.add_argument("--features", metavar="FILE",
                   help="rough pixel positions of the features in the rest frame (TOML, "
                   "docs/sensor.md section 5.2), where detection does not find them")  # fmt: skip


def feature_hints(args: argparse.Namespace, sensor):
    """The ``--features`` file read for frames of ``sensor``'s size, or None."""
    if args.features is None:
        return None
    from camwhisker.vision.hints import load_feature_hints

    return load_feature_hints(args.features, (sensor.camera.width_px, sensor.camera.height_px))


def springs_arg(p: argparse.ArgumentParser) -> None:
    """``--springs FILE``: the suspension's stiffness; adds the forces' columns."""
    p.add_argument("--springs", metavar="FILE",
                   help="springs file (TOML, docs/sensor.md section 7.2: the spring model's "
                   "design and/or fitted stiffnesses, as calibrate-springs writes it); adds "
                   "fz_mN and mb_Nmm to the table")  # fmt: skip


def springs_of(args: argparse.Namespace):
    """The ``--springs`` file's stiffness, or None."""
    if args.springs is None:
        return None
    from camwhisker.calibration.springfile import read_springs

    return read_springs(args.springs)


def mode_arg(p: argparse.ArgumentParser) -> None:
    """``--mode model|paper``: which pose the front end reports, the same in every command."""
    p.add_argument(
        "--mode",
        choices=("model", "paper"),
        default="model",
        help="exact camera model (default) or the paper's eqs. 2-7",
    )


def runs_arg(p: argparse.ArgumentParser, per_run: str) -> None:
    """``--signals S.csv --stage L.csv``, once per run, in the same order."""
    p.add_argument("--signals", action="append", required=True, metavar="S.csv",
                   help=f"signal table of one {per_run}; repeat once per {per_run}")
    p.add_argument("--stage", action="append", required=True, metavar="L.csv",
                   help=f"stage log of one {per_run}; repeat once per {per_run}, in the "
                   "order of --signals")


def paired_runs(args: argparse.Namespace, *optional: str) -> list[tuple]:
    """(signals, stage, *optional values) per run; each ``optional`` option (a dest,
    such as ``offset_s``) is given for every run or for none (None)."""
    n = len(args.signals)
    if len(args.stage) != n:
        raise CommandError(f"give one --stage per --signals ({n} signals, "
                           f"{len(args.stage)} stage logs)")
    columns = [args.signals, args.stage]
    for dest in optional:
        values = getattr(args, dest) or [None] * n
        if len(values) != n:
            flag = "--" + dest.replace("_", "-")
            raise CommandError(f"give {flag} for every run or for none ({n} runs, "
                               f"{len(values)} given)")
        columns.append(values)
    return list(zip(*columns, strict=True))


def command_line(args: argparse.Namespace) -> str:
    """The command as typed (main() keeps its words), quoted for a shell; for a namespace
    built elsewhere, the command as parsed."""
    if getattr(args, "typed", None) is not None:
        return shlex.join(["camwhisker", *args.typed])
    parts = ["camwhisker", *args.command.split()]  # "dev NAME" is two words
    for key, value in vars(args).items():
        if key in ("command", "dev_command", "func") or value is None or value is False:
            continue
        flag = "--" + key.replace("_", "-")
        if value is True:
            parts.append(flag)
            continue
        for v in value if isinstance(value, list) else [value]:
            parts += [flag, str(v)]
    return shlex.join(parts)


class _AboveBars(logging.Handler):
    """Each record as ``camwhisker CMD: warning: ...`` on stderr, above any progress bar."""

    def __init__(self, command: str):
        super().__init__(logging.WARNING)
        self.command = command

    def emit(self, record: logging.LogRecord) -> None:
        from tqdm import tqdm

        level = record.levelname.lower()
        tqdm.write(f"camwhisker {self.command}: {level}: {record.getMessage()}", file=sys.stderr)


@contextlib.contextmanager
def warnings_above_bars(command: str):
    """The library's warnings (logging) printed above any progress bar (``tqdm.write``),
    not into its line, while the command runs; left alone where logging is set up already."""
    root = logging.getLogger()
    handler = None if root.handlers else _AboveBars(command)
    if handler is not None:
        root.addHandler(handler)
    try:
        yield
    finally:
        if handler is not None:
            root.removeHandler(handler)

