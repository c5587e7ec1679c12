"""Batch resumes from any directory (issue #21, item 7)."""

import os
import shutil
from pathlib import Path

import pytest

from camwhisker.campaign import is_complete, output_path
from camwhisker.cli import main
from camwhisker.signals import read_signal_table

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "sample_frames" / "nominal_mjpg.avi"
SAMPLE_FRAMES = 12  # every one tracked (test_campaign: frames_decoded == 12)
VIDEOS = 40  # as in the issue; at ~0.3 s a video on 2 workers, the run lasts ~12 s


@pytest.fixture(scope="module")
def videos(tmp_path_factory):
    folder = tmp_path_factory.mktemp("videos")
    out = []
    for i in range(VIDEOS):
        out.append(folder / f"c{i:02d}.avi")
        shutil.copy(SAMPLE, out[-1])
    return out


def _outputs(videos, dest) -> list[Path]:
    return [output_path(v, dest) for v in videos]


def _check_outputs(outs) -> int:
    """Every table present is complete and whole; returns how many there are."""
    present = [o for o in outs if o.exists()]
    for out in present:
        assert is_complete(out), out
        table = read_signal_table(out)
        assert table["t_s"].size == SAMPLE_FRAMES and table["ok"].all(), out
    return len(present)


def test_output_path_does_not_depend_on_the_working_directory(tmp_path, monkeypatch):
    video = tmp_path / "data" / "day1" / "clip.avi"
    video.parent.mkdir(parents=True)
    seen = set()
    for cwd in (tmp_path, tmp_path / "data", Path("/")):
        monkeypatch.chdir(cwd)
        seen.add(output_path(video, tmp_path / "dest").resolve())
        rel = output_path(Path(os.path.relpath(video)), Path(os.path.relpath(tmp_path / "dest")))
        seen.add(rel.resolve())
    assert seen == {tmp_path / "dest" / "data" / "day1" / "clip.signals.csv"}


def test_dest_resume_from_another_directory_redoes_nothing(videos, tmp_path, monkeypatch, capsys):
    data = tmp_path / "data"
    data.mkdir()
    for v in videos[:2]:
        shutil.copy(v, data / v.name)
    monkeypatch.chdir(tmp_path)
    assert main(["batch", "data", "--dest", "out", "--quiet"]) == 0
    assert "2 videos: 2 done" in capsys.readouterr().out
    for cwd, args in [(data, [".", "--dest", "../out"]),
                      (Path("/"), [str(data), "--dest", str(tmp_path / "out")])]:  # fmt: skip
        monkeypatch.chdir(cwd)
        assert main(["batch", *args, "--quiet"]) == 0
        assert "2 videos: 0 done, 2 already complete" in capsys.readouterr().out
    assert _check_outputs(_outputs([data / v.name for v in videos[:2]], tmp_path / "out")) == 2
