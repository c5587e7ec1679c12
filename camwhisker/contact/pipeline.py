"""From a signal table and a stage log to contact estimates, pause by pause or frame by frame.

Data flow: signals + stage log -> clock offset -> pause medians -> contact onset
-> dx -> GM, MF -> Z -> fusion -> shape. :func:`estimate` is the vectorised core
that both the pause-level evaluation and the per-frame contact table use.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from camwhisker.contact.clock import estimate_offset_motion
from camwhisker.contact.fusion import MF_BIAS_FLOOR_MM, fuse
from camwhisker.contact.gm import GMFit, r_gm
from camwhisker.contact.mf import MFTable, r_mf
from camwhisker.contact.shape import BendCorrection, reconstruct
from camwhisker.contact.slip import slip_segments, slip_state, slipped, slipping
from camwhisker.contact.smooth import local_line
from camwhisker.contact.stage import (
    CONTACT_PHI_DEG,
    PauseTable,
    StageLog,
    contact_onset_x,
    detect_pauses,
    estimate_offset,
    pause_index,
    pause_medians,
)
from camwhisker.contact.zscore import SpreadTable, z_combined, z_dissimilarity

__all__ = ["Calibration", "RunAnalysis", "analyse_run", "estimate", "contact_rows", "base_speed",
           "doubt", "smooth_half_frames", "MODES"]


@dataclass(frozen=True)
class Calibration:
    """Everything the contact estimates need (see :mod:`camwhisker.contact.calibrate`)."""

    gm: GMFit
    gm_spread: SpreadTable
    mf_table: MFTable
    mf_spread: SpreadTable  # at a radius not calibrated (leave one run out): Table II
    mf_noise: SpreadTable  # from the pause medians' noise alone: what the fusion averages
    l_w_mm: float
    provenance: dict
    # MF's error over a contact between its radii, which the fusion allows a good GM.
    mf_bias_floor_mm: float = MF_BIAS_FLOOR_MM
    # What the GM model misses of the bent whisker, for eq. 12; None: nothing calibrated.
    bend: BendCorrection | None = None
    # Noise of a pause median of dz (mm), which sigma_MF at a pause scales; None: not
    # calibrated (sigma_MF is the calibration's per phi bin).
    dz_noise_mm: float | None = None


# A run with fewer pauses than this is aligned and its onset found from the motion:
# the rests before and after a sweep are two pauses that only bracket it.
MIN_PAUSES = 3


@dataclass(frozen=True)
class RunAnalysis:
    """One run on the camera clock: offset, pause medians, contact onset."""

    offset_s: float
    offset_score: float
    offset_estimated: bool
    pauses: PauseTable
    x_contact_mm: float
    travel_sign: float
    dx_mm: np.ndarray  # per pause, NaN before contact
    paused: bool = True  # False: offset and onset from continuous motion
    offset_se_s: float = math.nan  # standard error of an offset from motion; NaN otherwise


def analyse_run(signals: dict, log: StageLog, offset_s: float | None = None) -> RunAnalysis:
    """Clock offset (estimated unless given), pause medians and first contact of one run.

    Raises
    ------
    ValueError
        No row of the signal table is ok (named by its ``source``), or the offset
        cannot be estimated.
    """
    ok = np.asarray(signals["ok"], bool)
    if not ok.any():
        # Without one trusted row every estimate is empty: say so rather than write it.
        raise ValueError(f"{signals.get('source', '<signals>')}: no row is ok (ok = 0 in all "
                         f"{ok.size} rows): nothing to estimate contact from")
    estimated = offset_s is None
    score, se = math.nan, math.nan
    paused = detect_pauses(log).t_start_s.size >= MIN_PAUSES
    t = np.asarray(signals["t_s"], float)
    phi = np.where(ok, np.asarray(signals["phi_deg"], float), np.nan)
    dz = np.where(ok, np.asarray(signals["dz_mm"], float), np.nan)
    if estimated and paused:
        offset_s, score = estimate_offset(log, t, phi, dz)
        if not math.isfinite(offset_s):
            raise ValueError(f"{log.source}: cannot estimate the clock offset (too few pauses)")
    elif estimated:
        e = estimate_offset_motion(log, t, [phi, dz], in_contact=phi >= CONTACT_PHI_DEG)
        if not e:
            raise ValueError(f"{log.source}: cannot estimate the clock offset: phi does not "
                             f"follow the stage position (explained share {e.score:.2f}); "
                             f"give it with --offset-s")
        offset_s, score, se = e.offset_s, e.score, e.se_s
    pauses = pause_medians(log, t, phi, dz, ok, offset_s)
    sign = log.travel_sign
    if paused:
        x0 = contact_onset_x(pauses.x_mm, pauses.phi_deg, sign)
    else:
        x0 = contact_onset_x(log.x_at(t - offset_s), phi, sign)
    dx = _travel(pauses.x_mm, x0, sign)
    return RunAnalysis(offset_s=float(offset_s), offset_score=float(score),
                       offset_estimated=estimated, pauses=pauses, x_contact_mm=x0,
                       travel_sign=sign, dx_mm=dx, paused=paused, offset_se_s=float(se))


def _travel(x_mm, x0, sign):
    """Travel since first contact (mm); NaN before contact or without one."""
    x = np.asarray(x_mm, float)
    if not math.isfinite(x0):
        return np.full(x.shape, np.nan)
    dx = sign * (x - x0)
    return np.where(dx > 0, dx, np.nan)


def estimate(calib: Calibration, x_mm, dx_mm, phi_deg, dz_mm, travel_sign,
             segment=None, fusion=None, slip=None) -> dict:
    """GM, MF, both Z scores, fusion and the reconstructed point, vectorised.

    Returns a dict of arrays shape (N,): r_gm_mm, r_mf_mm, mf_outside, mf_past_top,
    sigma_gm_mm, sigma_mf_mm, z_score (eq. 11), z_combined, slipping (1 or 0 where GM is
    defined, :mod:`~camwhisker.contact.slip`; NaN elsewhere), p_gm_good,
    gm_bias_mm, r_fused_mm, r_hat_mm (= r_fused_mm; NaN from the contact's first slip on where
    no MF is in reach to take GM's bias off), x_hat_mm, y_hat_mm (eq. 12 on the whisker
    bent as the GM model and the calibration's bend correction have it) and x_mf_mm,
    y_mf_mm (the same from r_MF; NaN with ``fusion``). Samples of one ``segment`` (contact)
    must be in time order (see :func:`~camwhisker.contact.fusion.fuse`); the fusion also
    parts them where slip starts or stops. ``fusion``, an
    :class:`~camwhisker.contact.fusion.OnlineFusion`, fuses one new sample with the
    earlier ones instead, its slip state from ``slip``, an
    :class:`~camwhisker.contact.slip.OnlineSlip` (live: no later samples).
    """
    phi = np.asarray(phi_deg, float)
    dz = np.asarray(dz_mm, float)
    rg = r_gm(calib.gm, dx_mm, phi)
    mf = r_mf(calib.mf_table, phi, dz)
    sg = calib.gm_spread.sigma_at(phi)
    noise = calib.mf_noise.sigma_at(phi)
    sm = _sigma_mf(calib, phi, mf.dr_ddz, noise)
    z = z_dissimilarity(rg, mf.r_mm, sg)
    zc = z_combined(rg, mf.r_mm, sg, sm)
    if fusion is None:
        sliding = slip_state(slipping(rg, dx_mm, sg, segment), segment) > 0
        slid = slipped(sliding, segment)
    else:
        dx1 = np.atleast_1d(np.asarray(dx_mm, float))
        sliding = np.array([slip(float(rg[0]), float(dx1[0]), float(sg[0])) > 0]
                           if slip is not None else [False])
        slid = np.array([slip is not None and slip.slipped])
    # A slide's line through GM's bias leaves out MF's lower bounds past its table.
    r_mf_fused = np.where(sliding & mf.past_top, np.nan, mf.r_mm)
    if fusion is None:
        fused, p_good, bias = fuse(rg, r_mf_fused, sg, noise, calib.l_w_mm,
                                   slip_segments(sliding, segment), trend=sliding,
                                   floor_mm=calib.mf_bias_floor_mm)
    else:
        fused, p_good, bias = fusion(rg, r_mf_fused, sg, noise, calib.l_w_mm, bool(sliding[0]))
    # From a slip on, GM alone (no MF in its segment to take its bias off) is no estimate.
    fused = np.where(slid & np.isfinite(rg) & ~np.isfinite(p_good), np.nan, fused)
    state = np.where(np.isfinite(rg), sliding, np.nan)
    x_hat, y_hat = reconstruct(x_mm, fused, phi, dz, travel_sign, calib.gm, calib.bend)
    # MF's own point is for tables (percepts weigh it); a live row does not carry it.
    x_mf, y_mf = (reconstruct(x_mm, mf.r_mm, phi, dz, travel_sign, calib.gm, calib.bend)
                  if fusion is None else (np.full(rg.shape, np.nan), np.full(rg.shape, np.nan)))
    return {
        "r_gm_mm": rg, "r_mf_mm": mf.r_mm, "mf_outside": mf.outside, "mf_past_top": mf.past_top,
        "sigma_gm_mm": sg, "sigma_mf_mm": sm, "z_score": z, "z_combined": zc,
        "slipping": state, "p_gm_good": p_good,
        # GM's bias where GM is: elsewhere the fusion's line through its neighbours says nothing.
        "gm_bias_mm": np.where(np.isfinite(rg), bias, np.nan), "r_fused_mm": fused,
        "r_hat_mm": fused, "x_hat_mm": x_hat, "y_hat_mm": y_hat, "x_mf_mm": x_mf,
        "y_mf_mm": y_mf,
    }


def _sigma_mf(calib: Calibration, phi, dr_ddz, noise):
    """sigma_MF at each sample: MF's slope dr/d(dz) there times the pause dz noise, with MF's
    error between calibrated radii (the part of the calibration's sigma_MF(phi) that its
    ``noise``, MF's scatter from noise in that phi bin, leaves); sigma_MF(phi) where
    either is missing. One bin's noise spans a fivefold range of dr/d(dz) over r."""
    spread = calib.mf_spread.sigma_at(phi)
    if calib.dz_noise_mm is None:
        return spread
    between = np.sqrt(np.maximum(spread**2 - noise**2, 0.0))
    here = dr_ddz * calib.dz_noise_mm
    return np.where(np.isfinite(here), np.hypot(here, between), spread)


def pause_estimates(calib: Calibration, run: RunAnalysis) -> dict:
    """:func:`estimate` on the pause medians of a run (the paper's data points)."""
    p = run.pauses
    out = estimate(calib, p.x_mm, run.dx_mm, p.phi_deg, p.dz_mm, run.travel_sign)
    return {"t_s": p.t_start_s, "x_mm": p.x_mm, "dx_mm": run.dx_mm, "phi_deg": p.phi_deg,
            "dz_mm": p.dz_mm, **out}


#: The contact table's columns (docs/sensor.md section 7).
CONTACT_COLUMNS = ("t_s", "x_mm", "dx_mm", "phi_deg", "dz_mm", "r_gm_mm", "r_mf_mm", "z_score",
                   "x_hat_mm", "r_hat_mm")
#: Diagnostics written after the contract's columns.
EXTRA_COLUMNS = ("y_hat_mm", "x_mf_mm", "y_mf_mm", "z_combined", "r_fused_mm", "p_gm_good",
                 "gm_bias_mm", "sigma_gm_mm", "sigma_mf_mm", "mf_outside", "phi_pause_deg",
                 "dz_pause_mm", "r_hat_pause_mm", "pause", "speed_mm_s", "doubt", "ok")
# Estimates that a frame takes from the stage pause it lies in.
_PER_PAUSE = ("r_gm_mm", "r_mf_mm", "z_score", "x_hat_mm", "r_hat_mm", "y_hat_mm", "x_mf_mm",
              "y_mf_mm", "z_combined", "r_fused_mm", "p_gm_good", "gm_bias_mm", "sigma_gm_mm",
              "sigma_mf_mm", "slipping")
#: How the estimates of a row are made: from the frame itself, or from its pause's medians.
MODES = ("frame", "pause")
# Base travel per frame above which a row is "fast": a clock error of one frame
# (the alignment's target) then moves dx by more than 0.2 mm, a fifth of the
# 1 mm steps the calibration is made of. At 30 frames/s: 6 mm/s.
FAST_MM_PER_FRAME = 0.2
# Rows closer than this to the contact onset are "onset": dx is small against the
# onset's own uncertainty (a fifth of a step, tests/test_stage.py), and the
# whisker has not yet settled into a bend that eq. (8) describes.
ONSET_DX_MM = 1.0
# Half-width (s) of the local line through phi and dz behind a frame's estimates:
# about as many frames as the paper's pause medians (1 s at 30 frames/s), over a
# time short enough that the base's starts and stops blur little.
SMOOTH_HALF_S = 0.2


def smooth_half_frames(frame_s: float) -> int:
    """h of the local line behind the per-frame estimates, for a frame period (s)."""
    return int(round(SMOOTH_HALF_S / frame_s)) if frame_s > 0 else 0


def base_speed(log: StageLog, t_stage_s) -> np.ndarray:
    """Base speed (mm/s, >= 0) at stage-clock times: the log's slope there; NaN outside it."""
    t = np.asarray(t_stage_s, float)
    v = np.abs(np.diff(log.x_mm) / np.diff(log.t_s))
    k = np.clip(np.searchsorted(log.t_s, t, side="right") - 1, 0, v.size - 1)
    return np.where((t >= log.t_s[0]) & (t <= log.t_s[-1]), v[k], np.nan)


# "" ... "fast;onset;slip": the flags of doubt() joined by ";", at the code fast + 2 onset + 4 slip.
_DOUBT_TEXT = np.array([";".join(n for b, n in enumerate(("fast", "onset", "slip")) if c >> b & 1)
                        for c in range(8)], dtype=object)


def doubt(speed_mm_s, dx_mm, frame_s: float, slip=None) -> np.ndarray:
    """Why a row's estimate is doubtful: "", or some of "fast", "onset", "slip" joined by ";".

    ``slip`` (1 where :mod:`~camwhisker.contact.slip` finds the contact slipping): GM's
    fixed contact no longer holds there; the fusion takes GM's growing bias off whole.
    """
    fast = np.asarray(speed_mm_s, float) * frame_s > FAST_MM_PER_FRAME
    dx = np.asarray(dx_mm, float)
    onset = np.isfinite(dx) & (dx < ONSET_DX_MM)
    slid = np.zeros(dx.shape, bool) if slip is None else np.asarray(slip) == 1
    # Each row's flags as a 3-bit code into the joined names: one look-up for any row count.
    code = fast.astype(int) + 2 * onset + 4 * slid
    return _DOUBT_TEXT[code] if code.ndim else np.array(_DOUBT_TEXT[code], dtype=object)


def contact_rows(signals: dict, log: StageLog, calib: Calibration,
                 offset_s: float | None = None, mode: str = "frame") -> tuple[dict, RunAnalysis]:
    """One row per signal row (docs/sensor.md section 7) plus extra columns.

    ``x_mm`` is the stage position at the frame time (interpolated in the log
    after clock alignment) and ``dx_mm`` the travel since the contact onset;
    ``phi_deg`` and ``dz_mm`` are the frame's own values. With ``mode``
    "frame" the estimates (r_gm_mm ... r_hat_mm) are the frame's own, moving
    or paused; rows where the quasi-static model is doubtful are kept and
    named in ``doubt``. With "pause" they are those of the stage pause the
    frame lies in, from the pause medians as in the paper ("all data were
    collected during pauses"), and rows while the stage moves are empty.
    Either way ``r_hat_pause_mm`` holds the pause's estimate. Untrusted rows
    and rows outside the log get empty estimate cells.
    """
    if mode not in MODES:
        raise ValueError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
    run = analyse_run(signals, log, offset_s)
    t = np.asarray(signals["t_s"], float)
    x = log.x_at(t - run.offset_s)
    ok = np.asarray(signals["ok"], bool)
    phi = np.where(ok, signals["phi_deg"], np.nan)
    dz = np.where(ok, signals["dz_mm"], np.nan)
    dx = _travel(x, run.x_contact_mm, run.travel_sign)
    pe = pause_estimates(calib, run)
    idx = pause_index(t, detect_pauses(log), run.offset_s, 0.0)
    inside = (idx >= 0) & ok
    k = np.clip(idx, 0, None)
    frame_s = float(np.median(np.diff(t))) if t.size > 1 else 0.0

    def per_frame(values):
        v = np.asarray(values, float)
        return np.where(inside, v[k], np.nan) if v.size else np.full(t.shape, np.nan)

    cols = {"t_s": t, "x_mm": x, "dx_mm": dx, "phi_deg": phi, "dz_mm": dz}
    if mode == "pause":
        for name in _PER_PAUSE:
            cols[name] = per_frame(pe[name])
        mf_out = np.where(inside, np.asarray(pe["mf_outside"], bool)[k], False)
    else:
        h = smooth_half_frames(frame_s)
        own = estimate(calib, x, dx, local_line(phi, h), local_line(dz, h), run.travel_sign)
        for name in _PER_PAUSE:
            cols[name] = np.where(ok & np.isfinite(x), own[name], np.nan)
        mf_out = np.asarray(own["mf_outside"], bool) & ok
    cols["mf_outside"] = mf_out.astype(int)
    cols["phi_pause_deg"] = per_frame(run.pauses.phi_deg)
    cols["dz_pause_mm"] = per_frame(run.pauses.dz_mm)
    cols["r_hat_pause_mm"] = per_frame(pe["r_hat_mm"])
    cols["pause"] = np.where(idx >= 0, idx, np.nan)
    speed = base_speed(log, t - run.offset_s)
    cols["speed_mm_s"] = speed
    cols["doubt"] = doubt(speed, dx, frame_s, cols.pop("slipping"))
    cols["ok"] = ok.astype(int)
    return {name: cols[name] for name in CONTACT_COLUMNS + EXTRA_COLUMNS}, run
