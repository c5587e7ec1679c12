"""Contact frame by frame as the frames come (live, replay): no later frame is seen.

The contact command's per-frame rows (:func:`camwhisker.contact.pipeline.contact_rows`,
mode "frame") are made from a whole run. :class:`OnlineContact` makes each row
from its frame and the earlier ones, with the same functions:

- belief: eq. 1 (:func:`~camwhisker.contact.belief.contact_belief`) with eta from
  the rest frames of the session's first rest reference
  (:func:`~camwhisker.contact.belief.eta_from_rest`, as the belief command takes
  it from the table's sidecar), and the contact state of
  :func:`~camwhisker.contact.belief.next_contact`; rows before that reference is
  built (the rest frames themselves) have no belief;
- phi and dz smoothed by :func:`~camwhisker.contact.smooth.local_line` over the
  same window with the later frames missing (what batch does at a run's last
  frame): a line through the last h + 1 frames, read at the newest;
- the contact onset by :func:`~camwhisker.contact.stage.contact_onset_x` over the frames
  so far, fixed once phi passes ``ONSET_PHI_MAX_DEG`` (batch uses no frame past
  that either), and found again for each new contact (where the belief's contact
  ends: batch takes one per run);
- GM, MF, Z, fusion and eq. 12 by :func:`~camwhisker.contact.pipeline.estimate`
  with :class:`~camwhisker.contact.fusion.OnlineFusion` (the forward half of
  batch's two-sided bias estimate) and :class:`~camwhisker.contact.slip.OnlineSlip`
  (batch's slip test over the contact's samples so far; new for each contact);
- ``doubt`` by :func:`~camwhisker.contact.pipeline.doubt`.

Base positions (:class:`BaseTrack`, camera clock) are interpolated to the frame
time as :meth:`camwhisker.contact.stage.StageLog.x_at` does; past the newest sample
(the usual case live: the frame is newer than the last position received) they
are extrapolated along the last segment, up to :data:`MAX_EXTRAPOLATE_S`.
:class:`BaseFeed` hands a frame the samples received by its capture time, so a
replay of the logged samples gives the live rows again.
"""

from __future__ import annotations

import bisect
import math
from collections import deque

import numpy as np

from camwhisker.contact.belief import (
    ETA_FACTOR,
    ETA_QUANTILE,
    contact_belief,
    eta_from_rest,
    next_contact,
)
from camwhisker.contact.fusion import OnlineFusion
from camwhisker.contact.pipeline import Calibration, doubt, estimate, smooth_half_frames
from camwhisker.contact.slip import OnlineSlip
from camwhisker.contact.smooth import local_line
from camwhisker.contact.stage import CONTACT_PHI_DEG, ONSET_PHI_MAX_DEG, contact_onset_x

__all__ = ["MAX_EXTRAPOLATE_S", "ONSET_MAX_FRAMES", "BELIEF_FIELDS", "MF_FIELDS", "BASE_FIELDS",
           "BaseTrack", "BaseFeed", "OnlineContact"]

#: Longest time past the newest base position that x is extrapolated: 5 periods of a
#: 20 Hz stage; a base silent for longer has stopped sending or is lost, so no x.
MAX_EXTRAPOLATE_S = 0.25
#: Frames the onset fit holds at most: its cost grows with them, and 10 s at 30 frames/s
#: is far more than phi's rise from 1 to 5 deg at a sweep's base speeds (~1 s).
ONSET_MAX_FRAMES = 300
#: How many rest frames are kept for eta while the first rest reference is built
#: (it averages at most 30: options.rest_frames).
_REST_KEEP = 256

#: Per-frame fields, in the order of the row: the belief (docs/sensor.md section 6.2) ...
BELIEF_FIELDS = ("contact_b", "contact")
#: ... MF's estimate and its spread (with a calibration) ...
MF_FIELDS = ("r_mf_mm", "sigma_mf_mm")
#: ... and, with the base position, the contact table's (docs/sensor.md section 7).
BASE_FIELDS = ("x_mm", "dx_mm", "r_gm_mm", "sigma_gm_mm", "z_score", "z_combined", "p_gm_good",
               "r_fused_mm", "r_hat_mm", "x_hat_mm", "y_hat_mm", "speed_mm_s", "doubt")


