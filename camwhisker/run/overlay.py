"""Pictures of what the front end tracked: annotated frames, a rest check image, a video.

:func:`annotate_frame` draws, on a copy of a frame, the tracked corners and
the tip, the fitted model's outline (the square, the cross, the rod and the
tip's rim, placed at the fitted pose as the front end places them: the
forward model plus the rest offsets), each point's motion from its rest
position drawn at 10x (as in the paper's Fig. 4), and a line of text with
the pose. :func:`rest_check_image` draws the rest frame with every feature
named, for a user to see that detection found the right things;
:func:`write_rest_check` writes it (batch writes one beside each table).
:func:`annotate_video` drives the streaming core (:func:`camwhisker.vision.stream.stream`)
over a video and writes the annotated video with a JSON sidecar.

Pixels are (u, v): u to the right, v down, as everywhere in the package.
Colours are BGR.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from itertools import islice
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from camwhisker.files import jsonfile
from camwhisker.files.atomic import atomic_write_bytes, atomic_write_text
from camwhisker.io.signals import provenance
from camwhisker.io.sources import check_frame_size, open_source
from camwhisker.io.video_out import VIDEO_SUFFIXES, write_video
from camwhisker.sensor.file import Sensor
from camwhisker.sensor.model import N_SQUARE, POINT_NAMES, TIP, PlateModel
from camwhisker.vision.stream import Frame, stream
from camwhisker.vision.tracker import FrameResult, FrontEndOptions

__all__ = [
    "ARROW_SCALE",
    "LAYERS",
    "TRACKED_BGR",
    "UNTRACKED_BGR",
    "TIP_BGR",
    "OUTLINE_BGR",
    "ARROW_BGR",
    "Placement",
    "OverlayReport",
    "pose_vector",
    "is_rest_row",
    "status_line",
    "annotate_frame",
    "rest_check_image",
    "write_rest_check",
    "annotate_video",
    "rest_check_path",
    "sidecar_path",
]

#: Motion arrows are drawn this many times their length, as in the paper's Fig. 4.
ARROW_SCALE = 10.0
#: What :func:`annotate_frame` draws, bottom to top.
LAYERS = ("outline", "arrows", "points", "text")

#: Colours (BGR): each stands out on the blue square, the red cross, the black
#: tip and a light cloth; :func:`_legend` names them.
TRACKED_BGR = (0, 255, 0)
UNTRACKED_BGR = (255, 0, 255)
TIP_BGR = (255, 255, 0)
OUTLINE_BGR = (0, 255, 255)
ARROW_BGR = (0, 140, 255)
TEXT_BGR = (255, 255, 255)
TEXT_BACK_BGR = (0, 0, 0)
#: Radius of a tracked point's dot (px): small beside a corner's 25 px window.
MARKER_RADIUS_PX = 3
#: Half the span of an untracked point's cross (px).
CROSS_HALF_PX = 5
#: OpenCV draws with this many fractional bits: points placed to 1/16 px.
_SHIFT = 4
_ONE = 1 << _SHIFT
#: Text height as a share of the image height: legible at 720 and at 480 lines.
TEXT_HEIGHT_SHARE = 0.028
#: Labels of the rest check image: their size against the title's, their
#: distance from the plate's centre against its farthest point's (out of the
#: plate, where the rays to the corners part), and the tip's label's offset (px).
LABEL_SIZE = 0.7
LABEL_RADIUS = 1.4
LABEL_OFFSET_PX = 10.0


@dataclass(frozen=True)
class Placement:
    """Where the front end places the features at a pose: the forward model plus
    the rest offsets.

    Attributes
    ----------
    model : PlateModel
    rest_uv : ndarray, shape (13, 2)
        The rest frame's points (12 corners, the tip), px.
    offsets_uv : ndarray, shape (13, 2)
        Rest points minus the model's points at pose zero (px), as the front
        end measures them at its rest frame.
    """

    model: PlateModel
    rest_uv: np.ndarray
    offsets_uv: np.ndarray

    @classmethod
    def from_rest(cls, model: PlateModel, rest: FrameResult) -> Placement:
        """From the front end's rest frame result (its points are the rest points)."""
        rest_uv = np.array(rest.points_uv, float)
        if not np.isfinite(rest_uv).all():
            raise ValueError(f"frame {rest.frame} is not a rest frame: not every point found")
        model_uv = model.project(np.zeros(5), jacobian=False)[0]
        return cls(model, rest_uv, rest_uv - model_uv)

    def points(self, q: np.ndarray) -> np.ndarray:
        """The 13 points at pose q, shape (13, 2)."""
        return self.model.project(q, jacobian=False)[0] + self.offsets_uv

    def outlines(self, q: np.ndarray) -> dict[str, np.ndarray]:
        """Closed outlines at pose q, each shape (N, 2): "square", "cross", "rod"
        (the convex hull of its two end rims) and "rim" (the tip's end face).

        The rod and the rim move with the tip's rest offset, as the front end
        places them; the cross with its tracked corners' mean rest offset."""
        rim, rod, cross = self.model.outlines(q)
        tip_offset = self.offsets_uv[TIP]
        rod_hull = cv2.convexHull((rod + tip_offset).astype(np.float32))[:, 0].astype(float)
        return {
            "square": self.model.corners(q)[:N_SQUARE] + self.offsets_uv[:N_SQUARE],
            "cross": cross + self.offsets_uv[N_SQUARE:TIP].mean(axis=0),
            "rod": rod_hull,
            "rim": rim + tip_offset,
        }


