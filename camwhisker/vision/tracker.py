"""The front end: frames in, plate pose out. A tracker object, a generator, a batch driver.

:class:`FrontEnd` holds the state. :meth:`FrontEnd.start` takes the rest
frame: it white-balances it, detects every feature (no clicking), stores the
rest patches (the first templates) and the rest offsets of the points against
the model. :meth:`FrontEnd.update` then does, per frame:

1. white balance from the cloth (or the locked rest gains);
2. the tip, segmented near where the last pose (and the last velocity) put it,
   a coarse search of its whole reach if not there (straight away when no
   pixel near either prediction is dark enough to be the face: a jump); its
   centroid from its edge and the model's rim; a first tilt guess from the
   tip alone (after a jump, from the dark blob's centroid: the rim waits for
   the corners' fit, step 5);
3. drift correction of the square's and the cross's corners against their rest
   patches, warped by the model's rest-to-current affine map, from where that
   guess puts them (:func:`~camwhisker.vision.lk.refine_first_template`), on
   linear colour-share maps; corners the rod or the cross covers are left out;
4. only after a big jump (fewer than FALLBACK_BELOW corners locked): the
   missing corners predicted again from a fit to the others and corrected
   again (and other depths tried, and the features detected afresh, when
   too few lock at all);
5. the pose fit through the exact camera model (:func:`~camwhisker.vision.pose.fit_pose`;
   after a jump, of the corners alone, then with the tip measured with the
   rim placed at that fit, added by one step);
   the tip measured again with the model's rim at the fitted pose while the
   fit moves away from where the rim was placed, each time refitted by one
   step from the fit's own Jacobian (:func:`~camwhisker.vision.pose.refit_pose`);
   and the paper's eqs. (2)-(7) on the same points.

The template-updating tracker of the paper (pyramidal LK from each corner's
updated template with a forward-backward check,
:func:`~camwhisker.vision.lk.track_updated`, and Matthews et al.'s update
rule: a corner's updated template moves on only when its drift correction
agreed with its LK track) is an option: ``FrontEndOptions(updated_template=
"fallback")`` runs it for the corners step 4 could not recover,
``"always"`` for every corner first, in Matthews et al.'s order. The
benchmark (``camwhisker bench``) finds neither more accurate than leaving it
out on its scenes, which do jump between holds, and both slower, so the
default leaves it out.

When a frame cannot be trusted (tip not found, too few corners, a poor fit)
the next frame re-detects the features from scratch.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field

import cv2
import numpy as np
from numba import njit

from camwhisker.model import N_SQUARE, TIP, PlateModel
from camwhisker.polygon import polygon_area
from camwhisker.sensor import Sensor
from camwhisker.vision.colour import (
    cloth_level,
    cloth_samples,
    contrast_map,
    share_patches,
    unmixed_maps,
    unmixing_weights,
    white_balance_gains,
)
from camwhisker.vision.detect import FeaturesNotFound, detect_features
from camwhisker.vision.lk import (
    PATCH_HALF_PX,
    PYR_LEVELS,
    match_parabolic,
    refine_first_template,
    to_uint8,
    track_updated,
    warp_templates,
)
from camwhisker.vision.paper import PaperGeometry
from camwhisker.vision.pose import PoseFit, fit_pose, refit_pose
from camwhisker.vision.tip import (
    TipMeasurement,
    face_near,
    rim_centre,
    tip_edge_points,
)

__all__ = ["FrontEndOptions", "FrameResult", "FrontEnd", "track", "PHI_MIN_FOR_THETA_DEG"]

#: theta is reported only where phi exceeds this. On the benchmark's rest frames
#: the tilt vector's noise is ~0.006 deg per component (nominal) to ~0.016 deg
#: (hard); theta's error is about that over phi (rad), so at 0.6 deg of tilt it is
#: ~0.6 deg (nominal) to ~1.5 deg (hard), and it grows without bound below.
PHI_MIN_FOR_THETA_DEG = 0.6
#: Forward-backward error above which a step-3 track is dropped (px): a good track
#: comes back within ~0.05 px; a jump onto another edge does not.
FB_MAX_PX = 1.0
#: Step-4 result must correlate with its warped rest patch at least this well: a
#: corner found right scores >= 0.99 even at 5 DN noise and 2.6 px blur; a corner
#: half covered or caught on another edge scores 0.93-0.97.
QUALITY_MIN = 0.98
#: The updated template follows a corner only when drift correction moved it less
#: than this (Matthews et al.'s epsilon, px).
UPDATE_EPS_PX = 0.5
#: Corners needed for a trusted pose (of 12), and the largest trusted fit residual.
#: With the tip, 4 corners give 10 equations for 5 unknowns; at tilts near 30 deg
#: the rod and the cross hide up to 6 corners, so more would flag good rows.
MIN_CORNERS = 4
MAX_RMS_PX = 0.6
#: Search radius for the tip around its predicted positions (px; it moves < 3 px
#: between frames at 30 fps on a hold, more on a sweep, which the velocity covers;
#: farther than TIP_JUMP_PX it is taken for a jump anyway, and a face the window
#: cuts is looked for again around its visible part). 10 rather than 20: the window
#: is ~30% smaller, and the vision bench's and the live clip's errors are unchanged.
#: Then the margin of the corners' region for the updated-template LK (px).
TIP_SEARCH_PX = 10.0
#: The tip jumped when its dark blob lies farther than this from both predictions
#: (px): on the live benchmark's clip it lay within 4.6 px of the nearer one on every
#: frame but the jumps, and 25 px or more on those.
TIP_JUMP_PX = 10.0
REGION_MARGIN_PX = 40
#: The corners' spread grows by up to ~8% (dz = 1 mm brings them 4% closer; a tilt
#: spreads the near side): the region is this much larger than at rest.
REGION_GROWTH = 1.15
#: A corner is left out when its window comes this close to the rod's outline (px).
OCCLUSION_MARGIN_PX = 4.0
#: The rod can reach this far from the principal point (px): no cloth sampled inside.
CLOTH_EXCLUDE_FACTOR = 1.3
#: Weight of the tip in the pose fit relative to a corner: its centroid rests on
#: ~48 edge points against a corner's ~25 rows of a 25 x 25 window.
TIP_WEIGHT = 4.0
#: Passes of the rest frame's tip measurement (each re-centres its window).
REST_TIP_PASSES = 3
#: Warped templates are reused while the pose moves less than this (dz mm, a and b
#: rad, shift mm): 0.002 mm and 0.005 deg deform a 25 px patch by < 0.003 px.
TEMPLATE_REUSE = np.array([0.002, 1e-4, 1e-4, 0.002, 0.002])
#: LK patches carry this many pixels around the window for the corner to move in
#: while converging (the prediction from the tip is within ~1 px on holds). 20
#: rather than 10: after a jump between holds more corners lock at the first try,
#: which saves the recoveries of step 4; ``camwhisker bench`` found it as accurate
#: on every scene and faster overall (the hard scene: 113 against 93 frames/s).
REFINE_MARGIN_PX = 20
#: The LK first tries patches this much (px) larger than its window: as far as
#: the corners moved from their start on every frame of the live benchmark's clip
#: (at most 4.7 px) and on ~98% of the vision benchmark's three scenes; the rest
#: are refined again in the full margin.
NEAR_MARGIN_PX = 8
#: The tip is measured again at the fitted pose when dz or the shift moved this
#: much since the guess: 0.01 mm changes the rim's radius by 0.02 px.
RIM_REFIT_MM = 0.01
#: ... or the tilt by this (rad, 0.06 deg: < 0.02 px of rim radius at 30 deg).
RIM_REFIT_RAD = 1e-3
#: At most this many such measurements per frame. Near the fit the tip moves
#: ~0.03 px per 1e-3 rad of its rim's pose (the model tip ~0.5 px); a rim placed
#: a few tenths of a degree off also misplaces the rays left out beside the rod,
#: which moves it more. On the live clip one or two suffice: after them every
#: frame's rim lies within 9e-4 rad and 0.01 mm of its reported pose.
RIM_REFITS = 3
#: The second chances (re-prediction from the corners that locked, then the
#: updated templates) run when fewer corners than this locked on the warped rest
#: patches (a big jump); a corner or two lost to noise is not worth their ~2 ms.
FALLBACK_BELOW = 8
#: Corners that must lock for the others to be predicted again from a fit: with
#: the tip, 2 corners give 6 equations for the 5 unknowns.
MIN_REPREDICT = 2
#: Depths tried when too few corners lock (mm): the range of dz and beyond, in
#: steps (0.2 mm: ~1.5 px at the corners) within the LK's reach.
DZ_HYPOTHESES_MM = np.arange(-0.2, 1.41, 0.2)
#: The tip-only tilt guess (Newton) stops after a step below this (rad) or at the
#: iteration count: on the live clip's 448 Newton steps the step after a step s was
#: below s^2 + 2.1e-3 s, so < 1e-5 rad (6e-4 deg; 3.5e-6 at most there) is left;
#: the guess only starts the corners and the fit.
TILT_LAST_STEP_RAD = 2e-3
TILT_MAX_ITER = 8
#: Rest-frame colours are medians over pixels with |G| above this, eroded by
#: COLOUR_ERODE_PX so that no blurred edge pixel enters.
COLOUR_G_MIN = 1.0
COLOUR_ERODE_PX = 4


@dataclass(frozen=True)
class FrontEndOptions:
    """How the front end runs (all recorded in the batch sidecar).

    mode : "model" (exact camera model, default) or "paper" (eqs. 2-7 as printed).
    fit_shift : fit the lateral shift (sx, sy) too.
    lock_gains : keep the rest frame's white-balance gains.
    updated_template : when to track corners with pyramidal LK from their
        updated templates (the last frames): "off" (default) never;
        "fallback" only for corners the drift correction could not lock from
        the model's prediction; "always" for every corner first (Matthews et
        al.'s order). The benchmark finds neither more accurate than "off" on
        its scenes, and both slower, so the default leaves it out.
    lk_half_px : half size of a corner's template (px): the LK compares a
        (2 lk_half_px - 1)^2 window (the rest is its gradient's border).
    roi_margin_px : the region of interest around each corner's predicted
        position extends this far beyond its window (px), for the LK to
        converge in; also the reach of the "parabola" search.
    pyramid_levels : levels of the pyramidal LK of the updated-template step.
    subpixel : how a corner is placed against its warped rest template:
        "lk" (inverse-compositional Lucas-Kanade, translation only, iterated
        to 0.01 px) or "parabola" (normalised cross-correlation over the
        region of interest, cv2.matchTemplate, and a parabola through the peak).
    """

    mode: str = "model"
    fit_shift: bool = True
    lock_gains: bool = False
    updated_template: str = "off"
    lk_half_px: int = PATCH_HALF_PX
    roi_margin_px: int = REFINE_MARGIN_PX
    pyramid_levels: int = PYR_LEVELS
    subpixel: str = "lk"

    def __post_init__(self):
        if self.mode not in ("model", "paper"):
            raise ValueError(f"mode must be 'model' or 'paper', got {self.mode!r}")
        if self.updated_template not in ("fallback", "always", "off"):
            raise ValueError(
                f"updated_template must be 'fallback', 'always' or 'off', "
                f"got {self.updated_template!r}"
            )
        if self.subpixel not in ("lk", "parabola"):
            raise ValueError(f"subpixel must be 'lk' or 'parabola', got {self.subpixel!r}")
        for name, low in (("lk_half_px", 3), ("roi_margin_px", 1), ("pyramid_levels", 0)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")


@dataclass(frozen=True)
class FrameResult:
    """One frame's estimate. Values are NaN where untrusted; theta also where
    phi < PHI_MIN_FOR_THETA_DEG. ``points_uv`` (13, 2) and ``quality`` (13,)
    are the tracked points; ``paper`` holds (dz_mm, phi_deg, theta_deg) of eqs. 2-7."""

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

    @classmethod
    def untrusted(cls, frame: int, reason: str) -> FrameResult:
        """A row with no estimate: every value NaN, ``ok`` False, ``reason`` saying why."""
        nan3 = (math.nan,) * 3
        return cls(frame, math.nan, math.nan, math.nan, False, nan3, nan3, reason=reason)


class FrontEnd:
    """Stateful front end for one sensor. See the module notes.

    Parameters
    ----------
    sensor : Sensor
    options : FrontEndOptions, optional
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
        self._started = False
        self._lost = False
        self._index = -1
        #: The cloth's white-balanced brightness in the frame being processed (DN),
        #: read once per frame by start() and update(); the tip's quick look and
        #: every corner step of the frame use it.
        self._cloth_now = math.nan

    # ------------------------------------------------------------------ start
    def start(self, frame: np.ndarray, index: int = 0) -> FrameResult:
        """Take ``frame`` as the rest reference (pose zero) and detect the features.

        Raises
        ------
        FeaturesNotFound
            Naming what was not found.
        """
        self._check_frame(frame)
        gains = white_balance_gains(frame, *self._cloth)
        det = detect_features(frame, gains, self.model)
        self.gains_rest = gains
        model_uv, _, rest_rim = self.model.project(np.zeros(5), jacobian=False)
        self.offsets = det.uv - model_uv
        # Measure the tip exactly as update() will, until its window stops moving.
        radius = math.sqrt(polygon_area(rest_rim) / math.pi)
        for _ in range(REST_TIP_PASSES):
            edges, _, why = tip_edge_points(frame, gains, det.uv[TIP], radius, TIP_SEARCH_PX)
            tip = None if edges is None else self._tip_at(edges, np.zeros(5))
            if tip is None or not tip.ok:
                raise FeaturesNotFound(["magnifier tip"], why or tip.reason)
            det.uv[TIP] = tip.centre_uv
            self.offsets[TIP] = tip.centre_uv - model_uv[TIP]
        self.rest_uv = det.uv.copy()
        # Rest contrast maps over the corners' region: the first templates.
        g, origin = self._region_map(frame, gains, det.uv[:TIP])
        self.rest_origin = origin
        self._measure_colours(frame, gains, g, origin)
        self._cloth_now = self.cloth_rest
        self.rest_red, self.rest_blue = self._shares(frame, gains, origin, g.shape)
        # Updated templates: one image per corner (shared until they diverge).
        u0, v0 = origin.astype(int)
        rw, rh = self._region_size
        self._tmpl_img = [_Template(frame[v0 : v0 + rh, u0 : u0 + rw].copy(), origin, gains)] * TIP
        self._tmpl_uv = det.uv[:TIP].copy()
        self.q = np.zeros(5)
        self._q_hist = [np.zeros(5)]
        self._started = True
        self._lost = False
        self._index = index
        self._paper_rest = (self._paper_widths(det.uv), det.uv[TIP].copy())
        # The corners' step once at rest: its compiled kernels load now (~20 ms),
        # not on the first tracked frame, and the rest templates are ready.
        self._refine(frame, gains, self._templates(self.q), self.rest_uv[:TIP], np.ones(TIP, bool))
        return FrameResult(
            index, 0.0, 0.0, math.nan, True, (0.0, 0.0, math.nan), (0.0, 0.0, math.nan),
            0.0, 0.0, 0.0, 0.0, TIP, "", det.uv.copy(), np.ones(TIP + 1),
        )  # fmt: skip

    rezero = start

    def redetect(self, frame: np.ndarray) -> bool:
        """Find the features again from scratch at the current frame; True if found.

        The pose is re-estimated from whatever was detected with the tip (the
        rod and the cross may hide some corners).
        """
        fit = self._detected_pose(frame, self._gains(frame))
        if fit is None:
            return False
        self.q = fit.q.copy()
        self._q_hist = [self.q.copy()]
        self._tmpl_img = [None] * TIP
        self._lost = False
        return True

    # ----------------------------------------------------------------- update
    def update(self, frame: np.ndarray, index: int | None = None) -> FrameResult:
        """Estimate the pose in the next frame."""
        if not self._started:
            raise RuntimeError("FrontEnd.update before start(): no rest frame")
        self._check_frame(frame)
        self._index = self._index + 1 if index is None else index
        if self._lost:
            # Best effort: a fresh pose from the detected features; the steps below
            # search for the tip and the corners again either way.
            self.redetect(frame)
        opts = self.options
        gains = self._gains(frame)
        self._cloth_now = cloth_level(frame, *self._cloth, gains)
        q_pred, q_moving = self._predict()

        # The tip's edge, then a first tilt guess from the tip alone. The window spans
        # the predictions (standing still, and moving on at the last velocity) with
        # dark pixels near them: after a jump the velocity is the jump's, and the
        # moving prediction lies far off (a window spanning both had 5-10x the
        # pixels on the live clip, and went to the coarse search).
        uv_pred, _, rim = self.model.project(q_pred, jacobian=False)
        radius = math.sqrt(polygon_area(rim) / math.pi)
        tip_still = uv_pred[TIP] + self.offsets[TIP]
        tip_moving = tip_still
        if not np.array_equal(q_moving, q_pred):
            tip_moving = self.model.tip(q_moving)[0] + self.offsets[TIP]
        predicted = [tip_still] if tip_moving is tip_still else [tip_still, tip_moving]
        near = [uv for uv in predicted
                if face_near(frame, gains, uv[None], radius, self._cloth_now)]  # fmt: skip
        edges, blob_uv, why = None, None, ""
        if near:
            tip_guess = (near[0] + near[-1]) / 2
            span = float(np.hypot(*(near[-1] - near[0]))) / 2
            edges, blob_uv, why = tip_edge_points(frame, gains, tip_guess, radius,
                                                  TIP_SEARCH_PX + span)  # fmt: skip
        # Not in the window (or nothing dark where either prediction puts it: a
        # jump): the tip is farther from both predictions than the window reaches,
        # so the rim is not tried at a prediction below.
        lost = edges is None
        if lost:  # search all the tip can reach, around its rest position
            edges, blob_uv, why = tip_edge_points(frame, gains, self.rest_uv[TIP], radius,
                                                  self._reach_px)  # fmt: skip
        q_guess = q_pred.copy()
        tip = None
        tip_q = None  # the pose the tip's model rim and the rod's outline were placed at
        tip_uv = np.full(2, np.nan)  # where the corners' steps below take the tip to be
        if edges is not None:
            # Place the model's rim at the prediction the tip came closest to (the
            # refits below place it again at the fitted pose), and guess the tilt
            # from the tip's centroid.
            off_still, off_moving = np.hypot(*(blob_uv - [tip_still, tip_moving]).T).tolist()
            q0 = q_moving if off_moving < off_still else q_pred
            if not lost and min(off_still, off_moving) <= TIP_JUMP_PX:
                tip, tip_q = self._tip_at(edges, q0), q0
            if tip is not None and tip.ok:
                tip_uv = tip.centre_uv
            else:
                # A jump (the tip searched for afar, or far from both predictions, or
                # the rim finds no tip at the prediction). The tilt guess comes from
                # the dark blob's centroid (within ~1 px of the tip's, enough to start
                # the corners), and the tip is measured after the corners, with the
                # rim placed at their fit: a jump moves dz too, which the corners
                # tell and the tip does not.
                tip, tip_q, tip_uv = None, None, blob_uv
            q_guess = self._tilt_from_tip(q0, tip_uv)
        deferred = edges is not None and tip is None
        tip_found = edges is not None

        # Corners: drift-corrected LK against the rest patches warped to q_guess.
        uv_guess = self._corners_at(q_guess)
        if not np.isfinite(uv_guess).all():
            return self._fail("pose prediction failed")
        occluded = self._occluded(q_guess, uv_guess)
        start_uv = uv_guess.copy()
        tracked = np.zeros(TIP, bool)
        if opts.updated_template == "always":
            start_uv, tracked = self._updated_step(frame, gains, uv_guess, ~occluded)
        tmpl = self._templates(q_guess)
        uv_ref, qual = self._refine(frame, gains, tmpl, start_uv, ~occluded)
        retry = ~occluded & ~(qual >= QUALITY_MIN)
        locked = ~occluded & ~retry
        if locked.sum() < MIN_CORNERS and tip_found:
            # Lost after a jump in dz: try the corners where the tip would put them
            # at other depths, and keep the depth where most of them lock.
            best = locked.sum()
            for dz_mm in DZ_HYPOTHESES_MM:
                q_h = q_guess.copy()
                q_h[0] = dz_mm
                q_h = self._tilt_from_tip(q_h, tip_uv)
                uv_h = self._corners_at(q_h)
                occ_h = self._occluded(q_h, uv_h)
                uv_r, q_r = self._refine(frame, gains, self._warp_templates(q_h), uv_h, ~occ_h)
                n_locked = int((~occ_h & (np.nan_to_num(q_r, nan=-1) >= QUALITY_MIN)).sum())
                if n_locked > best:
                    best, q_guess, occluded, start_uv = n_locked, q_h, occ_h, uv_h
                    uv_ref, qual, tmpl = uv_r, q_r, self._warp_templates(q_h)
            retry = ~occluded & ~(qual >= QUALITY_MIN)
            locked = ~occluded & ~retry
        if locked.sum() < MIN_REPREDICT and tip_found:
            # Still nothing (the shift jumped too): detect the features afresh.
            fit0 = self._detected_pose(frame, gains, tip_uv)
            if fit0 is not None:
                q_h = fit0.q
                uv_h = self._corners_at(q_h)
                occ_h = self._occluded(q_h, uv_h)
                tmpl_h = self._warp_templates(q_h)
                uv_r, q_r = self._refine(frame, gains, tmpl_h, uv_h, ~occ_h)
                if (~occ_h & (np.nan_to_num(q_r, nan=-1) >= QUALITY_MIN)).sum() > locked.sum():
                    q_guess, occluded, start_uv, tmpl = q_h, occ_h, uv_h, tmpl_h
                    uv_ref, qual = uv_r, q_r
                    retry = ~occluded & ~(qual >= QUALITY_MIN)
                    locked = ~occluded & ~retry
        if retry.any() and MIN_REPREDICT <= locked.sum() < FALLBACK_BELOW and tip_found:
            # Some corners were too far from the tip-only prediction (dz or the shift
            # moved): predict them again from a fit to the corners that locked.
            pre = np.full((TIP + 1, 2), np.nan)
            pre[:TIP][locked] = uv_ref[locked]
            pre[TIP] = tip_uv
            fit0 = self._fit(pre, q_guess)
            if fit0.converged:
                again = self._corners_at(fit0.q)
                uv_r, q_r = self._refine(frame, gains, self._templates(fit0.q), again, retry)
                better = retry & (np.nan_to_num(q_r, nan=-1) > np.nan_to_num(qual, nan=-1))
                uv_ref[better], qual[better] = uv_r[better], q_r[better]
                retry = ~occluded & ~(qual >= QUALITY_MIN)
        locked = ~occluded & ~retry
        if opts.updated_template == "fallback" and retry.any() and locked.sum() < FALLBACK_BELOW:
            # Too far from the prediction: track those corners from the previous
            # frame (the updated template) and correct them again.
            again, tracked_r = self._updated_step(frame, gains, uv_guess, retry)
            tracked |= tracked_r
            if tracked_r.any():
                uv_r, q_r = self._refine(frame, gains, tmpl, again, tracked_r)
                better = tracked_r & (np.nan_to_num(q_r, nan=-1) > np.nan_to_num(qual, nan=-1))
                uv_ref[better], qual[better] = uv_r[better], q_r[better]
        good = np.isfinite(qual) & (qual >= QUALITY_MIN)
        measured = np.full((TIP + 1, 2), np.nan)
        measured[:TIP] = np.where(good[:, None], uv_ref, np.nan)
        if tip is None:
            tip = TipMeasurement(np.full(2, np.nan), math.nan, False, why)
        measured[TIP] = tip.centre_uv if tip.ok else np.nan
        fit = self._fit(measured, q_guess)
        if deferred:
            # The tip after a jump: its rim placed at the corners' fit where they fix
            # the pose (else at the guess), and added to the fit.
            corners_fit = fit.converged and fit.n_points >= MIN_CORNERS
            tip_q = fit.q if corners_fit else q_guess
            tip = self._tip_at(edges, tip_q)
            if tip.ok:
                measured[TIP] = tip.centre_uv
                fit = (refit_pose(self.model, fit, measured, self.offsets, self._weights,
                                  self.options.fit_shift, add=TIP)
                       if corners_fit else self._fit(measured, q_guess))  # fmt: skip
        quality = np.append(qual, 1.0 if tip.ok else np.nan)
        for _ in range(RIM_REFITS):
            # The tip was measured with its rim placed at tip_q: measure it again at
            # the fit, until the fit stays within RIM_REFIT of where the rim was placed.
            if not (fit.converged and tip_q is not None and _moved(fit.q, tip_q)):
                break
            tip, tip_q = self._tip_at(edges, fit.q), fit.q
            measured[TIP] = tip.centre_uv if tip.ok else np.nan
            fit = refit_pose(self.model, fit, measured, self.offsets, self._weights,
                             self.options.fit_shift)
        n_corners = int(good.sum())
        if opts.updated_template != "off":
            self._keep_previous(frame, gains, measured[:TIP], start_uv, tracked)

        reason = ""
        if not tip.ok:
            reason = f"tip: {tip.reason}"
        elif fit is None or not fit.converged:
            reason = "pose fit failed"
        elif n_corners < MIN_CORNERS:
            reason = f"only {n_corners} corners tracked"
        elif fit.rms_px > MAX_RMS_PX:
            reason = f"poor fit (rms {fit.rms_px:.2f} px)"
        ok = reason == ""
        if fit is not None and fit.converged and n_corners >= 3:
            self.q = fit.q.copy()
            self._q_hist = (self._q_hist + [self.q.copy()])[-2:]
        if not ok and (not tip.ok or n_corners < 3):
            self._lost = True
        return self._result(fit, measured, quality, n_corners, ok, reason)

    # ---------------------------------------------------------------- helpers
    def _check_frame(self, frame: np.ndarray) -> None:
        cam = self.sensor.camera
        if frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype != np.uint8:
            raise ValueError(
                f"expected a uint8 BGR frame (H, W, 3), got {frame.dtype} {frame.shape}"
            )
        if frame.shape[:2] != (cam.height_px, cam.width_px):
            raise ValueError(
                f"frame is {frame.shape[1]}x{frame.shape[0]} px but the sensor file says "
                f"{cam.width_px}x{cam.height_px}"
            )

    def _gains(self, frame):
        if self.options.lock_gains:
            return self.gains_rest
        return white_balance_gains(frame, *self._cloth)

    def _detected_pose(self, frame, gains, tip_uv=None) -> PoseFit | None:
        """A pose fitted to the features :func:`detect_features` finds (searching
        from the rest pose); ``tip_uv`` replaces its tip. None if too little."""
        try:
            det = detect_features(frame, gains, self.model, require=())
        except FeaturesNotFound:  # pragma: no cover - nothing is required
            return None
        uv = det.uv.copy()
        if tip_uv is not None:
            uv[TIP] = tip_uv
        found = np.isfinite(uv).all(axis=1)
        if not found[TIP] or found[:TIP].sum() < MIN_REPREDICT:
            return None
        fit = fit_pose(self.model, uv, self.offsets, self.q, self._weights * found,
                       self.options.fit_shift)
        return fit if fit.converged else None

    def _measure_colours(self, frame, gains, g, origin) -> None:
        """Colours of cross, square and cloth at the rest frame -> unmixing weights."""
        u0, v0 = origin.astype(int)
        h, w = g.shape
        region = frame[v0 : v0 + h, u0 : u0 + w].astype(np.float32) * gains
        kernel = np.ones((2 * COLOUR_ERODE_PX + 1,) * 2, np.uint8)
        red = cv2.erode((g < -COLOUR_G_MIN).astype(np.uint8), kernel).astype(bool)
        blue = cv2.erode((g > COLOUR_G_MIN).astype(np.uint8), kernel).astype(bool)
        if red.sum() < 10 or blue.sum() < 10:
            raise FeaturesNotFound(["square colour" if blue.sum() < 10 else "cross colour"])
        rows, cols = self._cloth
        cloth = (frame[rows, cols].astype(np.float32) * gains).mean(axis=0)
        self.weights = unmixing_weights(
            np.median(region[red], axis=0), np.median(region[blue], axis=0), cloth
        )
        self.cloth_rest = cloth_level(frame, rows, cols, gains)

    def _shares(self, frame, gains, origin, shape):
        """Red and blue share maps over the region at ``origin`` of the given shape."""
        u0, v0 = origin.astype(int)
        h, w = shape
        scale = 1.0
        if hasattr(self, "cloth_rest"):
            scale = cloth_level(frame, *self._cloth, gains) / self.cloth_rest
        return unmixed_maps(frame[v0 : v0 + h, u0 : u0 + w], self.weights, gains, scale)

    def _predict(self) -> tuple[np.ndarray, np.ndarray]:
        """The last pose, and the last pose moved on at the last velocity."""
        last = self._q_hist[-1].copy()
        if len(self._q_hist) < 2:
            return last, last
        return last, 2 * last - self._q_hist[-2]

    def _tmpl_img_missing(self) -> np.ndarray:
        return np.array([t is None for t in self._tmpl_img])

    def _region(self, frame, uv):
        """Origin (u, v) of a fixed-size region centred on the points (OpenCV's
        pyramidal LK wants equal sizes), or None."""
        h, w = frame.shape[:2]
        ok = np.isfinite(uv).all(axis=1)
        if not ok.any():
            return None
        if not hasattr(self, "_region_size"):
            ext = uv[ok].max(axis=0) - uv[ok].min(axis=0)
            margin = self.options.lk_half_px + REGION_MARGIN_PX
            size = np.ceil(ext * REGION_GROWTH).astype(int) + 2 * margin
            self._region_size = (min(int(size[0]), w), min(int(size[1]), h))
        rw, rh = self._region_size
        c = (uv[ok].min(axis=0) + uv[ok].max(axis=0)) / 2
        u0 = int(np.clip(round(c[0] - rw / 2), 0, w - rw))
        v0 = int(np.clip(round(c[1] - rh / 2), 0, h - rh))
        return np.array([u0, v0], float)

    def _region_map(self, frame, gains, uv):
        """Contrast map of eq. (1) over the region of :meth:`_region`: (map, origin)."""
        origin = self._region(frame, uv)
        if origin is None:
            return None, None
        u0, v0 = origin.astype(int)
        rw, rh = self._region_size
        return contrast_map(frame[v0 : v0 + rh, u0 : u0 + rw], gains), origin

    def _corners_at(self, q) -> np.ndarray:
        """Where the 12 corners should be seen at pose q (model plus rest offsets)."""
        return self.model.corners(q) + self.offsets[:TIP]

    def _tip_at(self, edges, q) -> TipMeasurement:
        """The tip's centroid from its edge points, with the model's rim at pose q."""
        rim, rod, _ = self.model.outlines(q)
        return rim_centre(edges, rim + self.offsets[TIP], rod + self.offsets[TIP])

    def _tilt_from_tip(self, q: np.ndarray, tip_uv: np.ndarray) -> np.ndarray:
        """Solve (a, b) so the model's tip meets the measured one, dz and shift held."""
        q = q.copy()
        target = tip_uv - self.offsets[TIP]
        for _ in range(TILT_MAX_ITER):
            uv, jac = self.model.tip(q)
            # OpenCV's LU solve: ~10x less overhead than np.linalg.solve at 2 x 2.
            solved, step = cv2.solve(jac[:, 1:3], (target - uv)[:, None])
            if not solved:
                break
            step = step.ravel()
            q[1:3] += step
            if np.abs(step).max() < TILT_LAST_STEP_RAD:
                break
        return q

    def _updated_step(self, frame, gains, uv_guess, which):
        """Pyramidal LK of the corners in ``which`` from their updated templates.

        Returns (start positions (12, 2), tracked (12,) bool); untracked corners
        keep ``uv_guess``."""
        uv = uv_guess.copy()
        ok = np.zeros(TIP, bool)
        which = which & np.array([t is not None for t in self._tmpl_img])
        if not which.any():
            return uv, ok
        g, origin = self._region_map(frame, gains, uv_guess)
        if g is None:
            return uv, ok
        u8 = to_uint8(g)
        groups: dict[int, list[int]] = {}
        for k in np.flatnonzero(which):
            groups.setdefault(id(self._tmpl_img[k]), []).append(k)
        for ks in groups.values():
            ks = np.array(ks)
            tmpl = self._tmpl_img[ks[0]]
            res, fb = track_updated(tmpl.u8(), tmpl.origin, self._tmpl_uv[ks], u8, origin,
                                    uv_guess[ks], self.options.lk_half_px,
                                    self.options.pyramid_levels)  # fmt: skip
            good = fb < FB_MAX_PX
            uv[ks[good]] = res[good]
            ok[ks[good]] = True
        return uv, ok

    def _keep_previous(self, frame, gains, measured, start_uv, tracked) -> None:
        """Matthews et al.'s rule: a corner's updated template moves on to this frame
        when its drift correction agreed with the updated-template track (within
        UPDATE_EPS_PX), or when it was not tracked from a template this frame;
        otherwise it keeps its old one."""
        found = np.isfinite(measured).all(axis=1)
        agree = np.hypot(*(measured - start_uv).T) < UPDATE_EPS_PX
        move = found & (~tracked | agree)
        if not move.any():
            return
        origin = self._region(frame, measured[found])
        if origin is None:
            return
        u0, v0 = origin.astype(int)
        rw, rh = self._region_size
        # A copy of the region; its contrast map is made only if a later frame needs it.
        entry = _Template(frame[v0 : v0 + rh, u0 : u0 + rw].copy(), origin, gains)
        for k in np.flatnonzero(move):
            self._tmpl_img[k] = entry
            self._tmpl_uv[k] = measured[k]

    def _refine(self, frame, gains, templates, start_uv, active):
        """Drift correction of every active corner against its warped rest patch.

        The LK runs first in patches NEAR_MARGIN_PX around the start, then again
        in the full ``roi_margin_px`` for the corners it lost there: the same
        result as one run in the full margin (its path and samples are the same
        until it leaves the smaller patch), from ~40% of the pixels."""
        opts = self.options
        half = opts.lk_half_px + opts.roi_margin_px
        active = active & self._patches_inside(frame, start_uv, half)[0]
        if opts.subpixel != "lk":  # template matching searches the whole patch
            patches, origins, _ = self._share_patches(frame, gains, start_uv, half)
            return match_parabolic(patches, origins, templates, start_uv, active)
        near = opts.lk_half_px + min(NEAR_MARGIN_PX, opts.roi_margin_px)
        patches, origins, _ = self._share_patches(frame, gains, start_uv, near)
        uv, qual = refine_first_template(patches, origins, templates, start_uv, active)
        again = active & np.isnan(qual)
        if near < half and again.any():
            patches, origins, _ = self._share_patches(frame, gains, start_uv, half)
            uv_f, q_f = refine_first_template(patches, origins, templates, start_uv, again)
            uv[again], qual[again] = uv_f[again], q_f[again]
        return uv, qual

    @staticmethod
    def _patches_inside(frame, uv, half):
        """Corners whose patch of 2 half + 1 px around ``uv`` lies inside the frame,
        and the patches' top-left pixels (0 where not)."""
        h, w = frame.shape[:2]
        return _patch_corners(np.asarray(uv, float), half, h, w)

    def _share_patches(self, frame, gains, uv, half):
        """Red-share (cross) or blue-share (square) patches around each corner.

        Returns patches (12, 2 half + 1, 2 half + 1) float32, their origins (12, 2)
        and whether each lies inside the frame."""
        n = 2 * half + 1
        inside, tl = self._patches_inside(frame, uv, half)
        scale = self._cloth_now / self.cloth_rest
        wgt = (self.weights * gains[None, :] / scale).astype(np.float32)  # (2, 3) red, blue
        # The cross's corners read the red share, the square's the blue share.
        patches = share_patches(frame, tl, n, wgt[self._is_square.astype(int)])
        return patches, tl.astype(float), inside

    def _templates(self, q):
        """Rest patches warped to pose q, shape (12, n, n); reused while q stays
        within TEMPLATE_REUSE of the pose they were warped for."""
        cached = getattr(self, "_tmpl_cache", None)
        if cached is not None and np.all(np.abs(cached[0] - q) <= TEMPLATE_REUSE):
            return cached[1]
        out = self._warp_templates(q)
        self._tmpl_cache = (np.array(q, float), out)
        return out

    def _warp_templates(self, q):
        d1 = self.model.edge_directions(q, step_mm=0.05)
        # A maps rest-image directions to current-image directions: A d0 = d1.
        a = np.swapaxes(d1, 1, 2) @ self._rest_dirs_inv
        half = self.options.lk_half_px
        sq = warp_templates(self.rest_blue, self.rest_origin, self.rest_uv[:N_SQUARE],
                            a[:N_SQUARE], half)  # fmt: skip
        cr = warp_templates(self.rest_red, self.rest_origin, self.rest_uv[N_SQUARE:TIP],
                            a[N_SQUARE:TIP], half)  # fmt: skip
        return np.concatenate([sq, cr])

    def _occluded(self, q, uv):
        """Corners whose window something nearer covers (or nearly) at pose q, shape (12,).

        The rod can cover any corner; the cross can cover the square's corners
        (at large tilts its arm ends pass over them)."""
        _, rod, cross = self.model.outlines(q)
        hull = cv2.convexHull(rod.astype(np.float32))
        cross = cross.astype(np.float32)
        reach = self.options.lk_half_px * math.sqrt(2) + OCCLUSION_MARGIN_PX
        out = np.zeros(TIP, bool)
        for k in range(TIP):
            pt = (float(uv[k, 0]), float(uv[k, 1]))
            out[k] = cv2.pointPolygonTest(hull, pt, True) > -reach
            if k < N_SQUARE:
                out[k] |= cv2.pointPolygonTest(cross, pt, True) > -reach
        return out

    def _fit(self, measured, q0) -> PoseFit:
        return fit_pose(self.model, measured, self.offsets, q0, self._weights,
                        self.options.fit_shift)

    @staticmethod
    def _paper_widths(uv) -> np.ndarray:
        """Projected widths (px) for eq. (2): cross b_u, b_v, square t_u, t_v, shape (4,).

        Each is NaN where one of its points is not tracked."""
        p = uv.tolist()  # a few sums: Python floats, without numpy's per-call cost
        arm = [((p[k][0] + p[k + 1][0]) / 2, (p[k][1] + p[k + 1][1]) / 2)
               for k in range(N_SQUARE, TIP, 2)]  # fmt: skip
        sq = p[:N_SQUARE]
        return np.array([
            arm[0][0] - arm[2][0],
            arm[1][1] - arm[3][1],
            (sq[1][0] + sq[2][0] - sq[0][0] - sq[3][0]) / 2,
            (sq[2][1] + sq[3][1] - sq[0][1] - sq[1][1]) / 2,
        ])  # fmt: skip

    def _paper_solve(self, uv):
        """Eqs. (2)-(7) on tracked points: (dz_mm, phi_deg, theta_deg); NaN if untracked.

        Eq. (2) takes b_u; where an arm end is hidden it substitutes b_v, then the
        square's t_u, t_v ("any can be substituted", section II.B)."""
        widths_i, tip_i = self._paper_rest
        widths_n = self._paper_widths(uv)
        usable = np.isfinite(widths_n) & np.isfinite(widths_i)
        if not (usable.any() and np.isfinite(uv[TIP]).all()):
            return (math.nan, math.nan, math.nan)
        k = int(np.argmax(usable))
        dz, phi, theta = self.paper.solve(widths_i[k], widths_n[k : k + 1], tip_i, uv[TIP][None, :])
        return float(dz[0]), math.degrees(phi[0]), math.degrees(theta[0])

    def _result(self, fit, measured, quality, n_corners, ok, reason) -> FrameResult:
        paper = self._paper_solve(measured)
        if fit is None or not fit.converged:
            return FrameResult(self._index, math.nan, math.nan, math.nan, False,
                               (math.nan,) * 3, paper, reason=reason, points_uv=measured,
                               quality=quality, n_corners=n_corners)  # fmt: skip
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
            self._index, dz, phi, theta, ok, model, paper, pose.sx_mm, pose.sy_mm,
            math.degrees(fit.phi_sigma_rad), fit.rms_px, n_corners, reason, measured, quality,
        )  # fmt: skip

    def _fail(self, reason: str) -> FrameResult:
        self._lost = True
        return FrameResult.untrusted(self._index, reason)