class BaseTrack:
    """The base positions received so far, on the camera clock (times strictly increasing)."""

    def __init__(self):
        self.t_s: list[float] = []
        self.x_mm: list[float] = []

    def add(self, t_s: float, x_mm: float) -> bool:
        """Append a sample; False (ignored) where its time is not after the last one's."""
        if self.t_s and not t_s > self.t_s[-1]:
            return False
        self.t_s.append(float(t_s))
        self.x_mm.append(float(x_mm))
        return True

    @property
    def travel_sign(self) -> float:
        """As :attr:`camwhisker.contact.stage.StageLog.travel_sign`, over the samples so far."""
        return 1.0 if not self.x_mm or self.x_mm[-1] >= self.x_mm[0] else -1.0

    def at(self, t_s: float) -> tuple[float, float]:
        """(x_mm, speed_mm_s) at a camera time: interpolated between samples (as
        StageLog.x_at) and the speed of that segment (as pipeline.base_speed); past the
        newest sample, along the last segment up to MAX_EXTRAPOLATE_S; else NaN."""
        t, x = self.t_s, self.x_mm
        if len(t) < 2 or not math.isfinite(t_s) or t_s < t[0]:
            return math.nan, math.nan
        k = min(bisect.bisect_right(t, t_s), len(t) - 1)  # segment k-1 .. k
        if t_s > t[-1] + MAX_EXTRAPOLATE_S:
            return math.nan, math.nan
        slope = (x[k] - x[k - 1]) / (t[k] - t[k - 1])
        if t_s > t[-1]:
            return x[-1] + slope * (t_s - t[-1]), abs(slope)
        return float(np.interp(t_s, t[k - 1:k + 1], x[k - 1:k + 1])), abs(slope)


class BaseFeed:
    """Base samples in the order received, each with its receive time (camera clock), handed
    to a :class:`BaseTrack` once a frame's capture time has reached it."""

    def __init__(self, track: BaseTrack):
        self.track = track
        self.samples: list[tuple[float, float, float]] = []  # (t_s, x_mm, received_s)
        self._next = 0
        #: Samples the track refused (time not after the previous one's).
        self.out_of_order = 0

    def put(self, t_s: float, x_mm: float, received_s: float) -> None:
        self.samples.append((float(t_s), float(x_mm), float(received_s)))

    def advance(self, t_frame_s: float) -> None:
        """Give the track every sample received at or before ``t_frame_s``."""
        while self._next < len(self.samples) and self.samples[self._next][2] <= t_frame_s:
            t, x, _ = self.samples[self._next]
            self.out_of_order += not self.track.add(t, x)
            self._next += 1


class _Onset:
    """The contact onset (base position) from the frames so far (module docstring)."""

    def __init__(self):
        self.pre: list[tuple[float, float]] = []  # the least and most travelled frames before
        self.post: list[tuple[float, float]] = []  # every frame from the first phi >= 1 deg
        self.x0_mm = math.nan
        self.fixed = False

    def update(self, x_mm: float, phi_deg: float, sign: float) -> float:
        if self.fixed or not (math.isfinite(x_mm) and math.isfinite(phi_deg)):
            return self.x0_mm
        if not self.post and phi_deg < CONTACT_PHI_DEG:
            # Before contact only the ends of the travel enter contact_onset_x (the
            # clip's bound and the frame just before the first hit): keep those two.
            pts = self.pre + [(x_mm, phi_deg)]
            lo = min(pts, key=lambda p: sign * p[0])
            hi = max(pts, key=lambda p: sign * p[0])
            self.pre = [lo] if lo is hi else [lo, hi]
            return self.x0_mm
        self.post.append((x_mm, phi_deg))
        pts = self.pre + self.post
        self.x0_mm = contact_onset_x([p[0] for p in pts], [p[1] for p in pts], sign)
        self.fixed = phi_deg >= ONSET_PHI_MAX_DEG or len(self.post) >= ONSET_MAX_FRAMES
        return self.x0_mm


