"""The command line in the user's order: their commands at the top, simulators and
benchmarks under ``camwhisker dev``."""

from __future__ import annotations

import pytest

from camwhisker.cli import build_parser, main
from camwhisker.cli.dev import BENCH_SCRIPTS

USER_ORDER = ["batch", "overlay", "live", "replay", "list-cameras", "calibrate-sensor",
              "calibrate", "calibrate-springs", "validate", "contact", "belief", "experiment",
              "percept", "map", "texture", "learn", "predict", "dev"]  # fmt: skip
DEV = ["render", "bound", "make-samples", "describe", "make-experiment",
       "make-space-experiment", "simulate-stage",
       "simulate-space", "simulate-taps", "simulate-whisk", "simulate-texture", "chain",
       "bench", "contact-bench", "percept-bench"]  # fmt: skip


def _commands(parser) -> list[str]:
    sub = next(a for a in parser._actions if a.dest in ("command", "dev_command"))
    return list(sub.choices)


def test_top_level_lists_the_users_commands_in_workflow_order():
    top = _commands(build_parser())
    assert top == USER_ORDER
    assert not set(DEV) & set(top)


def test_dev_holds_every_simulator_and_benchmark():
    dev = next(a for a in build_parser()._actions if a.dest == "command").choices["dev"]
    names = _commands(dev)
    assert names[: len(DEV)] == DEV
    assert names[len(DEV):] == list(BENCH_SCRIPTS)
    assert len(BENCH_SCRIPTS) == 17  # every `python -m camwhisker.bench.X` script with a main


def test_a_benchmark_script_parses_its_own_options(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["dev", "texture-bench", "--no-such-option"])
    assert exc.value.code == 2  # argparse's usage error, from the script's own parser
    assert "camwhisker dev texture-bench" in capsys.readouterr().err


def test_an_unknown_option_of_a_user_command_is_still_an_error(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["batch", "sample_frames/nominal.mp4", "--no-such-option"])
    assert exc.value.code == 2
    assert "unrecognized arguments: --no-such-option" in capsys.readouterr().err


def test_dev_errors_name_the_dev_command(tmp_path, capsys):
    assert main(["dev", "bench", "--out", str(tmp_path / "b.md"), "--configs", "nope"]) == 2
    assert capsys.readouterr().err.startswith("camwhisker dev bench: error:")
