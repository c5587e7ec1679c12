"""Texture from sliding: the gap and amplitude of a surface's ridges from a signal table.

The method of the base-stress / side-strain whisker study (../shared/seeds/003):
the signal is low-passed with a Butterworth filter below the whisker's natural
frequency, found by FFT of its free ringing (:mod:`camwhisker.percept.ringing`);
the gap is the interval between the filtered signal's extrema times the sliding
speed, the amplitude the signal's magnitude. Here the signal is the tip's push
toward the base, u = l_w - (l_w - dz) cos(phi) (mm: a rigid whisker's tip height
below its rest reach; the ridges' height moves it one for one), and its magnitude
is the peak to valley of its periodic waveform: the harmonics of the texture
frequency below the filter's corner, fitted by least squares, each corrected for
the mode's gain.

A recording: at rest (at least :data:`REST_S`), sliding, then let go and
ringing freely (at least :data:`MIN_RING_S`). What it cannot resolve is
reported as a limit, not a number: a texture frequency speed / gap above the
filter's corner (below the mode; and below half the frame rate, the Nyquist
limit) is cut before the extrema are sought, and a ridge height under the
noise leaves no extrema.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from camwhisker.percept.ringing import Ringing, fit_ringing, mode_gain

__all__ = ["TextureError", "TextureEstimate", "tip_push_mm", "estimate_texture", "stage_speed",
           "texture_record",
           "REST_S", "MIN_RING_S"]

# The recording's first REST_S are at rest: the baseline and its noise (as batch's zero).
REST_S = 0.5
# Contact: the tip's push, median-smoothed over SMOOTH_S, CONTACT_SIGMA rest sigmas up.
CONTACT_SIGMA = 8.0
SMOOTH_S = 0.25
MIN_RING_S = 1.0
# The corner sits this far below the natural frequency (4th order, forward-backward:
# the ringing at f_n is 20x down for the default whisker) and below Nyquist.
CUTOFF_RATIO = 0.7
NYQUIST_SHARE = 0.8
BUTTER_ORDER = 4
# An extremum must stand this many sigmas of the filtered noise above its surroundings.
PROMINENCE_SIGMA = 4.0
MIN_INTERVALS = 3
# The waveform: harmonics up to the corner, at most MAX_HARMONICS, each kept where it stands
# HARMONIC_SIGMA standard errors above zero (chosen on seeds 0-2).
MAX_HARMONICS = 8
HARMONIC_SIGMA = 3.0
# The extrema's filter: a corner this many times the texture's periodogram peak.
TIGHT_RATIO = 2.0
# A waveform must stand this many standard errors above zero to be a texture.
MIN_SNR = 5.0
# Extrema intervals more irregular than this are not one texture.
MAX_INTERVAL_CV = 0.25
# The analysis skips this many ringing time constants (and filter settling times, 1 / fc)
# at each end of the contact: the onset's ringing and the filter's edges.
EDGE_TAU = 3.0


class TextureError(ValueError):
    """A signal table or speed the texture estimate cannot use; names the file or key."""


@dataclass
class TextureEstimate:
    """Gap and amplitude (mm, with standard errors), or None where not resolved."""

    resolved: bool
    reason: str
    gap_mm: float | None
    gap_se_mm: float | None
    amplitude_mm: float | None
    amplitude_se_mm: float | None
    limits: dict
    ringing: Ringing
    details: dict = field(default_factory=dict)
    trace: dict = field(default_factory=dict)  # arrays for the plot


def tip_push_mm(dz_mm, phi_deg, length_mm: float):
    """u = l_w - (l_w - dz) cos(phi): how far the tip is pushed toward the base (mm)."""
    return length_mm - (length_mm - np.asarray(dz_mm)) * np.cos(np.radians(phi_deg))


def stage_speed(t_s, x_mm, source: str = "<stage log>"):
    """The stage's sliding speed (mm/s) and its standard error from a log's moving samples."""
    v = np.abs(np.diff(x_mm) / np.diff(t_s))
    moving = v > 0.5 * np.max(v) if v.size else np.zeros(0, bool)
    if moving.sum() < 2:
        raise TextureError(f"{source}: the stage does not move (fewer than 2 moving samples)")
    vm = v[moving]
    return float(np.median(vm)), float(np.std(vm) / math.sqrt(vm.size))


def _filled(signals: dict, source: str):
    """Rows' time and tip push inputs with untrusted rows filled linearly from their neighbours."""
    t = signals["t_s"]
    good = signals["ok"] & np.isfinite(signals["dz_mm"]) & np.isfinite(signals["phi_deg"])
    if good.sum() < 0.5 * t.size or good.sum() < 16:
        raise TextureError(f"{source}: only {int(good.sum())} of {t.size} rows are ok")
    dz = np.interp(t, t[good], signals["dz_mm"][good])
    phi = np.interp(t, t[good], signals["phi_deg"][good])
    return t, dz, phi, int(t.size - good.sum())


