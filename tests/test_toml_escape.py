"""TOML written by the package reads back whatever text it holds: a path with a tab and a
newline through `calibrate` and `contact`, and any string through toml_value / toml_comment."""

from __future__ import annotations

import tomllib
from pathlib import Path

from hypothesis import given, settings
from hypothesis import strategies as st

from camwhisker.cli import main
from camwhisker.files.tomlfile import toml_comment, toml_value
from camwhisker.sensor.file import dump_sensor, load_sensor

SAMPLES = Path(__file__).resolve().parents[1] / "sample_frames"
#: Control characters, quotes, backslashes, newlines and tabs are drawn far more often
#: than in uniform text, so each example holds several.
NASTY = st.sampled_from(["\n", "\t", "\r", "\x00", "\x1f", "\x7f", "\b", "\f", '"', "\\",
                         "'", "#", "=", "[", "\u2028", "\U0001f600"])  # fmt: skip
TEXT = st.lists(st.one_of(NASTY, st.text(max_size=5)), max_size=20).map("".join)


@settings(max_examples=500, deadline=None)
@given(TEXT, st.text())
def test_any_string_round_trips_as_a_value_and_a_comment(mixed, plain):
    for text in (mixed, plain):
        doc = f"{toml_comment(text)}\nk = {toml_value(text)}\nl = {toml_value([text, 1.5])}\n"
        # Exact equality: the writer escapes, it never drops or changes a character.
        assert tomllib.loads(doc) == {"k": text, "l": [text, 1.5]}
        assert "\n" not in toml_comment(text)  # a comment stays on its one line


def test_a_lone_surrogate_becomes_the_replacement_character():
    name = b"run-\xff.csv".decode("utf-8", "surrogateescape")  # an undecodable file name
    doc = f"k = {toml_value(name)}\n{toml_comment(name)}\n"
    assert tomllib.loads(doc.encode("utf-8").decode("utf-8")) == {"k": "run-\ufffd.csv"}


def test_a_sensor_from_a_folder_named_with_a_tab_and_a_newline_reads_back(tmp_path):
    folder = tmp_path / "bench\ttwo\nlines"
    folder.mkdir()
    src = folder / "s.toml"
    src.write_bytes((SAMPLES / "nominal.sensor.toml").read_bytes())
    sensor = load_sensor(src)
    again = folder / "again.toml"
    again.write_text(dump_sensor(sensor))
    # Every value the same (the comment names the folder, escaped, on one line).
    assert load_sensor(again).camera == sensor.camera and load_sensor(again).plate == sensor.plate
    assert dump_sensor(sensor).splitlines()[0].endswith("two\\nlines/s.toml)")


def test_calibrate_under_a_folder_named_with_a_tab_and_a_newline_reads_back(tmp_path, capsys):
    root = tmp_path / "stage\truns\nday 2"
    assert main(["dev", "simulate-stage", "--kind", "eq8", "--out", f"{root}/cal",
                 "--seed", "21"]) == 0
    calib = root / "calib.toml"
    args = ["calibrate", "--out", str(calib)]
    for r in ("r22.5", "r42.5", "r60", "r90"):
        args += ["--signals", f"{root}/cal/{r}_signals.csv", "--stage", f"{root}/cal/{r}_stage.csv"]
    assert main(args) == 0
    doc = tomllib.loads(calib.read_text(encoding="utf-8"))
    # The command and each run's files come back character for character.
    assert "stage\truns\nday 2" in doc["provenance"]["command"]
    assert [run["signals"] for run in doc["provenance"]["runs"]] == [
        f"{root}/cal/{r}_signals.csv" for r in ("r22.5", "r42.5", "r60", "r90")]
    # And `contact` takes the file (before, it refused it: "not valid TOML").
    out = root / "c.csv"
    assert main(["contact", "--signals", f"{root}/cal/r42.5_signals.csv", "--stage",
                 f"{root}/cal/r42.5_stage.csv", "--calib", str(calib), "--out", str(out)]) == 0
    assert "not valid TOML" not in capsys.readouterr().err
    assert out.read_text().count("\n") > 100  # a row per signal row (the runs have > 1000)
