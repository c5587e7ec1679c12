"""Every command over a corpus of bad input (issue #21): a clear error, nothing lost.

The corpus is made here, small: videos that are empty, truncated, corrupt in the
middle, of the wrong size, not video at all (text, audio only); an image folder with
an unreadable image; sensor files, stage logs, signal tables, a calibration file and
recorded sessions each broken. Each command that takes such input runs on it through
``main(argv)`` in this process, as a fresh process runs it (stdout, stderr and the library's
warnings on stderr captured, an escaping exception printed as its traceback); a few run as
a user runs them (``python -m camwhisker.cli``), the same checks on a true process. For each:

- bad input (nothing usable): exit 2, one line naming the file and the key, row or
  frame, and no output file, temporary or not;
- input partly usable: exit 1, every frame the decoder can read processed (counted
  here by PyAV, independently of the package's OpenCV reader), the outputs written
  with the problem named in their sidecar;
- never a traceback, never a numpy repr (``np.float64(...)``).
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import logging
import os
import shutil
import subprocess
import sys
import traceback
import wave
from pathlib import Path

import cv2
import numpy as np
import pytest

from camwhisker.cli import main
from camwhisker.vision.stream import DAMAGED_REASON, GAP_REASON

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "sample_frames"
MJPG = SAMPLES / "nominal_mjpg.avi"  # 12 frames, 1280x720
H264 = SAMPLES / "nominal.mp4"  # 90 frames, 1280x720, one key frame
SENSOR = SAMPLES / "nominal.sensor.toml"


def _decodable_frames(path: Path) -> int:
    """Frames FFmpeg (through PyAV) decodes from ``path``, going on past packets it
    cannot decode: what 'every readable frame' means here."""
    import av

    n = 0
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        for packet in container.demux(stream):
            try:
                n += len(packet.decode())
            except av.error.FFmpegError:
                continue
    return n


def _make_videos(d: Path) -> dict:
    (d / "empty.mp4").write_bytes(b"")
    (d / "text.mp4").write_text("not a video\n")
    with wave.open(str(d / "audio.wav"), "wb") as w:  # a container without a video stream
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(8000)
        w.writeframes(b"\0\0" * 800)
    data = MJPG.read_bytes()
    (d / "truncated.avi").write_bytes(data[: int(0.6 * len(data))])
    data = H264.read_bytes()
    k = int(0.4 * len(data))
    noise = np.random.default_rng(0).integers(0, 256, 50_000, dtype=np.uint8).tobytes()
    (d / "garbage.mp4").write_bytes(data[:k] + noise + data[k + len(noise):])
    writer = cv2.VideoWriter(str(d / "small.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 30.0,
                             (160, 120))
    for i in range(4):
        writer.write(np.full((120, 160, 3), 60 * i, np.uint8))
    writer.release()
    frames = d / "frames"
    frames.mkdir()
    cap = cv2.VideoCapture(str(MJPG))
    i = 0
    while (image := cap.read()[1]) is not None:
        cv2.imwrite(str(frames / f"{i:02d}.png"), image)
        i += 1
    (frames / "05.png").write_bytes(b"\x89PNG but then nothing")
    return {"frames_in_folder": i}


def _make_tables(d: Path) -> None:
    """simulate-stage runs and their calibration, then broken copies of each file."""
    assert main(["dev", "simulate-stage", "--kind", "eq8", "--out", str(d / "cal"),
                 "--seed", "5"]) == 0
    assert main(["dev", "simulate-stage", "--kind", "compliant", "--out", str(d / "run"),
                 "--seed", "6"]) == 0
    args = ["calibrate", "--out", str(d / "calib.toml")]
    for r in ("r22.5", "r60", "r90"):
        args += ["--signals", str(d / "cal" / f"{r}_signals.csv"),
                 "--stage", str(d / "cal" / f"{r}_stage.csv")]
    assert main(args) == 0
    for name in ("empty.csv", "empty.toml", "empty.sensor.toml"):
        (d / name).write_bytes(b"")
    (d / "stage_no_x.csv").write_text("t_s,position\n0,0\n0.1,0\n")
    (d / "stage_text.csv").write_text("t_s,x_mm\n0,0\n0.1,abc\n")
    (d / "stage_dup.csv").write_text("t_s,x_mm\n0,0\n0.1,0\n0.1,0.5\n")
    with open(d / "run" / "c35_signals.csv") as fh:
        rows = list(csv.DictReader(fh))
    header = list(rows[0])

    def table(name, rows_out, cols=header):
        with open(d / name, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=cols, extrasaction="ignore")
            w.writeheader()
            w.writerows(rows_out)

    table("signals_no_phi.csv", rows, [c for c in header if c != "phi_deg"])
    table("signals_text.csv", rows[:5] + [{**rows[5], "dz_mm": "0.1 mm"}] + rows[6:])
    table("signals_back.csv", rows[:9] + [{**rows[9], "t_s": "0"}] + rows[10:])
    table("signals_none_ok.csv", [{**r, "ok": "0", "phi_deg": "", "dz_mm": ""} for r in rows])
    (d / "sensor_toml.toml").write_text("[camera\nfx_px = 1\n")
    (d / "sensor_key.toml").write_text("[camera]\nfocal_px = 900.0\n")
    (d / "sensor_type.toml").write_text('[camera]\nfx_px = "nine hundred"\n')
    (d / "forces_text.csv").write_text("t_s,fz_mN\n0,0\n0.01,1.5 mN\n")
    (d / "springs_key.toml").write_text("[stiffness]\nkz = 0.05\n")
    # Recorded sessions: one without its timestamps, one listing more frames than it has.
    shutil.copy(MJPG, d / "session_alone.avi")
    shutil.copy(MJPG, d / "session_long.avi")
    lines = ["frame,video_frame,seq,t_s,event"] + [f"{k},{k},{k},{k / 30:.6f}," for k in range(20)]
    (d / "session_long.timestamps.csv").write_text("\n".join(lines) + "\n")


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    d = tmp_path_factory.mktemp("bad_input")
    info = _make_videos(d)
    _make_tables(d)
    info["decodable"] = {name: _decodable_frames(d / name)
                         for name in ("truncated.avi", "garbage.mp4")}
    return d, info


def _cases(d: Path) -> dict:
    """name -> (argv, the exit status expected, what stderr must hold)."""
    s = ["--sensor", str(SENSOR)]
    out = d / "out"
    video_in = {"empty.mp4": "not a video", "text.mp4": "not a video",
                "audio.wav": "not a video",
                "small.avi": f"frames are 160x120 px but {SENSOR} is for 1280x720 px"}
    cases = {}
    for name, needle in video_in.items():
        v = str(d / name)
        stem = Path(name).stem
        cases[f"batch {name}"] = (["batch", v, "--out", f"{out}/{stem}.csv", "--quiet", *s],
                                  2, f"{v}: {needle}")
        cases[f"overlay {name}"] = (["overlay", v, "--out", f"{out}/{stem}.mp4", "--quiet",
                                     *s], 2, f"{v}: {needle}")
        cases[f"live {name}"] = (["live", v, "--out", f"{out}/{stem}.live.csv", "--no-keys",
                                  *s], 2, f"{v}: {needle}")
        cases[f"calibrate-sensor {name}"] = (["calibrate-sensor", v, "--square-side-mm", "5",
                                              "--out", f"{out}/{stem}.toml", "--quiet", *s],
                                             2, f"{v}: {needle}")
        if name != "small.avi":  # describe needs no sensor: a small video is a video
            cases[f"describe {name}"] = (["dev", "describe", v], 2, f"{v}: {needle}")
    for name in ("truncated.avi", "garbage.mp4"):
        v = str(d / name)
        stem = Path(name).stem
        cases[f"batch {name}"] = (["batch", v, "--out", f"{out}/{stem}.csv", "--quiet", *s],
                                  1, f"problem: {v}: ")
        cases[f"describe {name}"] = (["dev", "describe", v], 1, f"warning: {v}: ")
    cases["live truncated.avi"] = (["live", str(d / "truncated.avi"), "--out",
                                    f"{out}/truncated.live.csv", "--no-keys", "--keep", "every",
                                    *s],
                                   1, f"problem: {d / 'truncated.avi'}: video ended after")
    cases["overlay truncated.avi"] = (["overlay", str(d / "truncated.avi"), "--out",
                                       f"{out}/truncated.mp4", "--quiet", *s],
                                      1, f"problem: {d / 'truncated.avi'}: video ended after")
    cases["batch frames/"] = (["batch", str(d / "frames"), "--out", f"{out}/frames.csv",
                               "--quiet", *s], 1, "05.png (frame 5: cannot read image)")
    # Broken sensor files.
    good = str(MJPG)
    for name, needle in (("empty.sensor.toml", "no table at all"),
                         ("sensor_toml.toml", "not valid TOML"),
                         ("sensor_key.toml", "[camera] focal_px: unknown key"),
                         ("sensor_type.toml", "[camera] fx_px: expected a number"),
                         ("missing.toml", "cannot read sensor file")):
        cases[f"batch --sensor {name}"] = (["batch", good, "--sensor", str(d / name), "--out",
                                            f"{out}/sensor.csv", "--quiet"], 2,
                                           f"{d / name}: {needle}")
    # Broken stage logs, signal tables and calibration files.
    sig, stage, calib = d / "run" / "c35_signals.csv", d / "run" / "c35_stage.csv", d / "calib.toml"
    for name, needle in (("empty.csv", "empty file"),
                         ("stage_no_x.csv", "row 1: missing column x_mm (header: t_s, position)"),
                         ("stage_text.csv", "row 3, column x_mm: not a number: 'abc'"),
                         ("stage_dup.csv", "row 4: duplicate time: t_s = 0.1 after 0.1")):
        cases[f"contact --stage {name}"] = (["contact", "--signals", str(sig), "--stage",
                                             str(d / name), "--calib", str(calib), "--out",
                                             f"{out}/contact.csv"], 2, f"{d / name}: {needle}")
        cases[f"calibrate --stage {name}"] = (["calibrate", "--signals", str(sig), "--stage",
                                               str(d / name), "--out", f"{out}/calib.toml"],
                                              2, f"{d / name}: {needle}")
    for name, needle in (("empty.csv", "empty file"),
                         ("signals_no_phi.csv", "row 1: missing column phi_deg"),
                         ("signals_text.csv", "row 7, column dz_mm: not a number: '0.1 mm'"),
                         ("signals_back.csv", "row 11, column t_s: not increasing"),
                         ("signals_none_ok.csv", "no row is ok (ok = 0 in all")):
        cases[f"contact --signals {name}"] = (["contact", "--signals", str(d / name), "--stage",
                                               str(stage), "--calib", str(calib), "--out",
                                               f"{out}/contact.csv"], 2, f"{d / name}: {needle}")
    cases["contact --calib empty.toml"] = (["contact", "--signals", str(sig), "--stage",
                                            str(stage), "--calib", str(d / "empty.toml"),
                                            "--out", f"{out}/contact.csv"],
                                           2, f"{d / 'empty.toml'}: missing key 'whisker'")
    # A broken force log and springs file.
    forces = d / "forces_text.csv"
    cases["calibrate-springs --forces forces_text.csv"] = (
        ["calibrate-springs", "--signals", str(sig), "--forces", str(forces), "--out",
         f"{out}/springs.toml"], 2, f"{forces}: row 3, column fz_mN: not a number: '1.5 mN'")
    springs = d / "springs_key.toml"
    cases["batch --springs springs_key.toml"] = (
        ["batch", good, "--springs", str(springs), "--out", f"{out}/springs.csv", "--quiet"],
        2, f"{springs}: [stiffness] kz: unknown key")
    cases["contact --springs springs_key.toml"] = (
        ["contact", "--signals", str(sig), "--stage", str(stage), "--calib", str(calib),
         "--springs", str(springs), "--out", f"{out}/contact_springs.csv"],
        2, f"{springs}: [stiffness] kz: unknown key")
    cases["replay session_alone.avi"] = (["replay", str(d / "session_alone.avi"), "--out",
                                          f"{out}/replay.csv", *s], 2,
                                         "session_alone.avi: not a recorded session: no "
                                         "session_alone.timestamps.csv beside it")
    cases["replay session_long.avi"] = (["replay", str(d / "session_long.avi"), "--out",
                                         f"{out}/replay.csv", *s], 2,
                                        "session_long.avi: fewer frames than its timestamps")
    return cases


#: Run as a user runs them, in a process of their own: a video, a partly usable video and
#: a table, so the in-process runs below stand for what a true process prints.
SUBPROCESS_CASES = ("batch empty.mp4", "describe garbage.mp4", "contact --stage stage_dup.csv")


def _in_process(argv: list[str]) -> tuple[int, str, str]:
    """``main(argv)`` as a fresh process runs it: exit status, stdout, stderr."""
    out, err = io.StringIO(), io.StringIO()
    root = logging.getLogger()
    handlers = root.handlers[:]
    root.handlers.clear()  # no handler, as in a fresh process: the CLI prints the warnings
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                rc = main(argv)
            except SystemExit as exc:  # argparse's errors
                rc = exc.code if isinstance(exc.code, int) else int(exc.code is not None)
            except Exception:  # what the interpreter would print, and its exit status
                traceback.print_exc()
                rc = 1
    finally:
        root.handlers[:] = handlers
    return rc, out.getvalue(), err.getvalue()


@pytest.fixture(scope="module")
def runs(corpus):
    d, _ = corpus
    cases = _cases(d)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get(
        "PYTHONPATH", "")])}
    (d / "out").mkdir()
    # The true processes run beside the in-process cases: they mostly wait on their start-up.
    procs = {name: subprocess.Popen([sys.executable, "-m", "camwhisker.cli", *cases[name][0]],
                                    env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                    text=True)
             for name in SUBPROCESS_CASES}  # fmt: skip
    done = {name: _in_process(argv) for name, (argv, _, _) in cases.items()
            if name not in procs}
    for name, proc in procs.items():
        out, err = proc.communicate(timeout=120)
        done[name] = (proc.returncode, out, err)
    return cases, done


def test_every_bad_input_gets_a_clear_error_and_its_exit_status(runs):
    cases, done = runs
    wrong = []
    for name, (_, code, needle) in cases.items():
        rc, _, err = done[name]
        if rc != code or needle not in err or "Traceback" in err or "np." in err:
            wrong.append(f"{name}: exit {rc} (expected {code}): {err.strip()[-300:]}")
    assert wrong == []
    assert len(cases) == 50


def test_bad_input_leaves_no_output_and_no_temporary_file(corpus, runs):
    d, _ = corpus
    cases, done = runs
    failed = {Path(a) for name, (argv, code, _) in cases.items() if code == 2
              for a in argv if str(a).startswith(str(d / "out"))}
    left = {p.name for p in (d / "out").iterdir()}
    assert not {p.name for p in failed} & left
    assert not [n for n in left if n.startswith(".")]  # atomic writes' temporary names


def _rows(path):
    with open(path) as fh:
        return list(csv.DictReader(fh))


def test_every_readable_frame_is_processed(corpus, runs):
    """Batch goes on past a corrupt stretch and writes each lost frame as an untrusted
    row; its table holds a tracked row for every frame PyAV can decode."""
    d, info = corpus
    out = d / "out"
    garbage = _rows(out / "garbage.csv")
    decoded = [r for r in garbage if r["note"] != GAP_REASON]
    assert len(garbage) == 90  # the container's count: every frame has its row
    assert len(decoded) == info["decodable"]["garbage.mp4"]
    assert all(r["ok"] == "0" for r in garbage if r["note"] == GAP_REASON)
    # Frames decoded from the broken references (to the next key frame) are untrusted:
    # one of them used to read ok with phi 1.57 deg off.
    damaged = [r for r in garbage if r["note"] == DAMAGED_REASON]
    assert damaged and all(r["ok"] == "0" for r in damaged)
    first_lost = min(int(r["frame"]) for r in garbage if r["note"] == GAP_REASON)
    assert min(int(r["frame"]) for r in damaged) > first_lost
    truncated = _rows(out / "truncated.csv")
    assert len(truncated) == info["decodable"]["truncated.avi"]
    live = _rows(out / "truncated.live.csv")
    assert len(live) == info["decodable"]["truncated.avi"]
    folder = _rows(out / "frames.csv")
    assert len(folder) == info["frames_in_folder"] == 12
    assert [r["frame"] for r in folder if r["note"] == GAP_REASON] == ["5"]
    assert sum(r["ok"] == "1" for r in folder) == 11  # the nominal clip: every frame tracks
    # The sidecars name what went wrong: no output that looks whole without saying so.
    for name in ("garbage.json", "truncated.json", "frames.json", "truncated.live.json",
                 "truncated.overlay.json"):
        assert json.loads((out / name).read_text())["problems"], name


def test_describe_counts_frames_decoded_against_the_container(corpus, runs):
    d, info = corpus
    _, done = runs
    rc, printed, err = done["describe garbage.mp4"]
    values = {k.strip(): v for k, v in (line.split(": ", 1) for line in printed.splitlines())}
    assert int(values["frames_decoded"]) == info["decodable"]["garbage.mp4"]
    assert int(values["frames_in_container"]) == 90
    assert "could not be decoded" in err