def _segments(t, u, fps: float, source: str):
    """Rest sigma, contact rows [i0, i1) (the longest run above the rest) and ringing start."""
    from scipy.ndimage import median_filter

    rest = t < t[0] + REST_S
    if rest.sum() < 5:
        raise TextureError(f"{source}: needs {REST_S:g} s at rest first (5 rows at least)")
    base, sigma = float(np.median(u[rest])), float(np.std(u[rest]))
    window = max(3, int(round(SMOOTH_S * fps)) | 1)
    up = median_filter(u - base, size=window, mode="nearest") > CONTACT_SIGMA * max(sigma, 1e-6)
    edges = np.flatnonzero(np.diff(np.r_[0, up.astype(int), 0]))
    if edges.size == 0:
        raise TextureError(f"{source}: no contact: the tip's push never rises "
                           f"{CONTACT_SIGMA:g} rest sigmas ({sigma:.3g} mm) above the rest")
    starts, ends = edges[::2], edges[1::2]
    k = int(np.argmax(ends - starts))
    i0, i1 = int(starts[k]), int(ends[k])
    ring0 = min(i1 + window, t.size)
    if t[-1] - t[ring0 - 1] < MIN_RING_S:
        raise TextureError(f"{source}: the recording ends {t[-1] - t[i1 - 1]:.2f} s after the "
                           f"contact; it needs {MIN_RING_S:g} s of free ringing after it")
    return sigma, i0, i1, ring0


def _extrema_times(t, y, prominence: float):
    """Maxima and minima standing out by ``prominence``, refined between frames by a parabola:
    for each, the times, frame indices and curvatures (y[i-1] - 2 y[i] + y[i+1])."""
    from scipy.signal import find_peaks

    out = []
    for sign in (1.0, -1.0):
        idx, _ = find_peaks(sign * y, prominence=prominence)
        idx = idx[(idx > 0) & (idx < y.size - 1)]
        a, b, c = y[idx - 1], y[idx], y[idx + 1]
        den = a - 2 * b + c
        shift = np.where(den != 0, 0.5 * (a - c) / np.where(den != 0, den, 1.0), 0.0)
        out.append((t[idx] + np.clip(shift, -0.5, 0.5) * (t[1] - t[0]), idx, den))
    return out


def _noise_acf(corners, fps: float, n: int):
    """Autocovariance at lags 0..n-1 frames of unit white noise through the low-passes at
    ``corners`` in turn (each forward and backward)."""
    from scipy.signal import butter, sosfreqz

    nfft = 2 ** int(math.ceil(math.log2(2 * n + 8)))  # no wrap-around within n lags
    freqs = np.fft.rfftfreq(nfft, 1.0 / fps)
    passed = np.ones(freqs.size)
    for corner in corners:
        sos = butter(BUTTER_ORDER, corner, fs=fps, output="sos")
        passed *= np.abs(sosfreqz(sos, worN=freqs, fs=fps)[1]) ** 4  # |B|^2, twice
    return np.fft.irfft(passed, nfft)[:n]


def _timing_cov(idx, curvature, acf, dt: float):
    """Covariance, per unit noise variance, of parabola-refined extremum times: each moves by
    dt (n[i-1] - n[i+1]) / (2 curvature) with n the filtered noise, correlated between extrema.
    A flat extremum (zero curvature) has no such model: then the times count as independent
    (the identity), which gives the plain least-squares SE."""
    if np.any(curvature == 0):
        return np.eye(idx.size)
    d = np.abs(idx[:, None] - idx[None, :])

    def r(lag):
        return acf[np.minimum(lag, acf.size - 1)]

    diff_cov = 2.0 * r(d) - r(d + 2) - r(np.abs(d - 2))
    return dt * dt * diff_cov / (4.0 * np.outer(curvature, curvature))


