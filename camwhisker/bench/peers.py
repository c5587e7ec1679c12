"""General-purpose point trackers, run on the same points as the front end.

Each peer follows the 13 image points of :data:`~camwhisker.vision.pose.POINT_NAMES`
(square corners, cross arm-end corners, magnifier tip) from their rest-frame
detection, on the grey image (``cv2.COLOR_BGR2GRAY``), with the rest frame's
patch as its template. Only the tracker differs from the front end: the pose
comes from the same exact fit (:func:`~camwhisker.vision.pose.fit_pose`).

A peer is a generator function ``track(frames, rest_frame, rest_uv)`` that
yields one (13, 2) array of pixel positions (u, v) per frame, NaN where the
point was lost. Frames are uint8 BGR (H, W, 3); nothing is modified.

Search regions. The benchmark's clips jump (holds at random poses, fast
sweeps): a corner moves up to ~120 px and the tip up to ~520 px between two
frames, within a reach of ~85 px (corners) and ~290 px (tip) from rest. The
global searches (matchTemplate, kornia) look over that whole reach around the
rest position; the local ones (phase correlation, CSRT) start from the last
position, as they are meant to, and lose points that jump beyond their window.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator

import cv2
import numpy as np

from camwhisker.sensor.model import TIP
from camwhisker.vision.lk import PATCH_HALF_PX

__all__ = [
    "PEERS",
    "REACH_CORNER_PX",
    "REACH_TIP_PX",
    "parabolic_peak",
    "track_match_template",
    "track_phase_correlation",
    "track_csrt",
    "track_kornia",
]

#: The tip's end face is ~72 px across: its template must hold the rim (81 x 81).
TIP_HALF_PX = 40
#: Search radius (px). The tip is unique: it is searched over its whole reach
#: around its rest position (<= 286 px in the benchmark scenes). A cross corner
#: has look-alikes on the other arms ~100-150 px away, so corners are searched
#: only within REACH_CORNER_PX of their last position.
REACH_CORNER_PX = 48
REACH_TIP_PX = 300
#: A correlation peak below this (normalised, in [-1, 1]) counts as lost.
MIN_SCORE = 0.5
#: Phase correlation: patch half size (px; 65 x 65 catches jumps < ~30 px) and
#: upsampling factor (1/20 px steps).
PHASE_HALF_PX = 32
PHASE_UPSAMPLE = 20
#: kornia: frames per batch, and the temperature of the soft-argmax over the
#: 3 x 3 correlation neighbourhood of the peak.
KORNIA_BATCH = 8
SOFT_ARGMAX_TEMPERATURE = 100.0


def parabolic_peak(score: np.ndarray) -> tuple[float, float, float]:
    """Sub-pixel (x, y) and value of the maximum of a 2-D score map.

    A parabola through the peak and its two neighbours along each axis; the
    integer peak where it lies on the border."""
    _, top, _, (x, y) = cv2.minMaxLoc(score)
    dx = dy = 0.0
    if 0 < x < score.shape[1] - 1:
        a, b, c = score[y, x - 1], score[y, x], score[y, x + 1]
        den = a - 2 * b + c
        dx = 0.5 * (a - c) / den if den < 0 else 0.0
    if 0 < y < score.shape[0] - 1:
        a, b, c = score[y - 1, x], score[y, x], score[y + 1, x]
        den = a - 2 * b + c
        dy = 0.5 * (a - c) / den if den < 0 else 0.0
    return x + dx, y + dy, float(top)


def _grey(frame: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)


def _radii(n: int = TIP + 1) -> np.ndarray:
    r = np.full(n, REACH_CORNER_PX)
    r[TIP] = REACH_TIP_PX
    return r


def _halves(n: int = TIP + 1, corner: int = PATCH_HALF_PX) -> np.ndarray:
    r = np.full(n, corner)
    r[TIP] = TIP_HALF_PX
    return r


def _templates(grey: np.ndarray, uv: np.ndarray, half):
    """Patches (2 half + 1, 2 half + 1) around the rounded points (half per point
    or one for all), and the points' sub-pixel offsets from the patch centres
    (N, 2); None where outside or not found."""
    h, w = grey.shape
    halves = np.broadcast_to(half, (len(uv),))
    ok = np.isfinite(uv).all(axis=1)
    centre = np.round(np.where(ok[:, None], uv, 0)).astype(int)
    out = []
    for (u, v), half, good in zip(centre, halves, ok, strict=True):
        if good and half <= u < w - half and half <= v < h - half:
            out.append(grey[v - half : v + half + 1, u - half : u + half + 1].copy())
        else:
            out.append(None)
    return out, uv - centre


def track_match_template(
    frames: Iterable[np.ndarray], rest_frame: np.ndarray, rest_uv: np.ndarray
) -> Iterator[np.ndarray]:
    """cv2.matchTemplate (TM_CCOEFF_NORMED) of each rest patch, the tip over its
    reach around its rest position, corners around their last position, with a
    parabolic sub-pixel peak."""
    halves = _halves(len(rest_uv))
    tmpl, frac = _templates(_grey(rest_frame), rest_uv, halves)
    rest_centre = np.round(rest_uv).astype(int)
    last = rest_uv.astype(float).copy()
    radii = _radii(len(rest_uv))
    for frame in frames:
        g = _grey(frame)
        h, w = g.shape
        out = np.full((len(rest_uv), 2), np.nan)
        centre = np.round(last).astype(int)
        centre[TIP] = rest_centre[TIP]
        for k, t in enumerate(tmpl):
            if t is None:
                continue
            half = halves[k]
            u0 = max(centre[k, 0] - radii[k] - half, 0)
            v0 = max(centre[k, 1] - radii[k] - half, 0)
            u1 = min(centre[k, 0] + radii[k] + half + 1, w)
            v1 = min(centre[k, 1] + radii[k] + half + 1, h)
            score = cv2.matchTemplate(g[v0:v1, u0:u1], t, cv2.TM_CCOEFF_NORMED)
            x, y, top = parabolic_peak(score)
            if top >= MIN_SCORE:
                out[k] = (u0 + x + half + frac[k, 0], v0 + y + half + frac[k, 1])
        found = np.isfinite(out).all(axis=1)
        last[found] = out[found]
        yield out


def track_phase_correlation(
    frames: Iterable[np.ndarray], rest_frame: np.ndarray, rest_uv: np.ndarray
) -> Iterator[np.ndarray]:
    """skimage's phase_cross_correlation (upsample_factor PHASE_UPSAMPLE) of each
    rest patch against the patch at the point's last position."""
    from skimage.registration import phase_cross_correlation

    half = _halves(len(rest_uv), PHASE_HALF_PX)
    half[TIP] = 2 * TIP_HALF_PX
    tmpl, frac = _templates(_grey(rest_frame).astype(np.float32), rest_uv, half)
    last = rest_uv.astype(float).copy()
    for frame in frames:
        g = _grey(frame).astype(np.float32)
        cur, _ = _templates(g, last, half)
        centre = np.round(last)
        out = np.full((len(rest_uv), 2), np.nan)
        for k, (t, c) in enumerate(zip(tmpl, cur, strict=True)):
            if t is None or c is None:
                continue
            # shift registers the current patch onto the rest patch: the point
            # moved by -shift (rows, cols) from the patch centre.
            shift, _, _ = phase_cross_correlation(t, c, upsample_factor=PHASE_UPSAMPLE)
            out[k] = centre[k] - shift[::-1] + frac[k]
        found = np.isfinite(out).all(axis=1)
        last[found] = out[found]
        yield out


