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
  frame): a line through the last h + 1 frames, read at the newest
  (:func:`~camwhisker.contact.smooth.local_line_newest`);
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

Base poses in space (:class:`PoseTrack`, docs/sensor.md section 9) make the one-axis
travel as :func:`camwhisker.contact.space.contact_rows_in_space` does, with the frames
so far: the pressing direction theta is the phi-weighted circular mean of theta over
the trusted rows at phi >= CONTACT_PHI_DEG of the contact so far (:class:`_Pressing`;
the batch command's mean is over the whole run); the travel is the base's position
projected on R0 (cos theta, sin theta, 0) (R0 the first pose's rotation), its
direction re-taken each frame until the onset is fixed and kept from there (before the
session's first contact theta is unknown: x_mm is empty); eq. 12's point is placed in W
by the pose at the frame (:data:`WORLD_FIELDS`). A base that turns gives the travel of
the shaft's point at r instead (:class:`_Turning`).
"""

from __future__ import annotations

import bisect
import math
from collections import deque

import numpy as np

from camwhisker.contact.belief import contact_belief, eta_from_rest, eta_source, next_contact
from camwhisker.contact.fusion import OnlineFusion
from camwhisker.contact.pipeline import Calibration, doubt, estimate, smooth_half_frames
from camwhisker.contact.slip import OnlineSlip
from camwhisker.contact.smooth import local_line_newest
from camwhisker.contact.space import STILL_TURN_DEG, WORLD_COLUMNS
from camwhisker.contact.stage import CONTACT_PHI_DEG, ONSET_PHI_MAX_DEG, contact_onset_x

__all__ = ["MAX_EXTRAPOLATE_S", "ONSET_MAX_FRAMES", "BELIEF_FIELDS",
           "MF_FIELDS", "BASE_FIELDS", "WORLD_FIELDS", "BaseTrack", "BaseFeed", "PoseTrack",
           "OnlineContact"]

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
#: ... and, with base poses, the contact point and the normal's estimate in W (section 9).
WORLD_FIELDS = WORLD_COLUMNS


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
    to a :class:`BaseTrack` or :class:`PoseTrack` once a frame's capture time has reached it."""

    def __init__(self, track):
        self.track = track
        #: (t_s, x_mm or the pose's seven numbers, received_s)
        self.samples: list[tuple] = []
        self._next = 0
        #: Samples the track refused (time not after the previous one's).
        self.out_of_order = 0

    def put(self, t_s: float, value, received_s: float) -> None:
        """A sample: ``value`` is x_mm (a float) or a pose (x, y, z, qw, qx, qy, qz)."""
        value = tuple(map(float, value)) if isinstance(value, (tuple, list)) else float(value)
        self.samples.append((float(t_s), value, float(received_s)))

    def advance(self, t_frame_s: float) -> None:
        """Give the track every sample received at or before ``t_frame_s``."""
        while self._next < len(self.samples) and self.samples[self._next][2] <= t_frame_s:
            t, value, _ = self.samples[self._next]
            self.out_of_order += not self.track.add(t, value)
            self._next += 1


def _quat_matrix(q) -> np.ndarray:
    """Rotation matrix of a unit quaternion (w, x, y, z), scalar first (Hamilton)."""
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _quat_product(a, b) -> np.ndarray:
    """a b (Hamilton, scalar first): the rotation b, then a."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return np.array([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw])


def _slerp(q0: np.ndarray, q1: np.ndarray, u: float) -> np.ndarray:
    dot = float(q0 @ q1)
    if dot < 0:  # the shorter way: q and -q are the same rotation
        q1, dot = -q1, -dot
    if dot > 1 - 1e-12:
        return q0
    a = math.acos(min(dot, 1.0))
    return (math.sin((1 - u) * a) * q0 + math.sin(u * a) * q1) / math.sin(a)


class PoseTrack:
    """The sensor's poses in W received so far, on the camera clock (times strictly
    increasing); each sample a carrier's pose composed with ``mount`` where one is given.

    Parameters
    ----------
    mount : camwhisker.io.poses.Mount, optional
        The pose of S in the carrier's frame, where the samples give the carrier's.
    """

    def __init__(self, mount=None):
        self.t_s: list[float] = []
        self.p_mm: list[np.ndarray] = []
        self.quat: list[np.ndarray] = []
        self._mount = None if mount is None else (np.asarray(mount.position_mm, float),
                                                  np.asarray(mount.quat, float))
        #: The largest angle (deg) between the first pose's orientation and any later one's:
        #: past STILL_TURN_DEG the base turns (:class:`_Turning`).
        self.turn_deg = 0.0

    def add(self, t_s: float, pose) -> bool:
        """Append a pose (x, y, z, qw, qx, qy, qz); False (ignored) where its time is not
        after the last one's. The quaternion is normalised as a pose log's is."""
        if self.t_s and not t_s > self.t_s[-1]:
            return False
        p = np.array(pose[:3], float)
        q = np.array(pose[3:], float)
        q = q / np.linalg.norm(q)
        if self._mount is not None:
            p = p + _quat_matrix(q) @ self._mount[0]
            q = _quat_product(q, self._mount[1])
        self.t_s.append(float(t_s))
        self.p_mm.append(p)
        self.quat.append(q)
        if len(self.quat) == 1:
            #: The first pose's rotation matrix: the travel's frame (as travel_log's).
            self.r0 = _quat_matrix(q)
        cos_half = min(abs(float(q @ self.quat[0])), 1.0)
        self.turn_deg = max(self.turn_deg, math.degrees(2.0 * math.acos(cos_half)))
        return True

    def at(self, t_s: float):
        """(position (3,), rotation matrix (3, 3), velocity (3,) mm/s) at a camera time:
        position linear and rotation by slerp between samples (as PoseLog.at), the velocity
        that segment's; past the newest, the position along the last segment and the last
        rotation (the base keeps its orientation), up to MAX_EXTRAPOLATE_S; else None."""
        t = self.t_s
        if len(t) < 2 or not math.isfinite(t_s) or t_s < t[0] or t_s > t[-1] + MAX_EXTRAPOLATE_S:
            return None
        k = min(bisect.bisect_right(t, t_s), len(t) - 1)  # segment k-1 .. k
        p0, p1 = self.p_mm[k - 1], self.p_mm[k]
        v = (p1 - p0) / (t[k] - t[k - 1])
        if t_s >= t[-1]:
            return p1 + v * (t_s - t[-1]), _quat_matrix(self.quat[-1]), v
        u = (t_s - t[k - 1]) / (t[k] - t[k - 1])
        q = _slerp(self.quat[k - 1], self.quat[k], u)
        return p0 + u * (p1 - p0), _quat_matrix(q), v


class _Pressing:
    """The direction the base pressed in (theta, deg in S): the phi-weighted circular mean
    of theta over the trusted rows at phi >= CONTACT_PHI_DEG of one contact so far."""

    def __init__(self):
        self.s = self.c = 0.0

    def update(self, phi_deg: float, theta_deg: float) -> float:
        if phi_deg >= CONTACT_PHI_DEG and math.isfinite(theta_deg):
            th = math.radians(theta_deg)
            self.s += phi_deg * math.sin(th)
            self.c += phi_deg * math.cos(th)
        return math.degrees(math.atan2(self.s, self.c)) if self.s or self.c else math.nan


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


class _SpaceOnset:
    """The contact onset as :class:`_Onset` does it, from the base's positions in W: they are
    kept and projected on the travel direction of each frame, re-taken with theta, until
    the onset is fixed. Of the frames before contact (the last ONSET_MAX_FRAMES), only the
    least and most travelled along the first contact frame's direction are kept, as
    :class:`_Onset` keeps them (theta moves by a few degrees after: a straight approach
    has the same ends along it)."""

    def __init__(self):
        self.pre: deque[tuple[np.ndarray, float]] = deque(maxlen=ONSET_MAX_FRAMES)
        self._p = np.empty((0, 3))  # before contact, then every frame from phi >= 1 deg
        self._phi = np.empty(0)
        self._n = 0
        self.x0_mm = math.nan
        self.fixed = False
        #: The travel direction in W (unit) the onset was fixed along.
        self.direction: np.ndarray | None = None

    def update(self, p: np.ndarray | None, phi_deg: float, origin, d_w, sign: float) -> float:
        if self.fixed or p is None or not math.isfinite(phi_deg):
            return self.x0_mm
        if not self._n and phi_deg < CONTACT_PHI_DEG:
            self.pre.append((p, phi_deg))
            return self.x0_mm
        if d_w is None:  # no direction yet (theta unknown): nothing to fit along
            return self.x0_mm
        if not self._n:  # the first contact frame: room for the onset's frames to come
            pre = list(self.pre)
            if pre:
                x = [sign * float((q - origin) @ d_w) for q, _ in pre]
                ends = sorted({int(np.argmin(x)), int(np.argmax(x))})
                pre = [pre[j] for j in ends]
            self.pre = deque(pre)
            self._p = np.empty((len(pre) + ONSET_MAX_FRAMES, 3))
            self._phi = np.empty(len(pre) + ONSET_MAX_FRAMES)
            for j, (q, f) in enumerate(pre):
                self._p[j], self._phi[j] = q, f
            self._n = len(pre)
        self._p[self._n], self._phi[self._n] = p, phi_deg
        self._n += 1
        n = self._n
        x = (self._p[:n] - origin) @ d_w
        self.x0_mm = contact_onset_x(x, self._phi[:n], sign)
        self.fixed = phi_deg >= ONSET_PHI_MAX_DEG or n - len(self.pre) >= ONSET_MAX_FRAMES
        if self.fixed:
            self.direction = d_w
        return self.x0_mm


def _direction_s(theta_deg: float) -> np.ndarray:
    th = math.radians(theta_deg)
    return np.array([math.cos(th), math.sin(th), 0.0])


class _Turning:
    """The travel of a turning base's shaft point at r, as the contact command's model
    (:mod:`camwhisker.contact.space`) with the frames so far: d_w(t) . (p(t) - c0), c0 the
    shaft's point at r at the pose where the contact began (the belief's contact state);
    r the running median of MF less dz over the contact (phi >= 2 CONTACT_PHI_DEG; before
    one, the last contact's or l_w / 2)."""

    def __init__(self, r_mm: float):
        self.r_mm = r_mm
        self._r_seen: list[float] = []
        #: Where the contact began: the base's position and its shaft's direction (W).
        self.c0: np.ndarray | None = None

    def note_r(self, r_mf_mm: float, dz_mm: float, phi_deg: float) -> None:
        if phi_deg >= 2.0 * CONTACT_PHI_DEG and math.isfinite(r_mf_mm - dz_mm):
            bisect.insort(self._r_seen, r_mf_mm - dz_mm)
            self.r_mm = self._r_seen[len(self._r_seen) // 2]

    def travel(self, p: np.ndarray, d_w: np.ndarray) -> float:
        return float(d_w @ (p - self.c0[:3] - self.r_mm * self.c0[3:]))


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
    base : BaseTrack or PoseTrack, optional
        The base positions, or its poses in W (the rows then add :data:`WORLD_FIELDS`);
        without it no GM, Z, fusion or contact point.
    """

    def __init__(self, calib: Calibration | None, frame_s: float, eta_deg: float | None = None,
                 base: BaseTrack | PoseTrack | None = None):
        self.calib = calib
        self.base = base
        self.eta_deg = eta_deg
        self.eta_from = "given" if eta_deg is not None else ""
        self.frame_s = float(frame_s)
        self.half_frames = smooth_half_frames(frame_s)
        n = self.half_frames + 1
        self._phi = deque([math.nan] * n, maxlen=n)
        self._dz = deque([math.nan] * n, maxlen=n)
        self._rest: deque[tuple[int, float]] = deque(maxlen=_REST_KEEP)
        self._state = False
        self.space = isinstance(base, PoseTrack)
        #: With poses: the travel direction in W (unit) the rows take while none is fixed.
        self._direction: np.ndarray | None = None
        self._new_contact()
        self._fusion = OnlineFusion(floor_mm=calib.mf_bias_floor_mm) if calib is not None else None

    def _new_contact(self) -> None:
        """A contact ended (or none yet): the next one has its own onset, slip state and
        pressing direction."""
        self._onset = _SpaceOnset() if self.space else _Onset()
        self._pressing = _Pressing()
        self._slip = OnlineSlip()
        last = getattr(self, "_turning", None)
        l_w = self.calib.l_w_mm if self.calib is not None else math.nan
        self._turning = _Turning(last.r_mm if last is not None else 0.5 * l_w)

    def fields(self) -> tuple[str, ...]:
        base = self.calib is not None and self.base is not None
        return (BELIEF_FIELDS + (MF_FIELDS if self.calib is not None else ())
                + (BASE_FIELDS if base else ()) + (WORLD_FIELDS if base and self.space else ()))

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
        how = eta_source(np.array(d), self.eta_deg)
        self.eta_from = f"{how}: frames {first}-{first + used - 1}"

    def _travel(self, t_s: float, phi: float) -> tuple[float, float, float, float]:
        """(x_mm, speed_mm_s, dx_mm, travel sign) at the frame, from base positions."""
        x, speed = self.base.at(t_s)
        sign = self.base.travel_sign
        x0 = self._onset.update(x, phi, sign)
        dx = sign * (x - x0) if math.isfinite(x0) and math.isfinite(x) else math.nan
        return x, speed, (dx if dx > 0 else math.nan), sign

    def _travel_in_space(self, t_s: float, phi: float, theta: float):
        """As :meth:`_travel` from base poses, along the pressing direction (module
        docstring); also the pose at the frame (None) and theta (deg, NaN)."""
        pose = self.base.at(t_s)
        theta_p = self._pressing.update(phi, theta)
        onset = self._onset
        if onset.fixed:
            d_w = onset.direction
        elif math.isfinite(theta_p):
            # Along theta in S as the base was at its first pose (as travel_log does).
            d_w = self._direction = self.base.r0 @ _direction_s(theta_p)
        else:
            d_w = self._direction
        origin = self.base.p_mm[0] if self.base.p_mm else None
        p = None if pose is None else pose[0]
        turning = self.base.turn_deg > STILL_TURN_DEG
        if turning and self._turning.c0 is None and self._state and pose is not None:
            self._turning.c0 = np.concatenate([p, pose[1][:, 2]])  # c0 follows r
        if d_w is None or origin is None:
            onset.update(p, phi, origin, None, 1.0)
            return math.nan, math.nan, math.nan, 1.0, pose, theta_p
        if turning:  # the base presses toward theta: the shaft's point travels along +d_w
            if pose is None or self._turning.c0 is None:
                return math.nan, math.nan, math.nan, 1.0, pose, theta_p
            x = dx = self._turning.travel(p, pose[1] @ (self.base.r0.T @ d_w))
            return x, abs(float(pose[2] @ d_w)), (dx if dx > 0 else math.nan), 1.0, pose, theta_p
        sign = 1.0 if (self.base.p_mm[-1] - origin) @ d_w >= 0 else -1.0
        x0 = onset.update(p, phi, origin, d_w, sign)
        if pose is None:
            return math.nan, math.nan, math.nan, sign, pose, theta_p
        x = float((p - origin) @ d_w)
        dx = sign * (x - x0) if math.isfinite(x0) else math.nan
        return x, abs(float(pose[2] @ d_w)), (dx if dx > 0 else math.nan), sign, pose, theta_p

    def update(self, frame: int, t_s: float, phi_deg: float, dz_mm: float, ok: bool,
               rest: tuple[int, int] | None = None, theta_deg: float = math.nan) -> dict:
        """The fields of :meth:`fields` for one frame (NaN where undefined).

        ``rest``: the session's first rest reference (first frame, frames used) once built;
        ``theta_deg`` the frame's theta (with base poses: the pressing direction).
        """
        phi = float(phi_deg) if ok else math.nan
        dz = float(dz_mm) if ok else math.nan
        out = {}
        self._eta(frame, phi, rest)
        b = math.nan
        if self.eta_deg is not None:
            b = contact_belief(phi, self.eta_deg)  # Eq. (1)
            was = self._state
            self._state = next_contact(self._state, b)
            if was and not self._state:
                self._new_contact()
        out["contact_b"], out["contact"] = b, int(self._state)
        if self.calib is None:
            return out
        self._phi.append(phi)
        self._dz.append(dz)
        phi_s = local_line_newest(self._phi, self.half_frames)
        dz_s = local_line_newest(self._dz, self.half_frames)
        x = speed = dx = theta_p = math.nan
        sign, pose = 1.0, None
        if self.space:
            theta = float(theta_deg) if ok else math.nan
            x, speed, dx, sign, pose, theta_p = self._travel_in_space(t_s, phi, theta)
        elif self.base is not None:
            x, speed, dx, sign = self._travel(t_s, phi)
        e = estimate(self.calib, np.array([x]), np.array([dx]), np.array([phi_s]),
                     np.array([dz_s]), sign, fusion=self._fusion, slip=self._slip)
        if self.space and self.base.turn_deg > STILL_TURN_DEG:
            self._turning.note_r(float(e["r_mf_mm"][0]), dz_s, phi_s)
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
        if self.space:
            out.update(_in_world(pose, theta_p, out["x_hat_mm"] - x, out["y_hat_mm"]))
        return out


def _in_world(pose, theta_deg: float, lateral_mm: float, y_hat_mm: float) -> dict:
    """Eq. 12's point placed in W (as contact_rows_in_space): across the shaft along theta
    by ``lateral_mm``, along it by ``y_hat_mm``; the normal's estimate toward psi."""
    nan = dict.fromkeys(WORLD_FIELDS, math.nan)
    if pose is None or not (math.isfinite(theta_deg) and math.isfinite(lateral_mm)
                            and math.isfinite(y_hat_mm)):  # fmt: skip
        return nan
    p, m, _ = pose
    d_s = _direction_s(theta_deg)
    point = p + m @ (lateral_mm * d_s + np.array([0.0, 0.0, y_hat_mm]))
    normal = m @ -d_s
    return dict(zip(WORLD_FIELDS, [*point.tolist(), *normal.tolist()], strict=True))