def _period(maxima, minima, timing_cov):
    """Common period (s) and its standard error from extrema times t_k = t0 + k T (LS), the
    noise sigma the residuals imply, and the intervals' spread.

    ``timing_cov``: the times' covariance per unit noise variance (maxima, then minima).
    """
    diffs = np.r_[np.diff(maxima), np.diff(minima)]
    t_med = float(np.median(diffs))
    rows, times = [], []
    for j, ts in enumerate((maxima, minima)):
        k = np.round((ts - ts[0]) / t_med)
        for kk, tt in zip(k, ts, strict=True):
            rows.append([kk, 1.0 - j, float(j)])
            times.append(tt)
    a, y = np.array(rows), np.array(times)
    coef, *_ = np.linalg.lstsq(a, y, rcond=None)
    res = y - a @ coef
    # The filtered noise moves neighbouring extrema together (or apart): the LS estimate's
    # sandwich covariance with that correlation, scaled by the residuals it predicts.
    proj = np.linalg.solve(a.T @ a, a.T)
    resid_share = float(np.trace(timing_cov) - np.trace(a @ proj @ timing_cov))
    noise_var = float(res @ res) / max(resid_share, 1e-300)
    cov = noise_var * proj @ timing_cov @ proj.T
    cv = float(np.std(diffs) / np.mean(diffs))
    return float(coef[0]), float(math.sqrt(cov[0, 0])), math.sqrt(noise_var), cv