def _csrt():
    if hasattr(cv2, "TrackerCSRT"):
        return cv2.TrackerCSRT.create()
    return cv2.TrackerCSRT_create()  # pragma: no cover - older OpenCV


def track_csrt(
    frames: Iterable[np.ndarray], rest_frame: np.ndarray, rest_uv: np.ndarray
) -> Iterator[np.ndarray]:
    """OpenCV's CSRT tracker (contrib), one per point, on a 25 x 25 box; its
    boxes are whole pixels, so the points are too (plus the rest offset)."""
    centre = np.round(rest_uv).astype(int)
    frac = rest_uv - centre
    trackers = []
    for (u, v), half in zip(centre, _halves(len(rest_uv)), strict=True):
        side = int(2 * half + 1)
        t = _csrt()
        t.init(rest_frame, (int(u - half), int(v - half), side, side))
        trackers.append(t)
    for frame in frames:
        out = np.full((len(trackers), 2), np.nan)
        for k, t in enumerate(trackers):
            ok, (x, y, bw, bh) = t.update(frame)
            if ok:
                out[k] = (x + (bw - 1) / 2 + frac[k, 0], y + (bh - 1) / 2 + frac[k, 1])
        yield out


def _box_mean(x, side: int):
    """Mean over every side x side box of the last two axes (valid part), by
    summed-area table: O(1) per box, where avg_pool2d is O(side^2)."""
    import torch.nn.functional as F

    s = F.pad(x, (1, 0, 1, 0)).cumsum(-1).cumsum(-2)
    box = s[..., side:, side:] - s[..., :-side, side:]
    box = box - s[..., side:, :-side] + s[..., :-side, :-side]
    return box / (side * side)


