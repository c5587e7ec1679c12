"""Spring calibration against a force log: k_z and k_phi by least squares, with 95 % intervals.

Input: runs, each a signal table (docs/sensor.md section 6) and a force log
(section 7.1) of the same run, such as the paper's test 2 (known dz steps, F_z
read by a force-torque sensor). Per run:

1. **Clock.** The force sensor's clock is offset from the camera's. A given
   offset is used as is; otherwise it is found as the stage log's is
   (:func:`camwhisker.contact.stage.estimate_offset`): a coarse grid then a fine grid,
   scoring each trial offset by the share of the signal's variance that a
   straight line in the force explains (both as :data:`SCORE_BOX_S` box
   means), frames outside the log counting as unexplained (dz against F_z,
   and phi against M_b where the log has it; the shares of the signals that
   span :data:`MIN_SPAN` averaged).
2. **Blocks.** Camera time is cut into blocks of :data:`BLOCK_S`; each block
   gives the mean of its trusted frames' dz and phi and the mean of the force
   samples in it. Both are means over the same interval, so the linear law
   holds between them through steps and ramps alike, while the noise falls by
   the square root of the samples: dz's noise (0.04 mm a frame at the paper's
   level) drops to ~0.01 mm, so the slope's attenuation by noise in dz
   (regression dilution) stays under 0.2 % over a 0-1 mm range. Blocks do not
   overlap, so their errors are independent and ordinary least squares gives
   honest intervals.
3. **Fit.** F_z = k_z dz + b_run (and M_b = k_phi phi + c_run) over the blocks
   of every run: one slope, one intercept per run (each log's own zero). The
   95 % interval is the slope's t interval. A stiffness is fitted only where
   its signal spans :data:`MIN_SPAN` over the blocks (dz for k_z, phi for
   k_phi); otherwise it is left to the spring model, and the result says why.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from camwhisker.contact.stage import DEFAULT_OFFSET_RANGE_S, best_offset
from camwhisker.io.forcelog import ForceLog
from camwhisker.sensor.springs import Stiffness

__all__ = ["SpringCalibrationError", "SpringRun", "StiffnessFit", "SpringCalibration",
           "BLOCK_S", "MIN_SPAN", "estimate_force_offset", "block_means", "calibrate_springs"]

#: Length of the averaging blocks (s): half the paper's shortest pause (>= 1 s),
#: so a pause holds at least one whole block, and 15 frames at 30 frames/s.
BLOCK_S = 0.5
#: A block needs this many trusted frames and force samples to count: three
#: is the fewest whose mean still averages noise at a low frame rate (3 frames/s).
MIN_BLOCK_SAMPLES = 3
#: A stiffness is fitted only where its signal spans this much over the blocks:
#: ten times the paper's per-frame noise (0.04 mm, 0.22 deg), so the slope is
#: set by the load, not by noise.
MIN_SPAN = {"dz_mm": 0.4, "phi_deg": 2.2}
#: Blocks below this are left out of a fit: phi is a magnitude, so near 0 its noise
#: has a positive mean (0.28 deg at the paper's 0.22 deg) and bends the line; 1 deg
#: is 4.5 sd of that noise (the simulator's floor for theta too). dz is signed.
FIT_FLOOR = {"dz_mm": -math.inf, "phi_deg": 1.0}
# The offset's score compares box means over this window (s) of both signal and force:
# the same linear filter on both keeps the law, and takes the per-sample noise down
# (a Nano17's 3.1 mN is a step of 0.06 mm of dz) while steps stay sharp.
SCORE_BOX_S = 0.2
# (signal column, force-log attribute, stiffness name, scale from slope to stiffness):
# k_z in N/mm from mN/mm; k_phi in N mm/rad from N mm/deg.
_PAIRS = (("dz_mm", "fz_mN", "k_z", 1e-3), ("phi_deg", "mb_Nmm", "k_phi", 180.0 / math.pi))


class SpringCalibrationError(ValueError):
    """Input that cannot give a spring calibration; the message names the file."""


@dataclass(frozen=True)
class SpringRun:
    """One run: its signal table (as read), its force log, and a known offset or None."""

    signals: dict
    log: ForceLog
    offset_s: float | None = None


@dataclass(frozen=True)
class StiffnessFit:
    """One fitted stiffness: value, 95 % interval, residual sd (the log's unit), blocks used.

    ``value`` is NaN where the runs do not determine it; ``why`` then says why.
    """

    value: float
    ci95: tuple[float, float]
    residual_sd: float
    blocks: int
    span: float
    why: str = ""

    @property
    def fitted(self) -> bool:
        return math.isfinite(self.value)


@dataclass(frozen=True)
class SpringCalibration:
    """The fits (``k_z``, ``k_phi``), each run's clock, and the stiffness they give.

    ``offsets`` holds per run (offset_s, estimated, score). ``rmse`` holds per
    stiffness the per-frame RMSE of the force from the signal (F_z = k_z dz + b)
    against the log interpolated to the frame, in the log's unit: the paper's
    Fig. 6C number (2 mN for F_z).
    """

    k_z: StiffnessFit
    k_phi: StiffnessFit
    offsets: list
    rmse: dict
    model: Stiffness
    sources: list = field(default_factory=list)

    def stiffness(self, source: str) -> Stiffness:
        """The model's stiffness with the fitted values in place of the model's."""
        kz = self.k_z.value if self.k_z.fitted else self.model.k_z_n_per_mm
        kp = self.k_phi.value if self.k_phi.fitted else self.model.k_phi_nmm_per_rad
        return Stiffness(kz, kp, source, self.k_z.ci95, self.k_phi.ci95)


def _trusted(signals: dict, column: str) -> np.ndarray:
    v = np.asarray(signals[column], float)
    return np.where(np.asarray(signals["ok"], bool) & np.isfinite(v), v, np.nan)


def _box_mean(t, values, centres, half: float) -> np.ndarray:
    """Mean of the finite ``values`` (at sorted times ``t``) within +-half of each centre."""
    finite = np.isfinite(values)
    cum_v = np.r_[0.0, np.cumsum(np.where(finite, values, 0.0))]
    cum_n = np.r_[0, np.cumsum(finite)]
    a = np.searchsorted(t, centres - half, side="left")
    b = np.searchsorted(t, centres + half, side="right")
    n = cum_n[b] - cum_n[a]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, (cum_v[b] - cum_v[a]) / n, np.nan)


def _spread(signal) -> float:
    """The signal's range between its 1st and 99th percentiles (0 without trusted frames)."""
    finite = signal[np.isfinite(signal)]
    return float(np.ptp(np.percentile(finite, [1, 99]))) if finite.size else 0.0


def _explained(signal, force, inside) -> float:
    """Share of the signal's variance a straight line in the force explains; frames
    outside the log count with their full deviation."""
    finite = np.isfinite(signal)
    use = finite & inside
    if use.sum() < 2 * MIN_BLOCK_SAMPLES:
        return 0.0
    s_all = signal[finite]
    total = float(np.sum((s_all - s_all.mean()) ** 2))
    f, s = force[use], signal[use]
    if total <= 0.0 or np.ptp(f) == 0.0:
        return 0.0
    slope, intercept = np.polyfit(f, s, 1)
    outside = float(np.sum((signal[finite & ~inside] - s_all.mean()) ** 2))
    return 1.0 - (float(np.sum((s - slope * f - intercept) ** 2)) + outside) / total


def estimate_force_offset(signals: dict, log: ForceLog,
                          search_s: tuple[float, float] = (-DEFAULT_OFFSET_RANGE_S,
                                                            DEFAULT_OFFSET_RANGE_S)):
    """``offset_s`` (t_camera = t_force + offset_s) from the signals and the force log.

    Returns
    -------
    offset_s : float
    score : float
        The explained share at the estimate, in [0, 1]; near 0 means the log's
        load never moved and the offset is not determined.
    """
    t = np.asarray(signals["t_s"], float)
    pairs = [(_trusted(signals, col), getattr(log, attr), col)
             for col, attr, _, _ in _PAIRS if getattr(log, attr) is not None]
    # Only signals that the load moves: a noise-only pair adds its own noise to the score.
    moved = [(s, f) for s, f, col in pairs if _spread(s) >= MIN_SPAN[col]]
    pairs = moved or [(s, f) for s, f, _ in pairs]

    half = SCORE_BOX_S / 2
    pairs = [(_box_mean(t, s, t, half), f) for s, f in pairs]

    def score(offset):
        tf = t - offset
        inside = (tf - half >= log.t_s[0]) & (tf + half <= log.t_s[-1])
        return float(np.mean([_explained(s, _box_mean(log.t_s, f, tf, half), inside)
                              for s, f in pairs]))

    return best_offset(lambda offsets: np.array([score(o) for o in offsets]), search_s)


def block_means(signals: dict, log: ForceLog, offset_s: float, column: str, attr: str):
    """Per block of :data:`BLOCK_S` (camera clock): mean trusted signal and mean force.

    Returns
    -------
    signal, force : ndarray, shape (B,)
        Only blocks with :data:`MIN_BLOCK_SAMPLES` frames and samples, inside the
        log, whose signal is at least :data:`FIT_FLOOR`.
    """
    t = np.asarray(signals["t_s"], float)
    s = _trusted(signals, column)
    tf = log.t_s + offset_s  # the force samples on the camera clock
    f = getattr(log, attr)
    start = max(t[0], tf[0])
    n = int(math.floor((min(t[-1], tf[-1]) - start) / BLOCK_S))
    if n < 1:
        return np.empty(0), np.empty(0)
    edges = start + BLOCK_S * np.arange(n + 1)
    ks = np.searchsorted(edges, t, side="right") - 1
    kf = np.searchsorted(edges, tf, side="right") - 1
    good = np.isfinite(s) & (ks >= 0) & (ks < n)
    inlog = (kf >= 0) & (kf < n)
    ns = np.bincount(ks[good], minlength=n)
    nf = np.bincount(kf[inlog], minlength=n)
    ss = np.bincount(ks[good], weights=s[good], minlength=n)
    fs = np.bincount(kf[inlog], weights=f[inlog], minlength=n)
    keep = (ns >= MIN_BLOCK_SAMPLES) & (nf >= MIN_BLOCK_SAMPLES)
    mean_s = ss[keep] / ns[keep]
    above = mean_s >= FIT_FLOOR[column]
    return mean_s[above], (fs[keep] / nf[keep])[above]


def _fit(blocks: list[tuple[np.ndarray, np.ndarray]], column: str, scale: float) -> StiffnessFit:
    """One slope, one intercept per run, by least squares; the slope's 95 % t interval."""
    x = np.concatenate([b[0] for b in blocks]) if blocks else np.empty(0)
    y = np.concatenate([b[1] for b in blocks]) if blocks else np.empty(0)
    nan2 = (math.nan, math.nan)
    span = float(np.ptp(x)) if x.size else 0.0
    if span < MIN_SPAN[column]:
        return StiffnessFit(math.nan, nan2, math.nan, int(x.size), span,
                            f"{column} spans {span:.3g} over the blocks, less than "
                            f"{MIN_SPAN[column]:g}: the model value is kept")
    runs = np.repeat(np.arange(len(blocks)), [b[0].size for b in blocks])
    design = np.column_stack([x, np.eye(len(blocks))[runs]])
    dof = x.size - design.shape[1]
    if dof < 1:
        return StiffnessFit(math.nan, nan2, math.nan, int(x.size), span,
                            f"{x.size} blocks for {design.shape[1]} unknowns")
    coef, *_ = np.linalg.lstsq(design, y, rcond=None)
    residual = y - design @ coef
    s2 = float(residual @ residual) / dof
    cov = s2 * np.linalg.inv(design.T @ design)
    half = stats.t.ppf(0.975, dof) * math.sqrt(cov[0, 0])
    k = coef[0] * scale
    return StiffnessFit(float(k), (float(k - half * scale), float(k + half * scale)),
                        math.sqrt(s2), int(x.size), span)


def _frame_rmse(runs, offsets, fits, intercepts) -> dict:
    """Per-frame RMSE of the force from the signal against the log at the frame (log units)."""
    out = {}
    for (col, attr, name, scale), fit in zip(_PAIRS, fits, strict=True):
        res = []
        for run, (offset, _, _), b in zip(runs, offsets, intercepts[name], strict=True):
            f = getattr(run.log, attr)
            if not fit.fitted or f is None or not math.isfinite(b):
                continue
            t = np.asarray(run.signals["t_s"], float) - offset
            s = _trusted(run.signals, col)
            use = np.isfinite(s) & (t >= run.log.t_s[0]) & (t <= run.log.t_s[-1])
            res.append(fit.value / scale * s[use] + b - np.interp(t[use], run.log.t_s, f))
        out[attr] = float(np.sqrt(np.mean(np.concatenate(res) ** 2))) if res else math.nan
    return out


def calibrate_springs(runs: list[SpringRun], model: Stiffness) -> SpringCalibration:
    """Fit k_z (and k_phi where the logs have moments) over the runs; see the module docstring.

    Raises
    ------
    SpringCalibrationError
        No runs, or no block where the signals and the force log of a run overlap.
    """
    if not runs:
        raise SpringCalibrationError("no runs: give a signal table and a force log")
    offsets = []
    for run in runs:
        if run.offset_s is not None:
            offsets.append((float(run.offset_s), False, math.nan))
            continue
        offset, score = estimate_force_offset(run.signals, run.log)
        offsets.append((offset, True, score))
    fits, intercepts = [], {}
    for col, attr, name, scale in _PAIRS:
        blocks = [None if getattr(r.log, attr) is None
                  else block_means(r.signals, r.log, o[0], col, attr)
                  for r, o in zip(runs, offsets, strict=True)]
        if attr == "fz_mN":
            for r, b in zip(runs, blocks, strict=True):
                if b[0].size == 0:
                    raise SpringCalibrationError(
                        f"{r.signals.get('source', '<signals>')}: no {BLOCK_S:g} s block where "
                        f"the signals and {r.log.source} overlap (is the clock offset right?)")
        have = [b for b in blocks if b is not None and b[0].size]
        fit = (_fit(have, col, scale) if any(b is not None for b in blocks) else
               StiffnessFit(math.nan, (math.nan, math.nan), math.nan, 0, 0.0,
                            "no force log has mb_Nmm: the model value is kept"))
        fits.append(fit)
        # Each run's intercept given the common slope: its blocks' mean residual.
        intercepts[name] = [math.nan if b is None or not fit.fitted or b[0].size == 0
                            else float(np.mean(b[1] - fit.value / scale * b[0]))
                            for b in blocks]
    rmse = _frame_rmse(runs, offsets, fits, intercepts)
    sources = [{"signals": str(r.signals.get("source", "<signals>")), "forces": r.log.source}
               for r in runs]
    return SpringCalibration(k_z=fits[0], k_phi=fits[1], offsets=offsets, rmse=rmse,
                             model=model, sources=sources)
