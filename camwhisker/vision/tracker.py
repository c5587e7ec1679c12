"""The front end: frames in, plate pose out. A tracker object and a generator.

:class:`FrontEnd` holds the state. :meth:`FrontEnd.start` takes the rest
frame: it white-balances it, detects every feature (no clicking; the user's
rough positions, ``FrontEndOptions.features``, where detection needs them) and builds
the :class:`~camwhisker.vision.rest.RestReference` (the rest patches, the
first templates, and the rest offsets of the points against the model).
:meth:`FrontEnd.update` then runs, per frame, the steps named in it:

1. look: white balance from the cloth (or the locked rest gains);
2. predict: the last pose, and the last pose moved on at the last velocity;
3. tip: the tip segmented near where the predictions put it, a coarse search
   of its whole reach if not there (straight away when no pixel near either
   prediction is dark enough to be the face: a jump); its centroid from its
   edge and the model's rim (moved to where the rest frame's blur shows the
   edge, :func:`~camwhisker.vision.tip.blurred_rim`); a first tilt guess from
   the tip alone (after a jump, from the dark blob's centroid: the rim waits
   for the corners' fit);
4. corners: drift correction of the square's and the cross's corners against
   their rest patches, warped by the model's rest-to-current affine map and
   given back the blur the warp took away (:mod:`~camwhisker.vision.blur`), from
   where that guess puts them (:func:`~camwhisker.vision.lk.refine_first_template`),
   on linear colour-share maps; corners the rod or the cross covers are left
   out. After a big jump, the recoveries: other depths tried, the features
   detected afresh, the missing corners predicted again from a fit to the
   locked ones;
5. fit: the pose fit through the exact camera model
   (:func:`~camwhisker.vision.pose.fit_pose`; after a jump, of the corners
   alone, then with the tip measured with the rim placed at that fit);
6. refine: the tip measured again with the model's rim at the fitted pose
   while the fit moves away from where the rim was placed, each time refitted
   by one step (:func:`~camwhisker.vision.pose.refit_pose`);
7. result: the checks that make a row trusted, and the paper's eqs. (2)-(7)
   on the same points (:mod:`camwhisker.vision.paper`).

When a frame cannot be trusted (tip not found, too few corners, a poor fit)
the next frame re-detects the features from scratch.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from camwhisker.kernels import tracker as kernels
from camwhisker.sensor.file import Sensor
from camwhisker.sensor.model import N_SQUARE, TIP, PlateModel
from camwhisker.sensor.polygon import polygon_area
from camwhisker.vision.blur import REBLUR_PAD_PX, reblur_templates, square_blur_px
from camwhisker.vision.colour import (
    cloth_level,
    cloth_samples,
    contrast_map,
    share_patches,
    unmixed_maps,
    white_balance_gains,
)
from camwhisker.vision.detect import FeaturesNotFound, detect_features
from camwhisker.vision.hints import FeatureHints
from camwhisker.vision.lk import PATCH_HALF_PX, refine_first_template, warp_templates
from camwhisker.vision.paper import PaperGeometry, PaperRest
from camwhisker.vision.pose import PoseFit, fit_pose, refit_pose
from camwhisker.vision.rest import RestReference, region_origin, region_size, rest_colours
from camwhisker.vision.tip import (
    TipMeasurement,
    blurred_rim,
    brightness,
    edge_blur_px,
    face_near,
    rim_centre,
    tip_edge_points,
)

__all__ = ["FrontEndOptions", "FrameResult", "FrontEnd", "PHI_MIN_FOR_THETA_DEG", "REST_FRAMES"]

#: Frames a rest reference is averaged over (``FrontEndOptions.rest_frames``): 1 s at
#: 30 fps, which brings its noise to ~0.18 of one frame's (under half, the target).
REST_FRAMES = 30
#: theta is reported only where phi exceeds this: theta's error is the tilt
#: vector's noise over phi, ~1 deg at this tilt and unbounded below.
PHI_MIN_FOR_THETA_DEG = 0.6
#: A corner is locked when it correlates with its warped rest patch this well:
#: one found right scores above, one half covered or on another edge below.
QUALITY_MIN = 0.98
#: Corners needed for a trusted pose (of 12): with the tip, 4 give 10 equations
#: for 5 unknowns, and at large tilts the rod and the cross hide up to 6.
MIN_CORNERS = 4
#: Largest trusted fit residual (px).
MAX_RMS_PX = 0.6
#: Search radius for the tip around its predicted positions (px): its motion
#: between frames on a hold; the velocity covers a sweep.
TIP_SEARCH_PX = 10.0
#: The tip jumped when its dark blob lies farther than this from both predictions (px).
TIP_JUMP_PX = 10.0
#: A corner is left out when its window comes this close to the rod's outline (px).
OCCLUSION_MARGIN_PX = 4.0
#: The rod can reach this far from the principal point, in tip reaches: no cloth sampled inside.
CLOTH_EXCLUDE_FACTOR = 1.3
#: Weight of the tip in the pose fit relative to a corner: its centroid rests on
#: ~4x the edge points of a corner's window.
TIP_WEIGHT = 4.0
#: Passes of the rest frame's tip measurement (each re-centres its window).
REST_TIP_PASSES = 3
#: Warped templates are reused while the pose moves less than this (dz mm, a and b
#: rad, shift mm): a 25 px patch then deforms by < 0.003 px.
TEMPLATE_REUSE = np.array([0.002, 1e-4, 1e-4, 0.002, 0.002])
#: Room around a corner's window for the LK to converge in (px): wide enough
#: that most corners lock at the first try after a jump between holds.
REFINE_MARGIN_PX = 20
#: The LK first tries patches this much larger than its window (px): most frames'
#: corners move less from their start, at a fraction of the full patch's pixels.
NEAR_MARGIN_PX = 8
#: The tip is measured again at the fitted pose when dz or the shift moved this
#: much since its rim was placed (mm): 0.02 px of rim radius.
RIM_REFIT_MM = 0.01
#: ... or the tilt by this (rad, 0.06 deg: < 0.02 px of rim radius at 30 deg).
RIM_REFIT_RAD = 1e-3
#: At most this many such re-measurements per frame.
RIM_REFITS = 3
#: The missing corners are predicted again only when fewer than this locked (a
#: big jump): a corner or two lost to noise is not worth the extra LK.
FALLBACK_BELOW = 8
#: Corners that must lock for the others to be predicted again from a fit: with
#: the tip, 2 corners give 6 equations for the 5 unknowns.
MIN_REPREDICT = 2
#: Depths tried when too few corners lock (mm): the range of dz and beyond, in
#: steps (~1.5 px at the corners) within the LK's reach.
DZ_HYPOTHESES_MM = np.arange(-0.2, 1.41, 0.2)
#: The tip-only tilt guess (Newton) stops after a step below this (rad): the
#: guess only starts the corners and the fit.
TILT_LAST_STEP_RAD = 2e-3
#: ... or after this many steps.
TILT_MAX_ITER = 8


@dataclass(frozen=True)
class FrontEndOptions:
    """How the front end runs (all recorded in the batch sidecar).

    mode : "model" (exact camera model, default) or "paper" (eqs. 2-7 as printed).
    fit_shift : fit the lateral shift (sx, sy) too.
    lock_gains : keep the rest frame's white-balance gains.
    lk_half_px : half size of a corner's template (px): the LK compares a
        (2 lk_half_px - 1)^2 window (the rest is its gradient's border).
    roi_margin_px : the region of interest around each corner's predicted
        position extends this far beyond its window (px), for the LK to
        converge in.
    rest_frames : the rest reference is averaged over up to this many frames at
        rest from the rest frame (and each re-zero) on (see
        :mod:`camwhisker.vision.stream`); 1: the rest frame alone.
    features : the user's rough positions of the features in the rest frame
        (:func:`~camwhisker.vision.hints.load_feature_hints`): detection searches
        each hinted feature around its hint; None: where the model puts them.
    apex_mask_px : the corners' LK leaves out its window's pixels this close to
        the centre (px; :func:`~camwhisker.vision.lk.refine_first_template`).
    square_band_px : the square's corners' LK keeps the cloth only this close to
        the square's edges (px; 0: all of it): a spring's end that enters the
        window farther out then moves them no more.
    """

    mode: str = "model"
    fit_shift: bool = True
    lock_gains: bool = False
    lk_half_px: int = PATCH_HALF_PX
    roi_margin_px: int = REFINE_MARGIN_PX
    rest_frames: int = REST_FRAMES
    features: FeatureHints | None = None
    apex_mask_px: float = 0.0
    square_band_px: float = 0.0

    def __post_init__(self):
        if self.mode not in ("model", "paper"):
            raise ValueError(f"mode must be 'model' or 'paper', got {self.mode!r}")
        for name, low in (("lk_half_px", 3), ("roi_margin_px", 1), ("rest_frames", 1)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
        if not 0.0 <= self.apex_mask_px < self.lk_half_px:
            raise ValueError(f"apex_mask_px must be in [0, lk_half_px), got {self.apex_mask_px!r}")
        if not 0.0 <= self.square_band_px:
            raise ValueError(f"square_band_px must be >= 0, got {self.square_band_px!r}")
        if self.features is not None and not isinstance(self.features, FeatureHints):
            raise ValueError(f"features must be FeatureHints or None, got {self.features!r}")


@dataclass(frozen=True, kw_only=True)
class FrameResult:
    """One frame's estimate. Values are NaN where untrusted; theta also where
    phi < PHI_MIN_FOR_THETA_DEG. ``points_uv`` (13, 2) and ``quality`` (13,)
    are the tracked points; ``paper`` holds (dz_mm, phi_deg, theta_deg) of eqs. 2-7.
    ``q`` (5,) is the fitted pose (dz_mm, a_rad, b_rad, sx_mm, sy_mm) whether trusted or
    not, NaN where no fit converged, zeros at the rest frame; theta is not masked in it."""

    frame: int
    dz_mm: float
    phi_deg: float
    theta_deg: float
    ok: bool
    model: tuple[float, float, float]
    paper: tuple[float, float, float]
    sx_mm: float = math.nan
    sy_mm: float = math.nan
    phi_sigma_deg: float = math.nan
    rms_px: float = math.nan
    n_corners: int = 0
    reason: str = ""
    points_uv: np.ndarray = field(default_factory=lambda: np.full((TIP + 1, 2), np.nan))
    quality: np.ndarray = field(default_factory=lambda: np.full(TIP + 1, np.nan))
    q: np.ndarray = field(default_factory=lambda: np.full(5, np.nan))

    @classmethod
    def untrusted(cls, frame: int, reason: str) -> FrameResult:
        """A row with no estimate: every value (``q`` too) NaN, ``ok`` False, ``reason``
        saying why."""
        nan3 = (math.nan,) * 3
        return cls(frame=frame, dz_mm=math.nan, phi_deg=math.nan, theta_deg=math.nan, ok=False,
                   model=nan3, paper=nan3, reason=reason)


@dataclass(frozen=True)
class _Look:
    """One frame as the steps read it: the image, its gains and its cloth level (DN)."""

    image: np.ndarray
    gains: np.ndarray
    cloth_dn: float


@dataclass(frozen=True)
class _TipFind:
    """The tip step's outcome.

    ``edges`` are the face's edge points (None: not found); ``measurement`` the
    tip measured with the model's rim placed at ``placed_q`` (None after a jump:
    measured after the corners' fit); ``uv`` where the corner steps take the tip
    to be (NaN when not found); ``q_guess`` the pose the corners start from.
    """

    edges: np.ndarray | None
    measurement: TipMeasurement | None
    placed_q: np.ndarray | None
    uv: np.ndarray
    q_guess: np.ndarray
    why: str

    @property
    def found(self) -> bool:
        return self.edges is not None

    @property
    def deferred(self) -> bool:
        return self.edges is not None and self.measurement is None


@dataclass(frozen=True)
class _Warped:
    """The rest templates warped to a pose, the rest offsets (13, 2) at that pose, and
    the pixels of each window the LK keeps (None: all; :func:`_square_band`)."""

    templates: np.ndarray
    offsets: np.ndarray
    keep: np.ndarray | None = None


def _square_band(dirs: np.ndarray, half: int, band_px: float) -> np.ndarray:
    """The pixels of each square corner's LK window (without the template's border)
    inside the square or within ``band_px`` of its edges, shape (K, 2 half - 1, 2 half - 1).

    ``dirs`` (K, 2, 2): the image directions of the corner's two edges, toward the
    square's neighbouring corners. The window's centre is taken as the corner: the
    tracked point lies within a pixel or two of it, inside."""
    r = np.arange(2 * half - 1) - (half - 1.0)
    pix = np.broadcast_to(np.stack(np.meshgrid(r, r), axis=-1), (len(dirs), len(r), len(r), 2))
    keep = np.ones(pix.shape[:3], bool)
    for edge, other in ((0, 1), (1, 0)):
        normal = dirs[:, edge, ::-1] * np.array([1.0, -1.0])
        normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
        # Toward the square's inside: the side of the corner's other edge.
        normal *= np.sign(np.einsum("ki,ki->k", normal, dirs[:, other]))[:, None]
        keep &= np.einsum("kyxi,ki->kyx", pix, normal) >= -band_px
    return keep


@dataclass
class _Corners:
    """The corners' step: the pose their templates were warped for, which are
    occluded, where each locked (uv (12, 2), quality (12,), NaN where not), and the
    rest offsets at that pose."""

    q: np.ndarray
    occluded: np.ndarray
    uv: np.ndarray
    quality: np.ndarray
    offsets: np.ndarray  # the rest offsets at q (:class:`_Warped`)

    @property
    def retry(self) -> np.ndarray:
        """Visible corners that did not lock."""
        return ~self.occluded & ~(self.quality >= QUALITY_MIN)

    @property
    def locked(self) -> np.ndarray:
        return ~self.occluded & ~self.retry

    @property
    def n_locked(self) -> int:
        return int(self.locked.sum())


class FrontEnd:
    """Stateful front end for one sensor. See the module notes.

    Parameters
    ----------
    sensor : Sensor
    options : FrontEndOptions, optional

    Attributes
    ----------
    rest : RestReference or None
        The rest frame's measurements; None before :meth:`start`.
    q : ndarray, shape (5,)
        The last trusted pose (dz_mm, a_rad, b_rad, sx_mm, sy_mm).
    """

    def __init__(self, sensor: Sensor, options: FrontEndOptions | None = None):
        self.sensor = sensor
        self.options = options or FrontEndOptions()
        self.model = PlateModel(sensor)
        self.paper = PaperGeometry.from_sensor(sensor)
        cam, plate = sensor.camera, sensor.plate
        reach_px = cam.fx_px * plate.h_r_mm / (plate.z_i_mm - plate.h_r_mm)
        #: How far the tip can get from its rest position (px): tilts to 45 deg, 1 mm
        #: of dz and 0.5 mm of shift, with room for the face's own radius.
        self._reach_px = (cam.fx_px * (plate.h_r_mm * math.sin(math.radians(45)) + 0.5)
                          / (plate.z_i_mm - plate.h_r_mm - 1.0))  # fmt: skip
        self._cloth = cloth_samples(
            (cam.height_px, cam.width_px), np.array([cam.cx_px, cam.cy_px]),
            CLOTH_EXCLUDE_FACTOR * reach_px,
        )  # fmt: skip
        self._is_square = np.arange(TIP) < N_SQUARE
        #: Image directions of the corners' edges at rest (the warps start from them).
        rest_dirs = self.model.edge_directions(np.zeros(5), step_mm=0.05)
        #: (D0^T)^-1 of the rest directions D0 (columns): A = D1^T (D0^T)^-1 maps them to D1.
        self._rest_dirs_inv = np.linalg.inv(np.swapaxes(rest_dirs, 1, 2))
        #: Weights of the pose fit: the tip counts TIP_WEIGHT corners.
        self._weights = np.where(np.arange(TIP + 1) == TIP, TIP_WEIGHT, 1.0)
        self.rest: RestReference | None = None
        # Per-frame state: the last poses, whether the last frame was lost, the frame
        # index, and the warped templates with the pose they were warped for.
        self.q = np.zeros(5)
        self._q_hist = [np.zeros(5)]
        self._lost = False
        self._index = -1
        self._template_cache: tuple[np.ndarray, _Warped] | None = None

    # ------------------------------------------------------------------ start
    def start(self, frame: np.ndarray, index: int = 0,
              rest_uv: np.ndarray | None = None) -> FrameResult:  # fmt: skip
        """Take ``frame`` as the rest reference (pose zero) and detect the features.

        ``rest_uv`` (13, 2): the points where an earlier rest frame's detection
        found them, used instead of detecting them again, the tip measured anew
        from there (a reference rebuilt from the mean of the rest frames: its zero
        lies in its templates, not in where they are centred).

        Raises
        ------
        FeaturesNotFound
            Naming what was not found.
        """
        self._check_frame(frame, rest=True)
        self.rest = self._measure_rest(frame, rest_uv)
        self.q = np.zeros(5)
        self._q_hist = [np.zeros(5)]
        self._lost = False
        self._index = index
        self._template_cache = None
        # The corners' step once at rest: its compiled kernels load now,
        # not on the first tracked frame, and the rest templates are ready.
        look = _Look(frame, self.rest.gains, self.rest.cloth_level)
        self._refine(look, self._templates(self.q), self.rest.uv[:TIP], np.ones(TIP, bool))
        return FrameResult(
            frame=index, dz_mm=0.0, phi_deg=0.0, theta_deg=math.nan, ok=True,
            model=(0.0, 0.0, math.nan), paper=(0.0, 0.0, math.nan), sx_mm=0.0, sy_mm=0.0,
            phi_sigma_deg=0.0, rms_px=0.0, n_corners=TIP, reason="",
            points_uv=self.rest.uv.copy(), quality=np.ones(TIP + 1), q=np.zeros(5),
        )

    rezero = start

    def redetect(self, frame: np.ndarray) -> bool:
        """Find the features again from scratch at the current frame; True if found.

        The pose is re-estimated from whatever was detected with the tip (the
        rod and the cross may hide some corners).
        """
        fit = self._detected_pose(frame, self.gains(frame))
        if fit is None:
            return False
        self.q = fit.q.copy()
        self._q_hist = [self.q.copy()]
        self._lost = False
        return True

    def gains(self, frame: np.ndarray) -> np.ndarray:
        """White-balance gains (B, G, R) for ``frame``: from its cloth, or the rest
        frame's when ``options.lock_gains``."""
        if self.options.lock_gains:
            return self.rest.gains
        return white_balance_gains(frame, *self._cloth)

    # ----------------------------------------------------------------- update
    def update(self, frame: np.ndarray, index: int | None = None) -> FrameResult:
        """Estimate the pose in the next frame."""
        if self.rest is None:
            raise RuntimeError("FrontEnd.update before start(): no rest frame")
        self._check_frame(frame)
        self._index = self._index + 1 if index is None else index
        if self._lost:
            # Best effort: a fresh pose from the detected features; the steps below
            # search for the tip and the corners again either way.
            self.redetect(frame)
        look = self._look(frame)
        q_still, q_moving = self._predict()
        tip = self._find_tip(look, q_still, q_moving)
        corners = self._lock_corners(look, tip)
        if corners is None:
            return self._fail("pose prediction failed")
        measured, fit, tip_now, placed_q = self._fit_step(corners, tip)
        quality = np.append(corners.quality, 1.0 if tip_now.ok else np.nan)
        fit, tip_now = self._refine_tip(fit, measured, tip, tip_now, placed_q, corners.offsets)
        return self._conclude(fit, measured, quality, tip_now)

    # ------------------------------------------------------------------ steps
    def _look(self, frame: np.ndarray) -> _Look:
        gains = self.gains(frame)
        return _Look(frame, gains, cloth_level(frame, *self._cloth, gains))

    def _predict(self) -> tuple[np.ndarray, np.ndarray]:
        """The last pose, and the last pose moved on at the last velocity."""
        last = self._q_hist[-1].copy()
        if len(self._q_hist) < 2:
            return last, last
        return last, 2 * last - self._q_hist[-2]

    def _find_tip(self, look: _Look, q_still: np.ndarray, q_moving: np.ndarray) -> _TipFind:
        """The tip's edge near the predictions (or anywhere in its reach), and a
        first tilt guess from the tip alone."""
        uv_still, _, rim = self.model.project(q_still, jacobian=False)
        radius = math.sqrt(polygon_area(rim) / math.pi)
        tip_still = uv_still[TIP] + self.rest.offsets[TIP]
        tip_moving, at_moving = tip_still, None
        if not np.array_equal(q_moving, q_still):
            at_moving = self.model.tip(q_moving)  # the tilt's first step reads it again
            tip_moving = at_moving[0] + self.rest.offsets[TIP]
        predicted = [tip_still] if tip_moving is tip_still else [tip_still, tip_moving]
        edges, blob_uv, why, afar = self._tip_edges(look, predicted, radius)
        if edges is None:
            return _TipFind(None, None, None, np.full(2, np.nan), q_still.copy(), why)
        # Place the model's rim at the prediction the tip came closest to (the
        # refits place it again at the fitted pose).
        off_still, off_moving = np.hypot(*(blob_uv - [tip_still, tip_moving]).T).tolist()
        q0, at_q0 = (q_moving, at_moving) if off_moving < off_still else (q_still, None)
        tip = None
        if not afar and min(off_still, off_moving) <= TIP_JUMP_PX:
            tip = self._tip_at(edges, q0)
        if tip is not None and tip.ok:
            return _TipFind(edges, tip, q0, tip.centre_uv,
                            self._tilt_from_tip(q0, tip.centre_uv, at_q0), why)  # fmt: skip
        # A jump: the tilt guess comes from the dark blob's centroid (within ~1 px
        # of the tip's, enough to start the corners), and the tip is measured after
        # the corners, with the rim placed at their fit: a jump moves dz too, which
        # the corners tell and the tip does not.
        return _TipFind(edges, None, None, blob_uv, self._tilt_from_tip(q0, blob_uv, at_q0), why)

    def _tip_edges(self, look: _Look, predicted: list[np.ndarray], radius: float):
        """The tip's edge points in a window over the predictions with dark pixels
        near them, else over all the tip can reach around its rest position.

        Returns (edges or None, the dark blob's centre, why not found, whether the
        whole reach was searched)."""
        # After a jump the velocity is the jump's and the moving prediction lies far
        # off: a window spanning both would be many times larger.
        near = [uv for uv in predicted
                if face_near(look.image, look.gains, uv[None], radius, look.cloth_dn)]  # fmt: skip
        edges, blob_uv, why = None, None, ""
        if near:
            tip_guess = (near[0] + near[-1]) / 2
            span = float(np.hypot(*(near[-1] - near[0]))) / 2
            edges, blob_uv, why = tip_edge_points(look.image, look.gains, tip_guess, radius,
                                                  TIP_SEARCH_PX + span)  # fmt: skip
        if edges is not None:
            return edges, blob_uv, why, False
        edges, blob_uv, why = tip_edge_points(look.image, look.gains, self.rest.uv[TIP], radius,
                                              self._reach_px)  # fmt: skip
        return edges, blob_uv, why, True

    def _lock_corners(self, look: _Look, tip: _TipFind) -> _Corners | None:
        """Drift correction of the corners from where the tip's guess puts them, and
        the recoveries after a big jump; None if the guess puts them nowhere."""
        warped = self._templates(tip.q_guess)
        uv_guess = self._corners_at(tip.q_guess, warped)
        if not np.isfinite(uv_guess).all():
            return None
        corners = self._lock_at(look, tip.q_guess, uv_guess, warped)
        if not tip.found:
            return corners
        if corners.n_locked < MIN_CORNERS:
            corners = self._try_other_depths(look, tip, corners)
        if corners.n_locked < MIN_REPREDICT:
            corners = self._try_fresh_detection(look, tip, corners)
        if corners.retry.any() and MIN_REPREDICT <= corners.n_locked < FALLBACK_BELOW:
            self._repredict_missing(look, tip, corners)
        return corners

    def _lock_at(self, look: _Look, q: np.ndarray, uv: np.ndarray, warped: _Warped) -> _Corners:
        """The visible corners at pose q, started from ``uv`` (12, 2)."""
        occluded = self._occluded(q, uv, warped.offsets)
        uv_ref, quality = self._refine(look, warped, uv, ~occluded)
        return _Corners(q, occluded, uv_ref, quality, warped.offsets)

    def _try_other_depths(self, look: _Look, tip: _TipFind, corners: _Corners) -> _Corners:
        """Recovery from a jump in dz: the corners where the tip would put them at
        other depths; the depth where most of them lock."""
        best = corners
        for dz_mm in DZ_HYPOTHESES_MM:
            q = best.q.copy()
            q[0] = dz_mm
            q = self._tilt_from_tip(q, tip.uv)
            warped = self._warp_templates(q)
            trial = self._lock_at(look, q, self._corners_at(q, warped), warped)
            if trial.n_locked > best.n_locked:
                best = trial
        return best

    def _try_fresh_detection(self, look: _Look, tip: _TipFind, corners: _Corners) -> _Corners:
        """Recovery when the shift jumped too: the features detected afresh, kept
        if more corners lock from the pose fitted to them."""
        fit = self._detected_pose(look.image, look.gains, tip.uv)
        if fit is None:
            return corners
        warped = self._warp_templates(fit.q)
        trial = self._lock_at(look, fit.q, self._corners_at(fit.q, warped), warped)
        return trial if trial.n_locked > corners.n_locked else corners

    def _repredict_missing(self, look: _Look, tip: _TipFind, corners: _Corners) -> None:
        """Recovery of corners too far from the tip-only prediction (dz or the shift
        moved): predicted again from a fit to the locked ones and the tip, in place."""
        locked, retry = corners.locked, corners.retry
        pre = np.full((TIP + 1, 2), np.nan)
        pre[:TIP][locked] = corners.uv[locked]
        pre[TIP] = tip.uv
        fit = self._fit(pre, corners.q, corners.offsets)
        if not fit.converged:
            return
        warped = self._templates(fit.q)
        uv_r, q_r = self._refine(look, warped, self._corners_at(fit.q, warped), retry)
        better = retry & (np.nan_to_num(q_r, nan=-1) > np.nan_to_num(corners.quality, nan=-1))
        corners.uv[better], corners.quality[better] = uv_r[better], q_r[better]

    def _fit_step(self, corners: _Corners, tip: _TipFind):
        """The pose fit to the locked corners and the tip; after a jump, the tip
        measured with its rim at the corners' fit and added by one step.

        Returns (measured points (13, 2), fit, the tip's measurement, the pose its
        rim was placed at or None)."""
        good = np.isfinite(corners.quality) & (corners.quality >= QUALITY_MIN)
        measured = np.full((TIP + 1, 2), np.nan)
        measured[:TIP] = np.where(good[:, None], corners.uv, np.nan)
        tip_now = tip.measurement
        if tip_now is None:
            tip_now = TipMeasurement(np.full(2, np.nan), math.nan, False, tip.why)
        measured[TIP] = tip_now.centre_uv if tip_now.ok else np.nan
        fit = self._fit(measured, corners.q, corners.offsets)
        if not tip.deferred:
            return measured, fit, tip_now, tip.placed_q
        # The rim placed at the corners' fit where they fix the pose, else at the guess.
        corners_fit = fit.converged and fit.n_points >= MIN_CORNERS
        placed_q = fit.q if corners_fit else corners.q
        tip_now = self._tip_at(tip.edges, placed_q)
        if tip_now.ok:
            measured[TIP] = tip_now.centre_uv
            fit = (refit_pose(self.model, fit, measured, corners.offsets, self._weights,
                              self.options.fit_shift, add=TIP)
                   if corners_fit else self._fit(measured, corners.q, corners.offsets))  # fmt: skip
        return measured, fit, tip_now, placed_q

    def _refine_tip(self, fit: PoseFit, measured: np.ndarray, tip: _TipFind,
                    tip_now: TipMeasurement, placed_q: np.ndarray | None,
                    offsets: np.ndarray):  # fmt: skip
        """The tip measured again with its rim at the fit, each time refitted by one
        step, until the fit stays within RIM_REFIT of where the rim was placed.

        Updates ``measured[TIP]``; returns (fit, the tip's last measurement)."""
        for _ in range(RIM_REFITS):
            if not (fit.converged and placed_q is not None and _moved(fit.q, placed_q)):
                break
            tip_now, placed_q = self._tip_at(tip.edges, fit.q), fit.q
            measured[TIP] = tip_now.centre_uv if tip_now.ok else np.nan
            fit = refit_pose(self.model, fit, measured, offsets, self._weights,
                             self.options.fit_shift)  # fmt: skip
        return fit, tip_now

    def _conclude(self, fit: PoseFit, measured, quality, tip: TipMeasurement) -> FrameResult:
        """Judge the frame, keep its pose for the next prediction, build its row."""
        n_corners = int((quality[:TIP] >= QUALITY_MIN).sum())
        reason = ""
        if not tip.ok:
            reason = f"tip: {tip.reason}"
        elif not fit.converged:
            reason = "pose fit failed"
        elif n_corners < MIN_CORNERS:
            reason = f"only {n_corners} corners tracked"
        elif fit.rms_px > MAX_RMS_PX:
            reason = f"poor fit (rms {fit.rms_px:.2f} px)"
        ok = reason == ""
        if fit.converged and n_corners >= 3:
            self.q = fit.q.copy()
            self._q_hist = (self._q_hist + [self.q.copy()])[-2:]
        if not ok and (not tip.ok or n_corners < 3):
            self._lost = True
        return self._result(fit, measured, quality, n_corners, ok, reason)

    # ---------------------------------------------------------------- helpers
    def _check_frame(self, frame: np.ndarray, rest: bool = False) -> None:
        cam = self.sensor.camera
        # A rest frame may be the float mean of several (vision.rest.mean_image).
        kinds = (np.uint8, np.float32) if rest else (np.uint8,)
        if frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype not in kinds:
            raise ValueError(
                f"expected a uint8 BGR frame (H, W, 3), got {frame.dtype} {frame.shape}"
            )
        if frame.shape[:2] != (cam.height_px, cam.width_px):
            raise ValueError(
                f"frame is {frame.shape[1]}x{frame.shape[0]} px but the sensor file says "
                f"{cam.width_px}x{cam.height_px}"
            )

    def _measure_rest(self, frame: np.ndarray, rest_uv=None) -> RestReference:
        """Detect the features at the rest frame (unless ``rest_uv`` gives them) and
        measure what the steps compare against."""
        gains = white_balance_gains(frame, *self._cloth)
        model_uv, _, rest_rim = self.model.project(np.zeros(5), jacobian=False)
        if rest_uv is None:
            uv = detect_features(frame, gains, self.model, hints=self.options.features).uv.copy()
        else:
            uv = np.array(rest_uv, float)
        offsets = uv - model_uv
        # Measure the tip exactly as update() will, until its window stops moving.
        radius = math.sqrt(polygon_area(rest_rim) / math.pi)
        # At rest the whole edge shows: the blur moves it inward evenly, not its centre.
        for _ in range(REST_TIP_PASSES):
            edges, _, why = tip_edge_points(frame, gains, uv[TIP], radius, TIP_SEARCH_PX)
            tip = None if edges is None else _tip_with_rim(self.model, edges, np.zeros(5),
                                                           offsets[TIP], 0.0)  # fmt: skip
            if tip is None or not tip.ok:
                raise FeaturesNotFound(["magnifier tip"], why or tip.reason)
            uv[TIP] = tip.centre_uv
            offsets[TIP] = tip.centre_uv - model_uv[TIP]
        rod = self.model.outlines(np.zeros(5))[1]
        tip_blur = edge_blur_px(brightness(frame, gains)[1], edges, rest_rim + offsets[TIP],
                                rod + offsets[TIP])  # fmt: skip
        # Rest colour shares over the corners' region: the first templates.
        size = region_size(frame.shape, uv[:TIP], self.options.lk_half_px)
        origin = region_origin(frame.shape, uv[:TIP], size)
        u0, v0 = origin.astype(int)
        region = frame[v0 : v0 + size[1], u0 : u0 + size[0]]
        weights, cloth_dn = rest_colours(frame, gains, contrast_map(region, gains), origin,
                                         *self._cloth)  # fmt: skip
        red, blue = unmixed_maps(region, weights, gains)
        blur = square_blur_px(blue, uv[:N_SQUARE] - origin)
        return RestReference(gains, uv, offsets, origin, size, red, blue, weights, cloth_dn,
                             PaperRest.from_points(uv), blur, tip_blur)  # fmt: skip

    def _detected_pose(self, frame, gains, tip_uv=None) -> PoseFit | None:
        """A pose fitted to the features :func:`detect_features` finds (searching
        from the rest pose); ``tip_uv`` replaces its tip. None if too little."""
        try:
            det = detect_features(frame, gains, self.model, require=(),
                                  hints=self.options.features)  # fmt: skip
        except FeaturesNotFound:  # pragma: no cover - nothing is required
            return None
        uv = det.uv.copy()
        if tip_uv is not None:
            uv[TIP] = tip_uv
        found = np.isfinite(uv).all(axis=1)
        if not found[TIP] or found[:TIP].sum() < MIN_REPREDICT:
            return None
        fit = fit_pose(self.model, uv, self.rest.offsets, self.q, self._weights * found,
                       self.options.fit_shift)  # fmt: skip
        return fit if fit.converged else None

    def _corners_at(self, q, warped: _Warped) -> np.ndarray:
        """Where the 12 corners should be seen at pose q (model plus rest offsets)."""
        return self.model.corners(q) + warped.offsets[:TIP]

    def _tip_at(self, edges, q) -> TipMeasurement:
        """The tip's centroid from its edge points, with the model's rim at pose q."""
        return _tip_with_rim(self.model, edges, q, self.rest.offsets[TIP], self.rest.tip_blur_px)

    def _tilt_from_tip(self, q: np.ndarray, tip_uv: np.ndarray, at_q=None) -> np.ndarray:
        """Solve (a, b) so the model's tip meets the measured one, dz and shift held;
        ``at_q``: the model's tip at q (:meth:`PlateModel.tip`) where already known."""
        q = q.copy()
        target = tip_uv - self.rest.offsets[TIP]
        for _ in range(TILT_MAX_ITER):
            uv, jac = self.model.tip(q) if at_q is None else at_q
            at_q = None
            # OpenCV's LU solve: far less call overhead than np.linalg.solve at 2 x 2.
            solved, step = cv2.solve(jac[:, 1:3], (target - uv)[:, None])
            if not solved:
                break
            step = step.ravel()
            q[1:3] += step
            if np.abs(step).max() < TILT_LAST_STEP_RAD:
                break
        return q

    def _refine(self, look: _Look, warped: _Warped, start_uv, active):
        """Drift correction of every active corner against its warped rest patch.

        The LK runs first in patches NEAR_MARGIN_PX around the start, then again
        in the full ``roi_margin_px`` for the corners it lost there: the same
        result as one run in the full margin (its path and samples are the same
        until it leaves the smaller patch), from fewer pixels."""
        opts = self.options
        half = opts.lk_half_px + opts.roi_margin_px
        active = active & self._patches_inside(look.image, start_uv, half)[0]
        near = opts.lk_half_px + min(NEAR_MARGIN_PX, opts.roi_margin_px)
        patches, origins, _ = self._share_patches(look, start_uv, near)
        lk = (warped.templates, start_uv)
        apex, keep = opts.apex_mask_px, warped.keep
        uv, qual = refine_first_template(patches, origins, *lk, active, apex, keep)
        again = active & np.isnan(qual)
        if near < half and again.any():
            patches, origins, _ = self._share_patches(look, start_uv, half)
            uv_f, q_f = refine_first_template(patches, origins, *lk, again, apex, keep)
            uv[again], qual[again] = uv_f[again], q_f[again]
        return uv, qual

    @staticmethod
    def _patches_inside(frame, uv, half):
        """Corners whose patch of 2 half + 1 px around ``uv`` lies inside the frame,
        and the patches' top-left pixels (0 where not)."""
        h, w = frame.shape[:2]
        return kernels.patch_corners(np.asarray(uv, float), half, h, w)

    def _share_patches(self, look: _Look, uv, half):
        """Red-share (cross) or blue-share (square) patches around each corner.

        Returns patches (12, 2 half + 1, 2 half + 1) float32, their origins (12, 2)
        and whether each lies inside the frame."""
        n = 2 * half + 1
        inside, tl = self._patches_inside(look.image, uv, half)
        scale = look.cloth_dn / self.rest.cloth_level
        wgt = (self.rest.weights * look.gains[None, :] / scale).astype(np.float32)  # red, blue
        # The cross's corners read the red share, the square's the blue share.
        patches = share_patches(look.image, tl, n, wgt[self._is_square.astype(int)])
        return patches, tl.astype(float), inside

    def _templates(self, q) -> _Warped:
        """:meth:`_warp_templates`, reused while q stays within TEMPLATE_REUSE of
        the pose they were warped for."""
        cached = self._template_cache
        if cached is not None and np.all(np.abs(cached[0] - q) <= TEMPLATE_REUSE):
            return cached[1]
        out = self._warp_templates(q)
        self._template_cache = (np.array(q, float), out)
        return out

    def _warp_templates(self, q) -> _Warped:
        """Rest patches warped to pose q, shape (12, n, n), and the rest offsets at q."""
        d1 = self.model.edge_directions(q, step_mm=0.05)
        # A maps rest-image directions to current-image directions: A d0 = d1.
        a = np.swapaxes(d1, 1, 2) @ self._rest_dirs_inv
        half = self.options.lk_half_px
        rest = self.rest
        big = half + REBLUR_PAD_PX
        sq = warp_templates(rest.blue, rest.origin, rest.uv[:N_SQUARE], a[:N_SQUARE], big)
        cr = warp_templates(rest.red, rest.origin, rest.uv[N_SQUARE:TIP], a[N_SQUARE:TIP], big)
        templates = reblur_templates(np.concatenate([sq, cr]), a, rest.share_blur_px)
        # A corner's offset is where its detected point sits in the corner's
        # neighbourhood (blur pulls it inward), which moves with that neighbourhood.
        offsets = rest.offsets.copy()
        offsets[:TIP] = np.einsum("kij,kj->ki", a, rest.offsets[:TIP])
        keep = None
        if self.options.square_band_px > 0:
            keep = np.ones((TIP, 2 * half - 1, 2 * half - 1), bool)
            keep[:N_SQUARE] = _square_band(d1[:N_SQUARE], half, self.options.square_band_px)
        return _Warped(templates, offsets, keep)

    def _occluded(self, q, uv, offsets):
        """Corners whose window something nearer covers (or nearly) at pose q, shape (12,).

        The rod can cover any corner; the cross can cover the square's corners
        (at large tilts its arm ends pass over them). Both are placed where the
        points are seen: the rod with the tip's rest offset (as the tip's rim), the
        cross with its corners' mean offset (``offsets`` (13, 2), at q)."""
        rod, cross = self.model.covers(q)
        hull = cv2.convexHull((rod + offsets[TIP]).astype(np.float32))
        cross = (cross + offsets[N_SQUARE:TIP].mean(axis=0)).astype(np.float32)
        reach = self.options.lk_half_px * math.sqrt(2) + OCCLUSION_MARGIN_PX
        out = np.zeros(TIP, bool)
        pts = np.asarray(uv, float).tolist()
        for k in _near_box(pts, hull, reach):
            out[k] = cv2.pointPolygonTest(hull, pts[k], True) > -reach
        for k in _near_box(pts[:N_SQUARE], cross, reach):
            out[k] |= cv2.pointPolygonTest(cross, pts[k], True) > -reach
        return out

    def _fit(self, measured, q0, offsets) -> PoseFit:
        return fit_pose(self.model, measured, offsets, q0, self._weights, self.options.fit_shift)

    def _result(self, fit, measured, quality, n_corners, ok, reason) -> FrameResult:
        paper = self.paper.pose_from_points(self.rest.paper, measured)
        if not fit.converged:
            return FrameResult(frame=self._index, dz_mm=math.nan, phi_deg=math.nan,
                               theta_deg=math.nan, ok=False, model=(math.nan,) * 3, paper=paper,
                               reason=reason, points_uv=measured, quality=quality,
                               n_corners=n_corners)  # fmt: skip
        pose = fit.pose
        phi_deg = pose.phi_deg
        theta_deg = pose.theta_deg if phi_deg >= PHI_MIN_FOR_THETA_DEG else math.nan
        model = (pose.dz_mm, phi_deg, theta_deg)
        paper_theta = paper[2] if paper[1] >= PHI_MIN_FOR_THETA_DEG else math.nan
        paper = (paper[0], paper[1], paper_theta)
        chosen = model if self.options.mode == "model" else paper
        if ok:
            dz, phi, theta = chosen
        else:
            dz = phi = theta = math.nan
        return FrameResult(
            frame=self._index, dz_mm=dz, phi_deg=phi, theta_deg=theta, ok=ok, model=model,
            paper=paper, sx_mm=pose.sx_mm, sy_mm=pose.sy_mm,
            phi_sigma_deg=math.degrees(fit.phi_sigma_rad), rms_px=fit.rms_px,
            n_corners=n_corners, reason=reason, points_uv=measured, quality=quality,
            q=fit.q.copy(),
        )

    def _fail(self, reason: str) -> FrameResult:
        self._lost = True
        return FrameResult.untrusted(self._index, reason)