def track_kornia(
    frames: Iterable[np.ndarray], rest_frame: np.ndarray, rest_uv: np.ndarray,
    batch: int = KORNIA_BATCH,
) -> Iterator[np.ndarray]:  # fmt: skip
    """A batched backend for recorded video: KORNIA_BATCH frames x 13 points at once.

    Zero-mean normalised cross-correlation of each rest patch over its search
    window (the tip: its reach around its rest position; a corner: around its
    position at the end of the previous batch), computed by FFT over a tensor of
    (batch, points) windows; the integer peak, then kornia's spatial soft-argmax
    over its 3 x 3 neighbourhood. On CUDA where torch has it, else on the CPU."""
    import kornia
    import torch
    import torch.nn.functional as F

    dev = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    n_pts = len(rest_uv)
    halves = _halves(n_pts)
    radii = _radii(n_pts)
    tmpl, frac = _templates(_grey(rest_frame).astype(np.float32), rest_uv, halves)
    has = np.array([t is not None for t in tmpl])
    rest_centre = np.round(rest_uv).astype(int)
    last = rest_uv.astype(float).copy()
    groups = []
    for half, r in sorted({(int(h), int(r)) for h, r in zip(halves, radii, strict=True)}):
        idx = np.flatnonzero(has & (halves == half) & (radii == r))
        if len(idx) == 0:
            continue
        side, size = 2 * half + 1, 2 * (r + half) + 1
        t = torch.from_numpy(np.stack([tmpl[k] for k in idx])).to(dev).double()
        t = t - t.mean(dim=(1, 2), keepdim=True)
        t = t / t.flatten(1).norm(dim=1).clamp_min(1e-6)[:, None, None]
        t_hat = torch.fft.rfft2(F.pad(t, (0, size - side, 0, size - side))).conj()
        groups.append((idx, half, r, side, size, t_hat))
    pad = int((radii + halves).max())

    def run(chunk):
        g = torch.from_numpy(np.stack(chunk)).to(dev).permute(0, 3, 1, 2).float()
        g = kornia.color.bgr_to_grayscale(g)[:, 0].double()  # (B, H, W)
        g = F.pad(g[:, None], (pad, pad, pad, pad), mode="replicate")[:, 0]
        out = np.full((len(chunk), n_pts, 2), np.nan)
        centre = np.round(last).astype(int)
        centre[TIP] = rest_centre[TIP]
        for idx, half, r, side, size, t_hat in groups:
            o = centre[idx] - r - half + pad  # window corners in padded coordinates
            win = torch.stack([g[:, v : v + size, u : u + size] for u, v in o], dim=1)
            n_out = 2 * r + 1
            corr = torch.fft.irfft2(torch.fft.rfft2(win) * t_hat, s=(size, size))
            corr = corr[..., :n_out, :n_out]  # (B, P, 2r + 1, 2r + 1)
            mean = _box_mean(win, side)
            sq = _box_mean(win * win, side)
            norm = ((sq - mean * mean).clamp_min(0) * side * side).sqrt().clamp_min(1e-3)
            ncc = corr / norm
            b, p, _, ww = ncc.shape
            flat = ncc.flatten(2).argmax(dim=2)  # (B, P)
            y, x = flat // ww, flat % ww
            top = ncc.flatten(2).gather(2, flat[..., None])[..., 0]
            nb = F.pad(ncc, (1, 1, 1, 1), value=-1.0)
            d = torch.arange(3, device=dev)
            rows = (y[..., None] + d)[..., :, None].expand(b, p, 3, 3)
            cols = (x[..., None] + d)[..., None, :].expand(b, p, 3, 3)
            lin = (rows * (ww + 2) + cols).flatten(2)
            patch = nb.flatten(2).gather(2, lin).view(b, p, 3, 3).float()
            sub = kornia.geometry.subpix.spatial_soft_argmax2d(
                patch, torch.tensor(SOFT_ARGMAX_TEMPERATURE), normalized_coordinates=False
            )  # (B, P, 2): (x, y) in [0, 2]
            u = (x.double() + sub[..., 0].double() - 1).cpu().numpy()
            v = (y.double() + sub[..., 1].double() - 1).cpu().numpy()
            good = (top >= MIN_SCORE).cpu().numpy()
            for j, k in enumerate(idx):
                uk = centre[k, 0] - r + u[:, j] + frac[k, 0]
                vk = centre[k, 1] - r + v[:, j] + frac[k, 1]
                out[good[:, j], k] = np.column_stack([uk, vk])[good[:, j]]
        for row in out:
            found = np.isfinite(row).all(axis=1)
            last[found] = row[found]
        return out

    chunk = []
    with torch.inference_mode():
        for frame in frames:
            chunk.append(frame)
            if len(chunk) == batch:
                yield from run(chunk)
                chunk = []
        if chunk:
            yield from run(chunk)


#: Peer name -> tracker generator function.
PEERS = {
    "matchTemplate": track_match_template,
    "phase correlation": track_phase_correlation,
    "CSRT": track_csrt,
    "kornia": track_kornia,
}