def pose_vector(result: FrameResult) -> np.ndarray | None:
    """The fitted pose q = (dz_mm, a_rad, b_rad, sx_mm, sy_mm) of a frame
    (:attr:`FrameResult.q`, a copy), or None where no fit converged."""
    q = np.asarray(result.q, float)
    return q.copy() if np.isfinite(q).all() else None


def is_rest_row(result: FrameResult, event: str, started: bool) -> bool:
    """Whether a row of :func:`camwhisker.vision.stream.stream` is a rest frame.

    ``started``: whether an earlier row was. The stream trusts no row before
    the front end starts, so its first trusted row is the rest frame; after
    it, a trusted ``"rezero"`` row is a new one."""
    return bool(result.ok) and (not started or event == "rezero")


def status_line(result: FrameResult) -> str:
    """One line: frame, dz, phi, theta, and ok or the reason."""

    def num(value: float, fmt: str) -> str:
        return format(value, fmt) if math.isfinite(value) else "-"

    state = "ok" if result.ok else (result.reason or "not ok")
    return (
        f"frame {result.frame}  dz {num(result.dz_mm, '+.3f')} mm  "
        f"phi {num(result.phi_deg, '.2f')} deg  theta {num(result.theta_deg, '.1f')} deg  "
        f"{state}"
    )


def _fixed(uv: np.ndarray) -> np.ndarray:
    """Pixels as OpenCV's fixed-point coordinates (``_SHIFT`` fractional bits)."""
    return np.round(np.asarray(uv, float) * _ONE).astype(np.int32)


def _point(uv) -> tuple[int, int]:
    u, v = _fixed(uv)
    return int(u), int(v)


def _draw_outlines(image: np.ndarray, outlines: dict[str, np.ndarray]) -> None:
    polys = [_fixed(p) for p in outlines.values() if np.isfinite(p).all()]
    cv2.polylines(image, polys, True, OUTLINE_BGR, 1, cv2.LINE_AA, _SHIFT)


def _draw_arrows(image: np.ndarray, rest_uv: np.ndarray, uv: np.ndarray, scale: float) -> None:
    for start, now in zip(rest_uv, uv, strict=True):
        if not np.isfinite(now).all():
            continue
        end = start + scale * (now - start)
        if np.hypot(*(end - start)) < 1.0:  # nothing to see
            continue
        cv2.arrowedLine(image, _point(start), _point(end), ARROW_BGR, 1, cv2.LINE_AA, _SHIFT, 0.2)


def _draw_cross(image: np.ndarray, uv: np.ndarray, colour) -> None:
    for du, dv in ((1, 1), (1, -1)):
        d = np.array([du, dv]) * CROSS_HALF_PX
        cv2.line(image, _point(uv - d), _point(uv + d), colour, 2, cv2.LINE_AA, _SHIFT)