def _tip_with_rim(model: PlateModel, edges, q, tip_offset, blur_px: float) -> TipMeasurement:
    """The tip's centroid from its edge points, with the model's rim at pose q
    moved by the tip's rest offset (px) and to where a blur of ``blur_px`` shows it."""
    rim, rod, _ = model.outlines(q)
    return rim_centre(edges, blurred_rim(rim, blur_px) + tip_offset, rod + tip_offset)


def _near_box(pts: list, polygon: np.ndarray, reach: float) -> list[int]:
    """The points (u, v) within ``reach`` (px, and 1 px more for rounding) of the
    polygon's bounding box: the only ones that can lie within ``reach`` of the polygon."""
    x, y, w, h = cv2.boundingRect(polygon)  # whole pixels, around every vertex
    m = reach + 1.0
    lo_u, lo_v, hi_u, hi_v = x - m, y - m, x + w + m, y + h + m
    # A NaN point compares False: it is tested.
    return [k for k, (u, v) in enumerate(pts)
            if not (u < lo_u or u > hi_u or v < lo_v or v > hi_v)]  # fmt: skip


def _moved(q1: np.ndarray, q0: np.ndarray) -> bool:
    """Whether the pose changed enough to reshape the tip's model rim."""
    dz, a, b, sx, sy = (abs(x - y) for x, y in zip(q1.tolist(), q0.tolist(), strict=True))
    return max(dz, sx, sy) > RIM_REFIT_MM or max(a, b) > RIM_REFIT_RAD