def _harmonics(t, u, f_hz, cutoff_hz, ringing: Ringing):
    """Peak to valley (mm) of the periodic waveform at f_hz and its standard error.

    Least squares of the harmonics k f_hz up to the corner (at least the fundamental),
    an offset and a linear trend on the unfiltered signal, each harmonic divided by the
    mode's gain there and the overtones weighted by the seed's filter, the waveform
    rebuilt over one period. The error: the residual's scatter through the fit's
    covariance at the waveform's peak and valley.
    """
    n_harm = int(min(max(1, cutoff_hz // f_hz), MAX_HARMONICS))
    tt = t - t.mean()
    k = np.arange(1, n_harm + 1)
    cols = [np.cos(2 * math.pi * kk * f_hz * tt) for kk in k]
    cols += [np.sin(2 * math.pi * kk * f_hz * tt) for kk in k]
    a = np.column_stack([*cols, np.ones_like(tt), tt])
    coef, *_ = np.linalg.lstsq(a, u, rcond=None)
    res = u - a @ coef
    cov = np.linalg.inv(a.T @ a) * float(res @ res) / max(u.size - a.shape[1], 1)
    # Harmonics within the noise only add to the peak to valley: left out (the fundamental kept).
    se = np.sqrt(np.diag(cov)[: 2 * n_harm])
    size = np.hypot(coef[:n_harm], coef[n_harm: 2 * n_harm])
    noise = np.hypot(se[:n_harm], se[n_harm:])
    keep = np.tile((size > HARMONIC_SIGMA * noise) | (k == 1), 2)
    coef = np.where(keep, coef[: 2 * n_harm], 0.0)
    # Each harmonic through the mode's inverse; the overtones also through the seed's filter
    # (|B|^2, forward and backward): a truncated series overshoots at a steep flank.
    taper = np.where(k == 1, 1.0, 1.0 + (k * f_hz / cutoff_hz) ** (2 * BUTTER_ORDER))
    gain = np.tile(mode_gain(k * f_hz, ringing) * taper, 2)
    phase = np.linspace(0.0, 1.0 / f_hz, 512, endpoint=False)
    basis = np.column_stack([np.cos(2 * math.pi * kk * f_hz * phase) for kk in k]
                            + [np.sin(2 * math.pi * kk * f_hz * phase) for kk in k]) / gain
    wave = basis @ coef
    hi, lo = int(np.argmax(wave)), int(np.argmin(wave))
    g = np.where(keep, basis[hi] - basis[lo], 0.0)
    se_pv = math.sqrt(float(g @ cov[: 2 * n_harm, : 2 * n_harm] @ g))
    return float(wave[hi] - wave[lo]), se_pv, int(keep[:n_harm].sum())


def _limits(speed, fps, cutoff_hz, sigma_f, ringing):
    """The finest gap (the corner's: the mode's, or Nyquist's where it holds the corner down)
    and the smallest amplitude the extrema can show."""
    mode_corner = CUTOFF_RATIO * ringing.natural_hz
    return {"gap_min_mm": speed / cutoff_hz, "nyquist_gap_min_mm": 2.0 * speed / fps,
            "mode_gap_min_mm": speed / mode_corner,
            "binding": "nyquist" if cutoff_hz < mode_corner else "mode",
            "amplitude_min_mm": PROMINENCE_SIGMA * sigma_f, "cutoff_hz": cutoff_hz,
            "natural_hz": ringing.natural_hz}


def _lowpass(u, corner: float, fps: float):
    """A Butterworth low-pass, forward and backward (no delay)."""
    from scipy.signal import butter, sosfiltfilt

    return sosfiltfilt(butter(BUTTER_ORDER, corner, fs=fps, output="sos"), u)


def _noise_share(corners, fps: float) -> float:
    """The share of white noise's sigma that passes the low-passes at ``corners`` in turn."""
    from scipy.signal import butter, sosfreqz

    passed = np.ones(4096)
    for corner in corners:
        sos = butter(BUTTER_ORDER, corner, fs=fps, output="sos")
        passed *= np.abs(sosfreqz(sos, worN=4096, fs=fps)[1]) ** 4  # |B|^2, twice
    return math.sqrt(float(np.mean(passed)))


def _texture_peak_hz(t, y, fps: float, corner: float) -> float:
    """The periodogram's peak (Hann, zero-padded) between two cycles per window and the corner."""
    from scipy.signal import periodogram

    f, p = periodogram(y, fs=fps, window="hann", nfft=8 * y.size, detrend="linear")
    band = (f >= 2.0 / (t[-1] - t[0])) & (f <= corner)
    return float(f[band][np.argmax(p[band])]) if band.any() else corner


def _prepare(signals, speed_mm_s, length_mm, speed_se_mm_s):
    """Tip push, contact, ringing, the corner below the mode, limits and the analysed stretch."""
    source = signals.get("source", "<signals>")
    if not (speed_mm_s > 0 and math.isfinite(speed_mm_s)):
        raise TextureError(f"speed_mm_s must be positive, got {speed_mm_s:g}")
    t, dz, phi, filled = _filled(signals, source)
    fps = 1.0 / float(np.median(np.diff(t)))
    u = tip_push_mm(dz, phi, length_mm)
    sigma, i0, i1, ring0 = _segments(t, u, fps, source)
    ringing = fit_ringing(t[ring0:], u[ring0:], source)
    cutoff = min(CUTOFF_RATIO * ringing.natural_hz, NYQUIST_SHARE * 0.5 * fps)
    y = _lowpass(u, cutoff, fps)
    sigma_f = sigma * _noise_share([cutoff], fps)
    limits = _limits(speed_mm_s, fps, cutoff, sigma_f, ringing)
    tau = 1.0 / (2 * math.pi * ringing.natural_hz * max(ringing.damping, 1e-3))
    edge = EDGE_TAU * max(tau, 1.0 / cutoff)
    win = (t >= t[i0] + edge) & (t <= t[i1 - 1] - edge)
    details = {"fps": fps, "speed_mm_s": speed_mm_s, "speed_se_mm_s": speed_se_mm_s,
               "rows_filled": filled, "rest_sigma_mm": sigma, "filtered_sigma_mm": sigma_f,
               "contact_s": [float(t[i0]), float(t[i1 - 1])], "ring_from_s": float(t[ring0]),
               "damping": ringing.damping, "damping_se": ringing.damping_se,
               "natural_se_hz": ringing.natural_se_hz, "edge_s": edge}
    trace = {"t_s": t, "u_mm": u, "filtered_mm": y, "window": win, "ring0": ring0}
    return ringing, limits, details, trace


def estimate_texture(signals: dict, speed_mm_s: float, length_mm: float,
                     speed_se_mm_s: float = 0.0) -> TextureEstimate:
    """Gap and amplitude of the texture slid over in ``signals`` (a read signal table).

    The seed's filter (corner :data:`CUTOFF_RATIO` of the natural frequency) first; then,
    for the extrema, a second corner at :data:`TIGHT_RATIO` times the periodogram's peak
    (a slow texture keeps less noise).

    Raises
    ------
    TextureError
        A speed <= 0, too few ok rows, no rest at the start, no contact, no free ringing.
    """
    ringing, limits, details, trace = _prepare(signals, speed_mm_s, length_mm, speed_se_mm_s)
    t, u, y, win = trace["t_s"], trace["u_mm"], trace["filtered_mm"], trace["window"]
    fps, cutoff = details["fps"], limits["cutoff_hz"]

    def unresolved(why):
        return TextureEstimate(False, why, None, None, None, None, limits, ringing, details, trace)

    if win.sum() < 8:
        return unresolved(f"the contact ({np.ptp(details['contact_s']):.2f} s) is too short: "
                          f"{2 * details['edge_s']:.2f} s go to its edges")
    tw = t[win]
    yw = y[win] - np.polyval(np.polyfit(tw, y[win], 1), tw)
    tight = TIGHT_RATIO * _texture_peak_hz(tw, yw, fps, cutoff)
    sigma_t = details["filtered_sigma_mm"]
    if tight < cutoff:  # else the seed's filter is as tight as it gets
        yw = _lowpass(yw, tight, fps)
        sigma_t = details["rest_sigma_mm"] * _noise_share([cutoff, tight], fps)
    corners = [cutoff, tight] if tight < cutoff else [cutoff]
    extrema = _extrema_times(tw, yw, PROMINENCE_SIGMA * sigma_t)
    (maxima, i_max, c_max), (minima, i_min, c_min) = extrema
    details.update(n_maxima=int(maxima.size), n_minima=int(minima.size),
                   tight_hz=min(tight, cutoff), window_s=[float(tw[0]), float(tw[-1])])
    trace.update(maxima=maxima, minima=minima)
    beyond = (f"finer than {limits['gap_min_mm']:.3g} mm at {speed_mm_s:g} mm/s (the whisker's "
              f"mode at {ringing.natural_hz:.2f} Hz: corner {cutoff:.2f} Hz; Nyquist at "
              f"{fps:.4g} frames/s: {limits['nyquist_gap_min_mm']:.3g} mm) or lower than "
              f"{limits['amplitude_min_mm']:.3g} mm")
    if min(maxima.size, minima.size) < MIN_INTERVALS + 1:
        return unresolved(f"no periodic ridges above the noise: the texture is {beyond}")
    timing_cov = _timing_cov(np.r_[i_max, i_min], np.r_[c_max, c_min],
                             _noise_acf(corners, fps, tw.size + 3), 1.0 / fps)
    period, period_se, timing_sigma, cv = _period(maxima, minima, timing_cov)
    f_tex = 1.0 / period
    details.update(interval_cv=cv, texture_hz=f_tex, timing_noise_mm=timing_sigma)
    if cv > MAX_INTERVAL_CV or f_tex > cutoff:
        return unresolved(f"the extrema are not one texture (interval spread {cv:.0%}): the "
                          f"texture is {beyond}")
    amplitude, se_fit, n_harm = _harmonics(tw, u[win], f_tex, cutoff, ringing)
    details.update(harmonics=n_harm, amplitude_snr=amplitude / se_fit)
    if amplitude < MIN_SNR * se_fit:
        return unresolved(f"the ridges' waveform is within the noise ({amplitude:.3g} +- "
                          f"{se_fit:.2g} mm): the texture is {beyond}")
    # The mode's gain through the fitted frequency and damping, one standard error off.
    shifted = Ringing(ringing.natural_hz + ringing.natural_se_hz, 0.0,
                      ringing.damping + ringing.damping_se, 0.0)
    se_mode = amplitude * abs(float(mode_gain(f_tex, shifted) / mode_gain(f_tex, ringing)) - 1.0)
    gap_se = math.hypot(speed_mm_s * period_se, speed_se_mm_s * period)
    return TextureEstimate(True, "resolved", speed_mm_s * period, gap_se, amplitude,
                           math.hypot(se_fit, se_mode), limits, ringing, details, trace)


def texture_record(est: TextureEstimate) -> dict:
    """The estimate as plain JSON fields: null where not resolved, the limits always."""
    return {"resolved": est.resolved, "reason": est.reason, "gap_mm": est.gap_mm,
            "gap_se_mm": est.gap_se_mm, "amplitude_mm": est.amplitude_mm,
            "amplitude_se_mm": est.amplitude_se_mm, "limits": est.limits,
            "natural_hz": est.ringing.natural_hz, "natural_se_hz": est.ringing.natural_se_hz,
            "details": est.details}
