"""The configurations the benchmark compares.

The default against each knob of ``FrontEndOptions`` varied on its own:
``mode`` (the paper's eqs. 2-7 or the exact model), ``fit_shift``,
``lock_gains`` (the white-balance method: gains per frame from the cloth, or
the rest frame's), ``lk_half_px`` (the LK window) and ``roi_margin_px`` (the
region of interest around each corner); then the paper-literal pipeline and
the peers.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from camwhisker.vision.tracker import FrontEndOptions

__all__ = ["Config", "CONFIGS", "DEFAULT", "PAPER", "select"]


@dataclass(frozen=True)
class Config:
    """One pipeline: the front end with ``options``, or a peer tracker by name.

    full_frame_map : compute the eq. (1) contrast map of the whole frame every
        frame as well (the paper's cost: it maps the full image).
    detect_each_frame : no tracking: every frame's features found afresh by
        segmenting the full-frame eq. (1) map (:func:`~camwhisker.vision.detect.detect_features`),
        then eqs. (2)-(7) (``options.mode == "paper"``) or the exact pose fit.
    """

    name: str
    options: FrontEndOptions = field(default_factory=FrontEndOptions)
    peer: str | None = None
    full_frame_map: bool = False
    detect_each_frame: bool = False
    note: str = ""


DEFAULT = "default"
PAPER = "paper-literal"

CONFIGS = [
    Config(DEFAULT, note="FrontEndOptions()"),
    Config(
        PAPER,
        FrontEndOptions(mode="paper"),
        full_frame_map=True,
        note='mode="paper" + full-frame eq. 1 map per frame',
    ),
    Config(
        "paper-literal (detect every frame)",
        FrontEndOptions(mode="paper"),
        detect_each_frame=True,
        note="full-frame eq. 1 map segmented every frame (detect_features), eqs. 2-7",
    ),
    Config(
        "peer: matchTemplate",
        peer="matchTemplate",
        note="TM_CCOEFF_NORMED, tip over its reach, corners within 48 px; parabolic peak",
    ),
    Config(
        "peer: phase correlation",
        peer="phase correlation",
        note="skimage, upsample 20, 65 px patch at last position",
    ),
    Config("peer: CSRT", peer="CSRT", note="cv2.TrackerCSRT per point, whole pixels"),
    Config("peer: kornia", peer="kornia", note="8 frames x 13 points, NCC + soft-argmax"),
    Config("fit_shift=False", FrontEndOptions(fit_shift=False)),
    Config("lock_gains=True", FrontEndOptions(lock_gains=True)),
    Config("lk_half_px=8", FrontEndOptions(lk_half_px=8)),
    Config("lk_half_px=16", FrontEndOptions(lk_half_px=16)),
    Config("roi_margin_px=10", FrontEndOptions(roi_margin_px=10)),
    Config("roi_margin_px=30", FrontEndOptions(roi_margin_px=30)),
]


def select(names: str | None) -> list[Config]:
    """Configurations by comma-separated names (all when None).

    Raises
    ------
    ValueError
        Naming an unknown configuration.
    """
    if not names:
        return list(CONFIGS)
    by_name = {c.name: c for c in CONFIGS}
    out = []
    for name in (n.strip() for n in names.split(",")):
        if name not in by_name:
            raise ValueError(f"unknown configuration {name!r} (known: {', '.join(by_name)})")
        out.append(by_name[name])
    return out
