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


def test_a_user_command_builds_its_own_parser_alone_and_parses_the_same():
    # main builds only the command it runs (the others' modules cost ~50 ms of start-up);
    # each name must be the one its add function registers, and parse as the whole parser.
    for name in USER_ORDER[:-1]:
        assert _commands(build_parser(name)) == [name]
    argv = ["batch", "v.mp4", "--sensor", "s.toml", "--out", "o.csv", "--rest-frame", "3"]
    alone, whole = build_parser("batch").parse_args(argv), build_parser().parse_args(argv)
    assert vars(alone) == vars(whole)
    render = build_parser("dev").parse_args(["dev", "render", "nominal", "--out", "x.avi"])
    assert render.frames == 60  # dev builds every dev command: render's default is there


def test_the_batch_command_leaves_the_other_commands_modules_unimported():
    # A fresh interpreter: this one has them already.
    import subprocess
    import sys

    code = ("import sys; from camwhisker.cli import build_parser; build_parser('batch'); "
            "print([m for m in ('camwhisker.percept.contact_map', 'camwhisker.learn.train', "
            "'camwhisker.sim.mechanics', 'camwhisker.sim.render.scenarios', "
            "'camwhisker.cli.live', 'camwhisker.cli.bench', 'camwhisker.cli.synth') "
            "if m in sys.modules])")  # fmt: skip
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout  # fmt: skip
    assert out.strip() == "[]"