def _draw_points(image: np.ndarray, uv: np.ndarray, expected_uv: np.ndarray | None) -> None:
    """Dots at the tracked points; crosses where the untracked ones were expected."""
    for k, point in enumerate(uv):
        if np.isfinite(point).all():
            colour = TIP_BGR if k == TIP else TRACKED_BGR
            cv2.circle(image, _point(point), MARKER_RADIUS_PX * _ONE, colour, -1, cv2.LINE_AA,
                       _SHIFT)  # fmt: skip
        elif expected_uv is not None and np.isfinite(expected_uv[k]).all():
            _draw_cross(image, expected_uv[k], UNTRACKED_BGR)


def _text_scale(image: np.ndarray) -> tuple[float, int]:
    """OpenCV font scale and thickness for text TEXT_HEIGHT_SHARE of the image high."""
    scale = TEXT_HEIGHT_SHARE * image.shape[0] / 22.0  # the font is ~22 px at scale 1
    return scale, max(1, round(scale * 1.5))


def _draw_text(image: np.ndarray, text: str, origin: tuple[float, float]) -> None:
    """Text on a dark box, its top-left corner at ``origin`` (px)."""
    font = cv2.FONT_HERSHEY_SIMPLEX
    scale, thick = _text_scale(image)
    (w, h), base = cv2.getTextSize(text, font, scale, thick)
    u, v = int(round(origin[0])), int(round(origin[1]))
    pad = max(2, h // 4)
    cv2.rectangle(image, (u, v), (u + w + 2 * pad, v + h + base + 2 * pad), TEXT_BACK_BGR, -1)
    cv2.putText(image, text, (u + pad, v + pad + h), font, scale, TEXT_BGR, thick, cv2.LINE_AA)


def _checked_copy(frame: np.ndarray) -> np.ndarray:
    frame = np.asarray(frame)
    if frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype != np.uint8:
        raise ValueError(f"expected a uint8 BGR frame (H, W, 3), got {frame.dtype} {frame.shape}")
    return frame.copy()


def annotate_frame(
    frame: np.ndarray,
    result: FrameResult,
    placement: Placement | None,
    q: np.ndarray | None = None,
    scale: float = ARROW_SCALE,
    layers: tuple[str, ...] = LAYERS,
) -> np.ndarray:
    """An annotated copy of a frame; ``frame`` itself is left as it was.

    Parameters
    ----------
    frame : ndarray, shape (H, W, 3), uint8
        BGR frame the front end saw.
    result : FrameResult
        The front end's result for it.
    placement : Placement or None
        The rest reference (None before the rest frame: text only).
    q : ndarray, shape (5,), optional
        The fitted pose (:func:`pose_vector`): the model's outline is drawn
        there, and untracked points are crossed where it puts them. None: no
        outline; untracked points are crossed at their rest position.
    scale : float
        Motion arrows are this many times each point's displacement from rest.
    layers : tuple of str
        Which of :data:`LAYERS` to draw.

    Returns
    -------
    ndarray, shape (H, W, 3), uint8
    """
    unknown = set(layers) - set(LAYERS)
    if unknown:
        raise ValueError(f"unknown layers {sorted(unknown)}; choose from {LAYERS}")
    image = _checked_copy(frame)
    uv = np.asarray(result.points_uv, float)
    if placement is not None:
        if "outline" in layers and q is not None:
            _draw_outlines(image, placement.outlines(q))
        if "arrows" in layers:
            _draw_arrows(image, placement.rest_uv, uv, scale)
        if "points" in layers:
            expected = placement.points(q) if q is not None else placement.rest_uv
            _draw_points(image, uv, expected)
    if "text" in layers:
        _draw_text(image, status_line(result), (0, 0))
        _draw_text(image, _legend(scale), (0, image.shape[0] - _text_box_height(image)))
    return image


def _legend(scale: float) -> str:
    return (f"green: tracked  magenta x: not tracked  cyan: tip  yellow: fitted model  "
            f"orange: motion x{scale:g}")  # fmt: skip


def _text_box_height(image: np.ndarray) -> int:
    """Height (px) of a :func:`_draw_text` box."""
    scale, thick = _text_scale(image)
    (_, h), base = cv2.getTextSize("Ag", cv2.FONT_HERSHEY_SIMPLEX, scale, thick)
    return h + base + 2 * max(2, h // 4)


def _draw_label(image, text, uv, centre_uv, radius_px) -> None:
    """A small label out from ``uv`` along the ray from the plate's centre, at
    ``radius_px`` from the centre, joined to its point by a line; a point at the
    centre (the tip) is labelled beside it."""
    scale, thick = _text_scale(image)
    scale *= LABEL_SIZE
    font = cv2.FONT_HERSHEY_SIMPLEX
    (w, h), base = cv2.getTextSize(text, font, scale, thick)
    d = uv - centre_uv
    n = float(np.hypot(*d))
    if n < LABEL_OFFSET_PX:
        anchor = uv + LABEL_OFFSET_PX
        corner = anchor
    else:
        d = d / n
        anchor = centre_uv + radius_px * d
        cv2.line(image, _point(uv), _point(anchor), TEXT_BACK_BGR, 1, cv2.LINE_AA, _SHIFT)
        # The box's centre stands out from the anchor by half its size along the ray.
        half = np.array([w + 4, h + base + 4]) / 2
        corner = anchor + d * half - half
    u, v = int(round(corner[0])), int(round(corner[1]))
    cv2.rectangle(image, (u, v), (u + w + 4, v + h + base + 4), TEXT_BACK_BGR, -1)
    cv2.putText(image, text, (u + 2, v + 2 + h), font, scale, TEXT_BGR, thick, cv2.LINE_AA)


def rest_check_image(
    frame: np.ndarray, result: FrameResult, model: PlateModel, names: bool = True
) -> np.ndarray:
    """The rest frame annotated for a check by eye: the model's outline at rest,
    every detected point, each named (``POINT_NAMES``), and a title line.

    Parameters
    ----------
    frame : ndarray, shape (H, W, 3), uint8
        The rest frame (left as it was).
    result : FrameResult
        What :meth:`FrontEnd.start` returned for it.
    model : PlateModel
    names : bool
        Label each point with its name.

    Returns
    -------
    ndarray, shape (H, W, 3), uint8
    """
    placement = Placement.from_rest(model, result)
    image = annotate_frame(frame, result, placement, np.zeros(5), layers=("outline",))
    if names:
        centre = placement.rest_uv[:TIP].mean(axis=0)
        radius = LABEL_RADIUS * np.hypot(*(placement.rest_uv[:TIP] - centre).T).max()
        for name, uv in zip(POINT_NAMES, placement.rest_uv, strict=True):
            _draw_label(image, name, uv, centre, radius)
    _draw_points(image, placement.rest_uv, None)  # over the labels' lines
    found = int(np.isfinite(result.points_uv).all(axis=1).sum())
    _draw_text(image, f"rest frame {result.frame}: {found} of {TIP + 1} features found", (0, 0))
    return image


def sidecar_path(out: str | Path) -> Path:
    """``OUT.overlay.json`` beside ``OUT.mp4``: apart from batch's ``OUT.json`` of the
    same recording."""
    out = Path(out)
    return out.with_name(out.stem + ".overlay.json")


def rest_check_path(out: str | Path) -> Path:
    """``OUT.rest.png`` beside an output ``OUT.ext``."""
    out = Path(out)
    return out.with_name(out.stem + ".rest.png")


def write_rest_check(
    path: str | Path, frame: np.ndarray, result: FrameResult, model: PlateModel
) -> Path:
    """Write :func:`rest_check_image` as a PNG (atomically); returns the path."""
    path = Path(path)
    ok, data = cv2.imencode(".png", rest_check_image(frame, result, model))
    if not ok:  # pragma: no cover - PNG encoding of a uint8 image does not fail
        raise OSError(f"{path}: PNG encoding failed")
    atomic_write_bytes(path, data.tobytes())
    return path


@dataclass
class OverlayReport:
    """What :func:`annotate_video` wrote: the video, its sidecar and rest check
    image, the frame counts, and problems that did not stop it."""

    out: Path
    sidecar: Path
    rest_check: Path
    frames: int = 0
    frames_ok: int = 0
    problems: list[str] = dataclasses.field(default_factory=list)


def _annotated_frames(
    frames: Iterable[Frame],
    sensor: Sensor,
    options: FrontEndOptions,
    rest_index: int,
    scale: float,
    report: OverlayReport,
) -> Iterator[np.ndarray]:
    """Drive the streaming core over the frames; yield each annotated, counting the
    rows in ``report`` and writing the rest check image at the first rest frame."""
    model = PlateModel(sensor)
    placement = None
    for frame, result in stream(frames, sensor, options, rest_index, strict=True):
        report.frames += 1
        report.frames_ok += bool(result.ok)
        if frame.image is None:  # a recorded session's gap: no picture to draw on
            continue
        if is_rest_row(result, frame.event, placement is not None):
            if placement is None:
                write_rest_check(report.rest_check, frame.image, result, model)
            placement = Placement.from_rest(model, result)
        q = pose_vector(result) if placement is not None else None
        yield annotate_frame(frame.image, result, placement, q, scale)
    if placement is None:
        raise ValueError(f"the video has no frame {rest_index} to use as the rest frame")


def annotate_video(
    video: str | Path,
    sensor: Sensor,
    out: str | Path,
    options: FrontEndOptions | None = None,
    rest_index: int = 0,
    max_frames: int | None = None,
    scale: float = ARROW_SCALE,
    progress: bool = True,
) -> OverlayReport:
    """Run the front end over a video and write it annotated (:func:`annotate_frame`).

    Parameters
    ----------
    video : path
        A video file OpenCV can read, or a folder of images.
    sensor : Sensor
    out : path
        ``.mp4`` (H.264) or ``.avi`` (MJPG). Beside it: ``OUT.overlay.json`` (how it
        was made) and ``OUT.rest.png`` (:func:`rest_check_image`).
    options : FrontEndOptions, optional
    rest_index : int
        The rest (reference) frame.
    max_frames : int, optional
        Stop after this many frames.
    scale : float
        Motion arrows' scale.
    progress : bool
        Show a progress bar.

    Returns
    -------
    OverlayReport

    Raises
    ------
    FileNotFoundError, camwhisker.io.sources.SourceError
        The input is missing or not a video.
    ValueError
        A frame's size differs from the sensor file's, the rest frame lacks a
        feature (``FeaturesNotFound``) or the video ends before it, or ``out``
        is neither .mp4 nor .avi. Nothing is written then.
    """
    if rest_index < 0:
        raise ValueError(f"rest_index must be >= 0, got {rest_index}")
    if max_frames is not None and max_frames < 1:
        raise ValueError(f"max_frames must be >= 1, got {max_frames}")
    out = Path(out)
    if out.suffix.lower() not in VIDEO_SUFFIXES:
        raise ValueError(f"{out}: video must end in .avi (MJPG) or .mp4 (H.264)")
    options = options or FrontEndOptions()
    source = open_source(video)
    check_frame_size(source, sensor)
    report = OverlayReport(out, sidecar_path(out), rest_check_path(out))
    frames = _annotated_frames(islice(source, max_frames), sensor, options, rest_index, scale,
                               report)  # fmt: skip
    total = len(source) or None
    if max_frames is not None:
        total = min(total or max_frames, max_frames)
    with tqdm(frames, total=total, unit="frame", desc="overlay", disable=not progress) as bar:
        write_video(out, bar, source.fps)
    # Stopping at max_frames is not the video ending early.
    if source.problem and (max_frames is None or report.frames < max_frames):
        report.problems.append(source.problem)
    meta = provenance("camwhisker.run.overlay.annotate_video", str(Path(video)), options, sensor,
                      fps=source.fps, codec="MJPG" if out.suffix.lower() == ".avi" else "H.264",
                      rest_frame=rest_index, max_frames=max_frames, arrow_scale=scale,
                      frames=report.frames, frames_ok=report.frames_ok, problems=report.problems,
                      rest_check=report.rest_check.name)  # fmt: skip
    atomic_write_text(report.sidecar, jsonfile.dumps(meta, indent=2) + "\n")
    return report
