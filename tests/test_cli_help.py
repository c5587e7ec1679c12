"""`camwhisker --help` and every command's (issue #21 item 11): each option explained,
its default shown, the exit status documented once for all commands."""

import argparse

from camwhisker.cli import build_parser
from camwhisker.cli.common import EXIT_CODES
from camwhisker.cli.dev import BENCH_SCRIPTS


def _commands():
    """The parser and every command it parses itself: the top level's and dev's (the
    benchmark scripts under dev parse their own options)."""
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    dev = next(a for a in sub.choices["dev"]._actions
               if isinstance(a, argparse._SubParsersAction))  # fmt: skip
    commands = {n: p for n, p in sub.choices.items() if n != "dev"}
    commands.update({n: p for n, p in dev.choices.items() if n not in BENCH_SCRIPTS})
    return parser, commands


def test_every_option_has_help_and_its_default_shown():
    _, commands = _commands()
    missing, no_default = [], []
    for name, p in commands.items():
        text = " ".join(p.format_help().split())
        for a in p._actions:
            if isinstance(a, argparse._HelpAction):
                continue
            flag = "/".join(a.option_strings) or a.dest
            if not (a.help or "").strip():
                missing.append(f"{name} {flag}")
            shown = any(a.default is v for v in (None, False)) or "default" in (a.help or "")
            if not shown and f"(default: {a.default})" not in text:
                no_default.append(f"{name} {flag}")
    assert len(commands) == 32  # with calibrate-springs, percept, percept-bench, belief,
    # simulate-texture, texture, learn, predict, experiment, map, simulate-space,
    # make-space-experiment, simulate-taps, simulate-whisk
    assert missing == [] and no_default == []


def test_repeated_run_options_say_so():
    _, commands = _commands()
    for name in ("calibrate", "validate"):
        helps = {a.dest: a.help for a in commands[name]._actions}
        assert "repeat once per" in helps["signals"] and "repeat once per" in helps["stage"], name


def test_top_level_help_is_for_a_user_and_lists_the_exit_status():
    parser, _ = _commands()
    text = " ".join(parser.format_help().split())
    assert "wiring only" not in text and "camwhisker batch VIDEO" in text
    for code in (0, 1, 2, 130):
        assert f"{code} {EXIT_CODES[code]}" in text


def test_readme_documents_the_same_exit_status():
    from pathlib import Path

    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    for code, text in EXIT_CODES.items():
        assert f"| {code} | {text} |" in readme