class OnlineContact:
    """Contact per frame from that frame and the earlier ones (module docstring).

    Parameters
    ----------
    calib : Calibration, optional
        Without it only the belief is given.
    frame_s : float
        The camera's frame period (s): sets the smoothing window as batch does.
    eta_deg : float, optional
        eta as given; default from the first rest reference's frames.
    base : BaseTrack, optional
        The base positions; without it no GM, Z, fusion or contact point.
    """

    def __init__(self, calib: Calibration | None, frame_s: float, eta_deg: float | None = None,
                 base: BaseTrack | None = None):
        self.calib = calib
        self.base = base
        self.eta_deg = eta_deg
        self.eta_from = "given" if eta_deg is not None else ""
        self.frame_s = float(frame_s)
        self.half_frames = smooth_half_frames(frame_s)
        n = self.half_frames + 1
        self._phi = deque([math.nan] * n, maxlen=n)
        self._dz = deque([math.nan] * n, maxlen=n)
        self._future = [math.nan] * self.half_frames  # later frames: missing
        self._rest: deque[tuple[int, float]] = deque(maxlen=_REST_KEEP)
        self._state = False
        self._onset = _Onset()
        self._fusion = OnlineFusion(floor_mm=calib.mf_bias_floor_mm) if calib is not None else None
        self._slip = OnlineSlip()

    def fields(self) -> tuple[str, ...]:
        return (BELIEF_FIELDS + (MF_FIELDS if self.calib is not None else ())
                + (BASE_FIELDS if self.calib is not None and self.base is not None else ()))

    def _eta(self, frame: int, phi: float, rest: tuple[int, int] | None) -> None:
        """Keep rest frames' phi until the first rest reference (first frame, frames
        used) is known, then eta from them; with too few, no eta, and ``eta_from`` says why."""
        if self.eta_deg is not None or self.eta_from:
            return
        self._rest.append((frame, phi))
        if rest is None:
            return
        first, used = rest
        d = [p for f, p in self._rest if first <= f < first + used]
        self._rest.clear()
        try:
            self.eta_deg = eta_from_rest(np.array(d))
        except ValueError as exc:  # the session goes on without a belief, and says why
            self.eta_from = f"none: rest frames {first}-{first + used - 1}: {exc}"
            return
        self.eta_from = (f"{ETA_FACTOR:g} x the {ETA_QUANTILE:g} quantile of phi_deg over "
                         f"rest frames {first}-{first + used - 1}")

    def update(self, frame: int, t_s: float, phi_deg: float, dz_mm: float, ok: bool,
               rest: tuple[int, int] | None = None) -> dict:
        """The fields of :meth:`fields` for one frame (NaN where undefined).

        ``rest``: the session's first rest reference (first frame, frames used) once built.
        """
        phi = float(phi_deg) if ok else math.nan
        dz = float(dz_mm) if ok else math.nan
        out = {}
        self._eta(frame, phi, rest)
        b = math.nan
        if self.eta_deg is not None:
            b = float(contact_belief(np.array([phi]), self.eta_deg)[0])  # Eq. (1)
            was = self._state
            self._state = next_contact(self._state, b)
            if was and not self._state:
                self._onset = _Onset()  # a contact ended: the next one has its own onset
                self._slip = OnlineSlip()
        out["contact_b"], out["contact"] = b, int(self._state)
        if self.calib is None:
            return out
        self._phi.append(phi)
        self._dz.append(dz)
        h = self.half_frames
        phi_s = local_line(list(self._phi) + self._future, h)[h]
        dz_s = local_line(list(self._dz) + self._future, h)[h]
        x = speed = dx = math.nan
        sign = 1.0
        if self.base is not None:
            x, speed = self.base.at(t_s)
            sign = self.base.travel_sign
            x0 = self._onset.update(x, phi, sign)
            if math.isfinite(x0) and math.isfinite(x) and sign * (x - x0) > 0:
                dx = sign * (x - x0)
        e = estimate(self.calib, np.array([x]), np.array([dx]), np.array([phi_s]),
                     np.array([dz_s]), sign, fusion=self._fusion, slip=self._slip)
        use = ok and math.isfinite(x)
        out["r_mf_mm"] = float(e["r_mf_mm"][0]) if ok else math.nan
        out["sigma_mf_mm"] = float(e["sigma_mf_mm"][0]) if ok else math.nan
        if self.base is None:
            return out
        out["x_mm"], out["dx_mm"] = x, dx
        for name in BASE_FIELDS[2:-2]:
            out[name] = float(e[name][0]) if use else math.nan
        out["speed_mm_s"] = speed
        out["doubt"] = str(doubt([speed], [dx], self.frame_s, e["slipping"])[0])
        return out