class _Template:
    """An updated template: a frame's region (BGR copy), its origin and gains;
    the 8-bit contrast map for OpenCV's LK is made on first use."""

    def __init__(self, bgr: np.ndarray, origin: np.ndarray, gains: np.ndarray):
        self.bgr, self.origin, self.gains = bgr, origin, gains
        self._u8 = None

    def u8(self) -> np.ndarray:
        if self._u8 is None:
            self._u8 = to_uint8(contrast_map(self.bgr, self.gains))
        return self._u8


@njit(cache=True, nogil=True, error_model="numpy")
def _patch_corners(uv, half, h, w):
    """FrontEnd._patches_inside in one compiled pass over the corners."""
    n = 2 * half + 1
    inside = np.zeros(uv.shape[0], np.bool_)
    tl = np.zeros((uv.shape[0], 2), np.intp)
    for k in range(uv.shape[0]):
        u, v = uv[k, 0], uv[k, 1]
        if not (np.isfinite(u) and np.isfinite(v)):
            continue
        u0, v0 = int(np.rint(u)) - half, int(np.rint(v)) - half
        if u0 >= 0 and v0 >= 0 and u0 + n <= w and v0 + n <= h:
            inside[k] = True
            tl[k, 0], tl[k, 1] = u0, v0
    return inside, tl


def _moved(q1: np.ndarray, q0: np.ndarray) -> bool:
    """Whether the pose changed enough to reshape the tip's model rim."""
    dz, a, b, sx, sy = (abs(x - y) for x, y in zip(q1.tolist(), q0.tolist(), strict=True))
    return max(dz, sx, sy) > RIM_REFIT_MM or max(a, b) > RIM_REFIT_RAD


def track(
    frames: Iterable[np.ndarray],
    sensor: Sensor,
    options: FrontEndOptions | None = None,
    rest_index: int = 0,
) -> Iterator[FrameResult]:
    """Yield one :class:`FrameResult` per frame; frame ``rest_index`` is the rest reference.

    Frames before the rest frame are yielded as untrusted rows.

    Raises
    ------
    FeaturesNotFound
        The rest frame lacks a feature.
    """
    if rest_index < 0:
        raise ValueError(f"rest_index must be >= 0, got {rest_index}")
    fe = FrontEnd(sensor, options)
    for i, frame in enumerate(frames):
        if i < rest_index:
            yield FrameResult.untrusted(i, "before the rest frame")
        elif i == rest_index:
            yield fe.start(frame, i)
        else:
            yield fe.update(frame, i)
