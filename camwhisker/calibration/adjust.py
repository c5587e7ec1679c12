"""Bundle adjustment of a sensor's intrinsics and plate geometry over a sweep.

Unknowns: the geometry of ``GEOMETRY_NAMES`` (camera intrinsics and
distortion, the ``[plate]`` dimensions) and, per frame off rest, the pose
(dz_mm, a_rad, b_rad). The residuals are the tracked image points (12 corners
and the tip, :mod:`camwhisker.sensor.model`) minus the model's, under a Huber loss on
each point's distance, scaled to that point's own scatter. The normal
equations are solved by Levenberg-Marquardt with the per-frame pose blocks
eliminated (Schur complement), so a sweep of hundreds of frames costs little
more than its geometry.

Gauges, and what holds them:

- Frames at rest have pose zero (that is what rest means): they fix dz = 0
  against the depth z_i. Their tip does not count: the front end reads the tip
  at rest up to 0.3 px off where it reads it once tilted, a constant the
  moving frames do not share.
- The lateral shift (sx, sy) is held at zero: a free shift lets the depth of
  the rotation centre trade off against the features' depths.
- The overall scale is invisible in the images: one known length (the
  square's side, measured with calipers) must be held at its value, or frames
  with a known dz (a stage's axial steps) given: a prior on their poses.

Known dz steps and dz's scale: with a known length, the sweep still leaves dz's
gain weakly determined (z_i and fx trade off, and a tilt-dependent tracking error
moves them together). The steps measure that gain directly: after the fit, their
frames' dz is read at the fitted geometry (each video's rest offsets taken out, as
the front end does), a line through the pauses gives the gain and its SE, and the
geometry is moved to make it one, weighted against the fit's full covariance (a
Kalman update along ``dz_gain_response``). Without a length the steps' prior on
the poses also holds the scale's gauge. ``DzScale`` says how well the gain is
known, from the sweep and with the steps.

The tracked corners: a tracked corner is the plate point that its rest
template is centred on, the detected corner, which lies off the true corner
by a constant (blur rounds a corner, compression moves an edge). With
``corner_shifts`` each video's corners carry that offset as an in-plane shift
in the plate, fitted under a prior: centred where an independent measurement
of the true corner at rest puts it (``corner_offsets_uv``, the crossing of
its edges' lines), with that measurement's error as its SD. A constant
per-point error is then a parameter, not geometry, and its uncertainty enters
every SE.

Weights: each point's residuals are weighted by its own noise SD, its robust
residual SD (its degrees of freedom less the share of the poses it absorbs)
inflated for the frame-to-frame correlation of its residuals, measured at the
solution and the fit repeated until they agree. A point measured worse (the
tip, whose rim and rod the front end places by the sensor file being fitted,
or a corner a spring disturbs) then weighs less. The shifts' prior keeps its
own SD.

Determinability: the standard error (SE) of every fitted parameter is the
larger of two: the Gauss-Newton covariance at the solution, and the sandwich
covariance with the residuals' scores summed over blocks of ``BLOCK_FRAMES``
(tracking errors drift: within a block they may correlate in any way). A
parameter whose SE exceeds ``SE_LIMIT`` times its build tolerance
(``tolerances``) is not determined by the sweep: it is held at its nominal
value, the worst first, and the rest fitted again.

Both leave out what no residual shows: a tracking error that grows smoothly with
the tilt, which the fit takes into the geometry. Each point is given one per
coordinate, c1 a/PHI0 + c2 b/PHI0 + c3 (a^2 + b^2)/PHI0^2 with each c of SD
``SYSTEMATIC_PX`` (measured on tuning builds) or more where the point's residuals,
regressed on the terms, show more (:func:`systematic_px`: a tracker worse than the
tuning builds'), and the geometry's linear response to them adds to every variance
and covariance. Which parameters to hold is decided without it:
holding one does not remove that error, it passes it to the parameters correlated
with the held one and adds its own (up to its tolerance).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from camwhisker.sensor.file import Sensor, SensorFileError
from camwhisker.sensor.model import (
    GEOMETRY_NAMES,
    TIP,
    PlateModel,
    build_tolerances,
    geometry_vector,
    with_geometry,
)
from camwhisker.vision.mismatch import CHECK_DZ_MM, CHECK_PHI_DEG, dz_gain_response, phi_response

__all__ = [
    "HUBER_PX",
    "SE_LIMIT",
    "PHI_MIN_SWEEP_DEG",
    "Adjustment",
    "DzScale",
    "step_levels",
    "steps_gain",
    "tolerances",
    "adjust_geometry",
    "corner_shift_jacobian",
    "bias_terms",
    "systematic_px",
]

#: The Huber loss is quadratic within this distance of a point's model (px):
#: above the tracking noise (~0.1 px), below a mistracked corner (pixels).
HUBER_PX = 0.5
#: Once its residuals are measured, a point's Huber distance is this many times its
#: own robust scatter (px per coordinate), up to HUBER_PX: a corner that a spring
#: reaches in some frames of the sweep then counts less in those frames alone.
HUBER_SCATTERS = 3.0
#: Median of a 2D normal vector's length, in SDs per coordinate: sqrt(2 ln 2).
_RAYLEIGH_MEDIAN = math.sqrt(2 * math.log(2))
#: A parameter whose SE exceeds this fraction of its build tolerance is held:
#: the sweep says less about it than the build's tolerance already does.
SE_LIMIT = 0.5
#: A sweep whose largest tilt stays below this (deg) leaves the depths and the
#: distortion poorly determined.
PHI_MIN_SWEEP_DEG = 15.0
#: Prior SD of a tracked corner's in-plane shift about the one its measured offset
#: gives (mm): the edges' crossings' error on tuning builds (0.0053 mm RMS over the
#: moving frames, 0.010 at rest alone: compression moves an edge, the same way in
#: every still frame); and where none was measured (the detected corner taken as the
#: true one): the detection's error.
CORNER_SHIFT_MM = 0.006
CORNER_SHIFT_UNMEASURED_MM = 0.03
#: Frames whose residuals the sandwich SE lets correlate freely: 1 s at 30 fps, longer
#: than the tracking errors take to drift.
BLOCK_FRAMES = 30
#: SD (px) of a point's tilt-dependent tracking error at PHI0 of tilt, per term: the
#: tracked-minus-true points of tuning builds 0-4 regressed on the terms, the RMS
#: coefficient (0.074 px) less the regressions' own noise (0.021 px), in quadrature.
SYSTEMATIC_PX = 0.071
SYSTEMATIC_PHI0_RAD = math.radians(20.0)
#: The frame-to-frame residual correlation used for the noise SD is capped here.
MAX_FRAME_CORRELATION = 0.95
#: The residuals' SD (px) assumed before the first fit measures it, and the
#: relative change of the measured one below which the fit is not repeated.
NOISE_START_PX = 0.1
NOISE_RTOL = 0.1
#: Fewest degrees of freedom a point's own noise SD is measured from.
MIN_NOISE_DOF = 20
#: Fits with the noise SDs updated, at most.
_NOISE_PASSES = 4
#: Points a frame needs for its pose (3 unknowns) to be checked by the others.
MIN_POINTS = 4
#: SD of a known dz (mm) per stage pause: a stage's step error.
KNOWN_DZ_SD_MM = 0.001
#: Fewest distinct known dz levels (pauses) whose line gives dz's gain.
MIN_STEP_LEVELS = 3
#: The geometry is moved along the steps' gain until they read it within this many of its
#: SEs of one, in this many passes at most (the gain's response is linear to ~1 %).
STEP_GAIN_RTOL = 0.1
_STEP_PASSES = 4
#: Warn when dz's gain is known from the sweep alone to no better than this (1 SE,
#: relative): the paper's test 2 reads dz to ~0.3 % of its 1 mm range.
DZ_GAIN_WARN = 0.003
#: Warn where the steps' gain and the sweep's differ by more than this many combined SEs.
STEPS_DISAGREE_SE = 3.0
#: Parameters no sweep determines, always held at nominal, and why.
ALWAYS_HELD = {
    "plate.rod_diameter_mm": "moves only the tip's centroid, at second order: held at nominal",
}
#: Ridge (relative to the mean diagonal) that keeps an exactly singular reduced
#: system solvable; a gauge direction then gets an SE of ~1e5 tolerances.
_RIDGE = 1e-10
#: Iterations at most; fewer for the poses alone at the start: they only start the
#: geometry's fit, which moves them again, and the start geometry's px-sized
#: residuals make Huber's reweighting converge slowly.
_MAX_ITER = 60
_START_ITER = 10
#: Iterations stop when the cost (residuals in units of their SD, squared) falls by
#: less than this: the last steps crawl along directions the sweep hardly determines.
COST_ATOL = 0.01


def tolerances(sensor: Sensor) -> np.ndarray:
    """Each parameter's build tolerance, in the order of ``GEOMETRY_NAMES``."""
    return build_tolerances(sensor)


@dataclass(frozen=True)
class DzScale:
    """How well dz's scale (its gain, read over true, at ``CHECK_DZ_MM``) is known.

    Attributes
    ----------
    se_sweep : float
        Relative SE of the gain from the sweep's fit (its full covariance).
    se : float
        ... after the known dz steps (``se_sweep`` without them).
    steps_gain, steps_gain_se : float
        The gain the steps measured on the sweep's fit, and its relative SE (NaN
        without steps): the fit's geometry was then moved to make it one.
    """

    se_sweep: float = math.nan
    se: float = math.nan
    steps_gain: float = math.nan
    steps_gain_se: float = math.nan

    def text(self) -> str:
        """One line for the user."""
        out = f"dz's scale known to +-{100 * self.se_sweep:.2f} % (1 SE) from the sweep"
        if math.isfinite(self.steps_gain):
            out += (f"; +-{100 * self.se:.2f} % with the known dz steps (they read the "
                    f"sweep's fit's dz x{self.steps_gain:.4f} +- {100 * self.steps_gain_se:.2f} %)")
        return out

    def warnings(self) -> list[str]:
        """A warning where the sweep leaves dz's scale weakly determined, or where the
        steps read the sweep's fit's dz off by more than both their SEs explain."""
        if math.isfinite(self.steps_gain):
            z = abs(self.steps_gain - 1.0) / math.hypot(self.se_sweep, self.steps_gain_se)
            if not z > STEPS_DISAGREE_SE:
                return []
            return [f"the known dz steps read the sweep's fit's dz x{self.steps_gain:.4f}, "
                    f"{z:.1f} SE from one: the sweep's or the steps' tracking is biased (the "
                    "fit follows the steps); check the dz RMSE against a stage run"]
        if not self.se > DZ_GAIN_WARN:
            return []
        return [f"dz's scale is known to +-{100 * self.se:.2f} % (1 SE) from the sweep alone "
                f"(> {100 * DZ_GAIN_WARN:g} %): add a video of known dz steps "
                "(--dz-steps VIDEO LOG, the paper's test 2) to pin it"]


@dataclass(frozen=True)
class Adjustment:
    """The adjusted geometry, its standard errors and the residuals.

    Attributes
    ----------
    sensor : Sensor
        The nominal sensor with the fitted geometry.
    nominal, value, se : ndarray, shape (len(GEOMETRY_NAMES),)
        Nominal and fitted values, standard errors (NaN where held).
    se_data : ndarray, shape (len(GEOMETRY_NAMES),)
        The SEs without the tilt-dependent tracking error: what the sweep's data
        say, which decides what is held and when the rounds are stable.
    covariance : ndarray, shape (G, G)
        The covariance behind ``se``; zero in a held parameter's row and column.
    held : dict
        Held parameter name -> why.
    q : ndarray, shape (F, 5)
        Per-frame poses (dz_mm, a_rad, b_rad, sx_mm, sy_mm); NaN for unused frames.
    residual_uv : ndarray, shape (F, 13, 2)
        Tracked minus model pixels; NaN where a point was not tracked.
    used : ndarray of bool, shape (F,)
        Frames in the adjustment (enough tracked points).
    sigma_px : float
        Robust residual standard deviation per coordinate.
    n_iter : int
    corner_shifts_mm : ndarray, shape (V, 12, 2)
        Each video's tracked corners' in-plane shifts (x, y) in the plate.
    noise_px : ndarray, shape (13,)
        Each point's noise SD per coordinate, which weights its residuals: their
        robust SD inflated for their frame-to-frame correlation.
    warnings : list of str
    dz_scale : DzScale
        How well dz's gain is known, with and without known dz steps.
    """

    sensor: Sensor
    nominal: np.ndarray
    value: np.ndarray
    se: np.ndarray
    se_data: np.ndarray
    covariance: np.ndarray
    held: dict
    q: np.ndarray
    residual_uv: np.ndarray
    used: np.ndarray
    sigma_px: float
    n_iter: int
    corner_shifts_mm: np.ndarray
    noise_px: np.ndarray
    warnings: list = field(default_factory=list)
    dz_scale: DzScale = field(default_factory=DzScale)

    @property
    def names(self) -> tuple[str, ...]:
        return GEOMETRY_NAMES

    @property
    def phi_max_deg(self) -> float:
        return float(np.degrees(np.nanmax(np.hypot(self.q[:, 1], self.q[:, 2]))))

    def phi_se_deg(self, phi_deg: float = CHECK_PHI_DEG) -> float:
        """SE of phi at ``phi_deg`` read with the fitted file, from the fitted
        parameters' covariance (held ones count as exact), in the worst direction."""
        response = phi_response(PlateModel(self.sensor), phi_deg)
        return float(np.sqrt(np.einsum("tg,gh,th->t", response, self.covariance, response).max()))

    def rms_per_point_px(self) -> np.ndarray:
        """RMS residual distance of each tracked point over the used frames, shape (13,)."""
        d2 = np.sum(self.residual_uv[self.used] ** 2, axis=-1)
        return np.sqrt(np.nanmean(d2, axis=0))

    def rms_per_frame_px(self) -> np.ndarray:
        """RMS residual distance over each frame's tracked points, shape (F,)."""
        d2 = np.sum(self.residual_uv**2, axis=-1)
        with np.errstate(invalid="ignore"):
            return np.sqrt(np.nanmean(np.where(np.isnan(d2).all(axis=1)[:, None], 0.0, d2), axis=1))


@dataclass
class _Problem:
    """What one solve works on: observations, which frames and parameters, scaling."""

    obs: np.ndarray  # (F, 13, 2)
    valid: np.ndarray  # (F, 13)
    rest: np.ndarray  # (F,)
    video: np.ndarray  # (F,) each frame's video
    sensor: Sensor
    tol: np.ndarray  # (G + 2 TIP V,): the geometry's, then the shifts' prior SDs (mm)
    shift_prior: np.ndarray  # (2 TIP V,): the shifts' prior centres (mm)
    free: np.ndarray  # indices into the geometry, then the shifts
    huber_max_px: float
    huber_px: np.ndarray  # (13,) each point's Huber distance (px), at most huber_max_px
    noise_px: np.ndarray  # (13,) each point's residuals' SD per coordinate: their weight
    known_dz: np.ndarray  # (F,) a known dz (mm) per frame, NaN where none
    known_dz_sd: np.ndarray  # (F,) its SD per frame (mm)


@dataclass
class _Normal:
    """The robust normal equations at one point: geometry block U (n, n), its
    right side bg (n,), pose blocks V (F, 3, 3), bp (F, 3), couplings W (F, n, 3)."""

    cost: float
    U: np.ndarray
    bg: np.ndarray
    V: np.ndarray
    bp: np.ndarray
    W: np.ndarray
    residual: np.ndarray  # (F, 13, 2)
    weight: np.ndarray  # (F, 13)
    bg_frame: np.ndarray  # (F, n): each frame's share of bg
    leverage: np.ndarray  # (F, 13): each point's share of its frame's pose (two coordinates)
    systematic: np.ndarray  # (13, 2, 3, n): the reduced score's response to each bias term


def _huber(dist: np.ndarray, k: float) -> tuple[np.ndarray, np.ndarray]:
    """Huber loss of point distances and its IRLS weights."""
    quad = dist <= k
    rho = np.where(quad, dist**2, 2 * k * dist - k * k)
    with np.errstate(divide="ignore", invalid="ignore"):
        w = np.where(quad, 1.0, k / dist)
    return rho, w


def corner_shift_jacobian(model: PlateModel, q5: np.ndarray) -> np.ndarray:
    """d uv / d each tracked corner's in-plane (x, y) position in the plate, (12, 2, 2);
    at poses of shape (F, 5), (F, 12, 2, 2).

    Not in :class:`PlateModel`: its Jacobians are by the shared dimensions only.
    """
    q5 = np.asarray(q5, dtype=float)
    d_point = model.jacobians_many(q5.reshape(-1, 5)).corner_point[..., :2]
    return d_point.reshape(*q5.shape[:-1], TIP, 2, 2)


@dataclass
class _Rows:
    """The rows of the frames ``frames`` (Fa,): residuals r (Fa, 13, 2), zero where a
    point does not count, its Huber loss rho and weight w (Fa, 13), the weights' square
    roots over the noise sw (Fa, 26), and in units of the noise the residuals rw (Fa, 26),
    the free parameters' Jacobian jg (Fa, 26, n) and the poses' jp (Fa, 26, 3)."""

    frames: np.ndarray
    r: np.ndarray
    rho: np.ndarray
    w: np.ndarray
    sw: np.ndarray
    rw: np.ndarray
    jg: np.ndarray
    jp: np.ndarray


def _rows(p: _Problem, model: PlateModel, shifts: np.ndarray, q: np.ndarray) -> _Rows:
    """Every frame with a point that counts, linearised at the model, the corners'
    shifts (V, 12, 2) and the poses q (F, 3)."""
    frames = np.flatnonzero(p.valid.any(axis=1))
    n_a, m = len(frames), p.valid[frames]
    q5 = np.zeros((n_a, 5))
    q5[:, :3] = q[frames]
    jac = model.jacobians_many(q5)
    d_corner = jac.corner_point[..., :2]  # (Fa, 12, 2, 2)
    video = p.video[frames]
    uv = jac.uv.copy()
    uv[:, :TIP] += np.einsum("fjab,fjb->fja", d_corner, shifts[video])  # first order
    r = np.where(m[..., None], p.obs[frames] - uv, 0.0)
    rho, w = _huber(np.linalg.norm(r, axis=-1), p.huber_px)
    rho, w = np.where(m, rho, 0.0), np.where(m, w, 0.0)
    sw = np.repeat(np.sqrt(w) / p.noise_px, 2, axis=1)  # residuals in units of their SD
    # Each video's shifts: block-diagonal, each shift moves its own corner in its frames.
    d_shift = np.zeros((n_a, TIP + 1, 2, len(shifts), TIP, 2))
    f, j = np.arange(n_a)[:, None], np.arange(TIP)[None]
    d_shift[f, j, :, video[:, None], j, :] = d_corner
    d_all = np.concatenate([jac.geometry, d_shift.reshape(n_a, TIP + 1, 2, -1)], axis=-1)
    n_rows = 2 * (TIP + 1)
    jg = (d_all[..., p.free] * p.tol[p.free]).reshape(n_a, n_rows, len(p.free)) * sw[..., None]
    jp = jac.pose[..., :3].reshape(n_a, n_rows, 3) * sw[..., None]
    return _Rows(frames, r, rho, w, sw, r.reshape(n_a, -1) * sw, jg, jp)


def _normal(p: _Problem, g: np.ndarray, q: np.ndarray) -> _Normal | None:
    """Linearise at g (the geometry, then the corners' shifts) and poses q (F, 3);
    None if g is not a valid sensor."""
    n_geo = len(GEOMETRY_NAMES)
    try:
        model = PlateModel(with_geometry(p.sensor, g[:n_geo]))
    except SensorFileError:
        return None
    n_f, n = len(q), len(p.free)
    rows = _rows(p, model, g[n_geo:].reshape(-1, TIP, 2), q)
    frames, jg, jp, rw = rows.frames, rows.jg, rows.jp, rows.rw
    cost = float(np.sum(rows.rho / p.noise_px**2))
    residual = np.full((n_f, TIP + 1, 2), np.nan)
    residual[frames] = np.where(p.valid[frames][..., None], rows.r, np.nan)
    weight = np.zeros((n_f, TIP + 1))
    weight[frames] = rows.w
    # Summed over per-frame products: BLAS threads one large one, and busy cores stall them.
    U = (jg.transpose(0, 2, 1) @ jg).sum(axis=0)
    bg_frame = np.zeros((n_f, n))
    bg_frame[frames] = np.einsum("fri,fr->fi", jg, rw)
    bg = bg_frame.sum(axis=0)
    V, bp, W = np.zeros((n_f, 3, 3)), np.zeros((n_f, 3)), np.zeros((n_f, n, 3))
    leverage = np.zeros((n_f, TIP + 1))
    moving = ~p.rest[frames]
    fm, jg, jp, rw = frames[moving], jg[moving], jp[moving], rw[moving]
    V[fm] = jp.transpose(0, 2, 1) @ jp
    bp[fm] = np.einsum("fri,fr->fi", jp, rw)
    W[fm] = jg.transpose(0, 2, 1) @ jp
    k = fm[np.isfinite(p.known_dz[fm])]  # a prior on the pose's dz, in units of its SD
    r_dz = (p.known_dz[k] - q[k, 0]) / p.known_dz_sd[k]
    V[k, 0, 0] += p.known_dz_sd[k] ** -2
    bp[k, 0] += r_dz / p.known_dz_sd[k]
    cost += float(np.sum(r_dz**2))
    v_inv = np.linalg.pinv(V[fm]) if len(fm) else np.zeros((0, 3, 3))
    # The hat matrix's diagonal: how much of each residual the pose absorbs.
    hat = np.sum((jp @ v_inv) * jp, axis=-1)
    leverage[fm] = hat.reshape(len(fm), TIP + 1, 2).sum(axis=-1)
    # What of the geometry's rows the pose cannot absorb, per pixel of bias.
    reduced = (jg - jp @ (v_inv @ W[fm].transpose(0, 2, 1))) * rows.sw[moving][..., None]
    systematic = np.einsum("fjcn,fk->jckn", reduced.reshape(len(fm), TIP + 1, 2, n),
                           bias_terms(q[fm]))  # fmt: skip
    cost += _add_shift_prior(p, g, U, bg)
    return _Normal(cost, U, bg, V, bp, W, residual, weight, bg_frame, leverage, systematic)


def _add_shift_prior(p: _Problem, g: np.ndarray, U: np.ndarray, bg: np.ndarray) -> float:
    """Add the free shifts' prior to U and bg, in units of its SD (residual: centre -
    shift, Jacobian 1); returns its cost."""
    n_geo = len(GEOMETRY_NAMES)
    is_shift = p.free >= n_geo
    k = p.free[is_shift] - n_geo
    x = (g[n_geo:][k] - p.shift_prior[k]) / p.tol[p.free[is_shift]]
    U[is_shift, is_shift] += 1.0
    bg[is_shift] -= x
    return float(x @ x)


def bias_terms(q3: np.ndarray) -> np.ndarray:
    """The tilt-dependent tracking error's terms at pose (dz, a, b), shape (3,); at
    poses of shape (F, 3), (F, 3)."""
    q3 = np.asarray(q3, dtype=float)
    a, b = q3[..., 1] / SYSTEMATIC_PHI0_RAD, q3[..., 2] / SYSTEMATIC_PHI0_RAD
    return np.stack([a, b, a * a + b * b], axis=-1)


def _reduced(ne: _Normal, lam: float, moving: np.ndarray):
    """The Schur complement S and right side of the geometry step, with Marquardt
    damping lam, and the damped pose blocks' inverses (F, 3, 3)."""
    eye3 = np.eye(3)
    vd = ne.V + lam * ne.V * eye3 + np.where(moving, 0.0, 1.0)[:, None, None] * eye3
    vinv = np.linalg.inv(vd)
    wv = ne.W @ vinv  # (F, n, 3)
    S = ne.U + lam * np.diag(np.diag(ne.U)) - np.einsum("fij,fkj->ik", wv, ne.W)
    rhs = ne.bg - np.einsum("fij,fj->i", wv, ne.bp)
    n = len(S)
    if n:
        S = S + _RIDGE * max(np.trace(S) / n, 1e-300) * np.eye(n)
    return S, rhs, vinv


def _step(ne: _Normal, lam: float, moving: np.ndarray):
    """Levenberg-Marquardt step: geometry (n,) in tolerance units, poses (F, 3)."""
    S, rhs, vinv = _reduced(ne, lam, moving)
    dg = np.linalg.solve(S, rhs) if len(S) else np.zeros(0)
    dq = np.einsum("fij,fj->fi", vinv, ne.bp - np.einsum("fij,i->fj", ne.W, dg))
    return dg, np.where(moving[:, None], dq, 0.0)


def _solve(p: _Problem, g: np.ndarray, q: np.ndarray, moving: np.ndarray,
           max_iter: int = _MAX_ITER):  # fmt: skip
    """Minimise the robust cost from (g, q); returns g, q, the last normal equations
    and the number of iterations."""
    ne = _normal(p, g, q)
    if ne is None:
        raise SensorFileError("the starting geometry is not a valid sensor")
    lam, n_iter = 1e-3, 0
    while n_iter < max_iter:
        n_iter += 1
        dg, dq = _step(ne, lam, moving)
        g_try = g.copy()
        g_try[p.free] += dg * p.tol[p.free]
        q_try = q + dq
        trial = _normal(p, g_try, q_try)
        if trial is not None and trial.cost <= ne.cost:
            done = ne.cost - trial.cost <= COST_ATOL
            g, q, ne, lam = g_try, q_try, trial, max(lam / 3, 1e-9)
            if done:
                break
        else:
            lam *= 4
            if lam > 1e8:
                break
    return g, q, ne, n_iter


def _noise(ne: _Normal, p: _Problem, moving: np.ndarray
           ) -> tuple[float, np.ndarray, np.ndarray]:  # fmt: skip
    """The robust residual SD per coordinate (px); each point's noise SD, shape
    (13,): its own robust residual SD inflated for its frame-to-frame correlation;
    and each point's Huber distance (13,), ``HUBER_SCATTERS`` times its scatter
    (from its median residual), at most ``huber_max_px``.
    Per point, since a point measured with a biased model (the tip's rim and rod)
    scatters far more than the corners, and must not drag their geometry."""
    n_obs = 2 * int(np.count_nonzero(ne.weight))
    dof = max(n_obs - 3 * int(moving.sum()) - len(p.free), 1)
    r2 = np.nansum(ne.residual**2, axis=-1)
    sigma = float(np.sqrt(np.sum(ne.weight * r2) / dof))
    noise, huber = p.noise_px.copy(), p.huber_px.copy()
    for j in range(TIP + 1):
        # Its dof: its coordinates less the share of the poses they absorb (a point
        # weighted heavily fits its frames' poses itself and shows no residual).
        dof_j = 2 * np.count_nonzero(ne.weight[:, j]) - ne.leverage[:, j].sum()
        if dof_j >= MIN_NOISE_DOF:
            s_j = math.sqrt(np.sum(ne.weight[:, j] * r2[:, j]) / dof_j)
            noise[j] = s_j * math.sqrt(_correlation_inflation(ne.residual[:, j]))
            scatter = np.nanmedian(np.sqrt(r2[:, j][ne.weight[:, j] > 0])) / _RAYLEIGH_MEDIAN
            huber[j] = min(HUBER_SCATTERS * scatter, p.huber_max_px)
    return sigma, noise, huber


def systematic_px(residual: np.ndarray, q: np.ndarray, moving: np.ndarray,
                  noise_px: np.ndarray) -> np.ndarray:  # fmt: skip
    """Each point's tilt-dependent tracking error's SD per term (px), shape (13,): at
    least ``SYSTEMATIC_PX``, more where the fit's residuals (F, 13, 2) regressed on
    :func:`bias_terms` (with a constant) show larger coefficients than their noise
    (``noise_px``) explains: what the geometry could not take in, a floor of the rest."""
    terms = bias_terms(q)
    out = np.full(TIP + 1, SYSTEMATIC_PX)
    for j in range(TIP + 1):
        use = moving & np.isfinite(residual[:, j]).all(axis=1)
        if use.sum() < MIN_NOISE_DOF:
            continue
        x = np.column_stack([np.ones(use.sum()), terms[use]])
        coef = np.linalg.lstsq(x, residual[use, j], rcond=None)[0][1:]  # (3, 2)
        noise = noise_px[j] ** 2 * np.diag(np.linalg.pinv(x.T @ x))[1:, None]
        out[j] = max(SYSTEMATIC_PX, math.sqrt(max(float(np.mean(coef**2 - noise)), 0.0)))
    return out


def _standard_errors(ne: _Normal, p: _Problem, q: np.ndarray, moving: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """SE of the free parameters (their units) from the undamped reduced system, whose
    residuals are in units of their noise SD: the larger of the model's covariance
    S^-1 and the sandwich S^-1 M S^-1 with the residuals' scores summed over blocks
    of ``BLOCK_FRAMES`` (errors correlated in any way within a block, not across),
    and that plus the variance from the tilt-dependent errors (:func:`systematic_px`).
    Third, the covariance behind the second: the sandwich's correlations with those
    variances, plus the tilt-dependent errors' own."""
    if not len(p.free):
        return np.zeros(0), np.zeros(0), np.zeros((0, 0))
    S, _, vinv = _reduced(ne, 0.0, moving)
    score = ne.bg_frame - np.einsum("fij,fj->fi", ne.W @ vinv, ne.bp)  # each frame's share
    # A block never spans two videos, and each video's rest frames are one block.
    in_video = np.where(p.rest, -1, np.arange(len(p.rest)) // BLOCK_FRAMES)
    block = p.video * (len(p.rest) + 1) + in_video
    _, index = np.unique(block, return_inverse=True)
    sums = np.zeros((index.max() + 1, S.shape[0]))
    np.add.at(sums, index, score)
    meat = sums.T @ sums
    is_shift = p.free >= len(GEOMETRY_NAMES)
    meat[is_shift, is_shift] += 1.0  # the prior: an observation of unit variance
    s_inv = np.linalg.inv(S)
    sandwich = s_inv @ meat @ s_inv
    var = np.clip(np.maximum(np.diag(s_inv), np.diag(sandwich)), 0.0, None)
    sys_px = np.repeat(systematic_px(ne.residual, q, moving, p.noise_px), 2 * 3)
    response = s_inv @ ne.systematic.reshape(-1, S.shape[0]).T * sys_px  # (n, 13 * 2 * 3)
    var_sys = np.sum(response**2, axis=1)
    d = np.sqrt(np.clip(np.diag(sandwich), 1e-300, None))
    scale = np.sqrt(var) / d
    cov = sandwich * np.outer(scale, scale) + response @ response.T
    tol = p.tol[p.free]
    return np.sqrt(var) * tol, np.sqrt(var + var_sys) * tol, cov * np.outer(tol, tol)


def _correlation_inflation(residual: np.ndarray) -> float:
    """Variance factor (1 + rho) / (1 - rho) for residuals correlated from one frame
    to the next with lag-1 correlation rho (AR(1)): tracking errors drift smoothly,
    so consecutive frames are not independent measurements."""
    a, b = residual[:-1], residual[1:]
    both = np.isfinite(a) & np.isfinite(b)
    if both.sum() < 10:
        return 1.0
    a, b = a[both], b[both]
    rho = float(np.sum(a * b) / np.sqrt(np.sum(a * a) * np.sum(b * b)))
    rho = min(max(rho, 0.0), MAX_FRAME_CORRELATION)
    return (1 + rho) / (1 - rho)


def _fit_holding(p: _Problem, g, q, moving, nominal, held: dict, se_limit: float):
    """Fit, with the noise SD measured at the solution until it agrees with the one
    used; then hold the free geometry parameter worst determined (SE above
    se_limit tolerances) at nominal and fit again, until none is; ``held``,
    ``p.free`` and ``p.noise_px`` are updated. Returns g, q, the normal
    equations, the free SEs (with and without the tilt-dependent error) and their
    covariance, sigma and the iterations."""
    n_geo, n_iter, passes = len(nominal), 0, 0
    while True:
        g, q, ne, it = _solve(p, g, q, moving)
        n_iter += it
        passes += 1
        sigma, noise, huber = _noise(ne, p, moving)
        change = np.abs(np.concatenate([noise / p.noise_px, huber / p.huber_px]) - 1)
        if change.max() > NOISE_RTOL and passes < _NOISE_PASSES:
            # The weights were off: fit again with the measured SDs and Huber distances.
            p.noise_px, p.huber_px = noise, huber
            continue
        se_data, se_free, cov = _standard_errors(ne, p, q, moving)
        n_free_geo = int(np.count_nonzero(p.free < n_geo))
        # By what the sweep's data say: holding does not remove the tilt-dependent error,
        # it passes it to the parameters correlated with the held one, and adds its own.
        ratio = se_data[:n_free_geo] / p.tol[p.free[:n_free_geo]]
        if not len(ratio) or ratio.max() <= se_limit:
            return g, q, ne, (se_free, se_data, cov), sigma, n_iter
        worst = int(np.argmax(ratio))
        i = int(p.free[worst])
        held[GEOMETRY_NAMES[i]] = (
            f"not determined by the sweep (SE {se_data[worst]:.3g} > {se_limit} x tolerance "
            f"{p.tol[i]:.3g}): held at nominal"
        )
        g[i] = nominal[i]
        p.free = np.delete(p.free, worst)


def _shift_prior(sensor: Sensor, offsets_uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The shifts' prior centres (mm) from the corners' rest offsets (px), and their
    SDs (mm): each offset carried into the plate through its corner's Jacobian at rest;
    an unmeasured one (NaN) centres at zero with the wider SD."""
    d_corner = corner_shift_jacobian(PlateModel(sensor), np.zeros(5))  # (12, 2, 2)
    measured = np.isfinite(offsets_uv).all(axis=-1)  # (V, 12)
    centre = np.linalg.solve(d_corner[None], np.nan_to_num(offsets_uv)[..., None])[..., 0]
    centre[~measured] = 0.0
    sd = np.where(measured, CORNER_SHIFT_MM, CORNER_SHIFT_UNMEASURED_MM)
    return centre.reshape(-1), np.repeat(sd.reshape(-1), 2)


def _checked(points_uv, rest, video, corner_offsets_uv, fixed):
    """adjust_geometry's inputs as arrays (and a dict), with their defaults; ValueError
    naming the first that is malformed."""
    points_uv = np.asarray(points_uv, dtype=float)
    rest = np.asarray(rest, dtype=bool)
    n_frames = len(points_uv)
    if points_uv.ndim != 3 or points_uv.shape[1:] != (TIP + 1, 2) or len(rest) != n_frames:
        raise ValueError(f"points_uv must be (F, {TIP + 1}, 2) with one rest flag per frame")
    video = np.zeros(n_frames, int) if video is None else np.asarray(video, dtype=int)
    if video.shape != (n_frames,) or video.min(initial=0) < 0:
        raise ValueError("video must give each frame's video index, 0 or more")
    n_videos = int(video.max(initial=0)) + 1
    if corner_offsets_uv is None:
        corner_offsets_uv = np.full((n_videos, TIP, 2), np.nan)
    corner_offsets_uv = np.asarray(corner_offsets_uv, dtype=float)
    if corner_offsets_uv.shape != (n_videos, TIP, 2):
        raise ValueError(f"corner_offsets_uv must be ({n_videos}, {TIP}, 2): one row per video")
    fixed = dict(fixed or {})
    unknown = set(fixed) - set(GEOMETRY_NAMES)
    if unknown:
        raise ValueError(f"unknown geometry parameter {sorted(unknown)[0]!r}")
    return points_uv, rest, video, corner_offsets_uv, fixed


def adjust_geometry(
    points_uv: np.ndarray,
    sensor: Sensor,
    rest: np.ndarray,
    fixed: dict[str, float] | None = None,
    q0: np.ndarray | None = None,
    corner_shifts: bool = False,
    corner_offsets_uv: np.ndarray | None = None,
    video: np.ndarray | None = None,
    huber_px: float = HUBER_PX,
    se_limit: float = SE_LIMIT,
    known_dz_mm: np.ndarray | None = None,
    known_dz_sd_mm: np.ndarray | float = KNOWN_DZ_SD_MM,
) -> Adjustment:
    """Fit the geometry and per-frame poses to tracked points over a sweep.

    Parameters
    ----------
    points_uv : ndarray, shape (F, 13, 2)
        Tracked image points per frame (12 corners, the tip); NaN where not tracked.
    sensor : Sensor
        The starting (nominal) sensor; held parameters keep its values.
    rest : ndarray of bool, shape (F,)
        Frames at rest (pose zero). At least one is needed.
    fixed : dict, optional
        Parameters held at given values, e.g. ``{"plate.square_side_mm": 5.02}``
        (the known length that fixes the scale).
    q0 : ndarray, shape (F, 3) or (F, 5), optional
        Starting poses (dz_mm, a_rad, b_rad, ...); default zero.
    corner_shifts : bool
        Fit each video's tracked corners' in-plane positions in the plate too,
        under the prior of the module notes; otherwise they are held at its centre.
    corner_offsets_uv : ndarray, shape (V, 12, 2), optional
        Each video's tracked corners minus the true corners at rest (px), measured
        apart from the detection (NaN: not measured); default: none measured.
    video : ndarray of int, shape (F,), optional
        Each frame's video, 0 ... V - 1 (its rest templates); default all 0.
    huber_px, se_limit : float
        See ``HUBER_PX`` (each point's Huber distance at most) and ``SE_LIMIT``.
    known_dz_mm, known_dz_sd_mm : ndarray, shape (F,), optional; float or ndarray
        A frame's known dz (mm; NaN where unknown), such as a stage's axial steps, and
        its SD: they fix dz's gain after the fit (module notes); without a known
        length, also a prior on the frame's pose, which fixes the scale.

    Returns
    -------
    Adjustment
    """
    points_uv, rest, video, corner_offsets_uv, fixed = _checked(points_uv, rest, video,
                                                                corner_offsets_uv, fixed)
    known_dz, known_sd = _checked_dz(known_dz_mm, known_dz_sd_mm, n_frames := len(points_uv))
    n_videos = len(corner_offsets_uv)
    valid, used = _usable(points_uv, rest)
    nominal = geometry_vector(sensor)
    g = nominal.copy()
    g[[GEOMETRY_NAMES.index(name) for name in fixed]] = list(fixed.values())
    start = with_geometry(sensor, g)
    n_geo = len(g)
    shift_prior, shift_sd = _shift_prior(start, corner_offsets_uv)
    g = np.concatenate([g, shift_prior])  # then the corners' shifts (mm)
    q = np.zeros((n_frames, 3)) if q0 is None else np.array(q0, dtype=float)[:, :3]
    q[rest | ~used] = 0.0
    moving = used & ~rest
    tol = np.concatenate([tolerances(sensor), shift_sd])
    held = {n: "held at the given value" for n in fixed} | {
        k: v for k, v in ALWAYS_HELD.items() if k not in fixed}
    # With a known length the steps enter after the fit (_dz_scale), else also as a prior.
    prior = np.full(n_frames, np.nan) if _length_known(fixed) else known_dz
    p = _Problem(points_uv, valid, rest, video, start, tol, shift_prior, np.zeros(0, dtype=int),
                 huber_px, np.full(TIP + 1, huber_px), np.full(TIP + 1, NOISE_START_PX),
                 prior, known_sd)  # fmt: skip
    g, q, ne, n_iter = _solve(p, g, q, moving, _START_ITER)  # the poses alone first
    free_geo = [i for i, n in enumerate(GEOMETRY_NAMES) if n not in held]
    p.free = np.array(free_geo + (list(range(n_geo, len(g))) if corner_shifts else []), int)
    g, q, ne, se_free, sigma, it = _fit_holding(p, g, q, moving, nominal, held, se_limit)
    n_iter += it
    se, se_data, covariance = _geometry_errors(p.free, n_geo, *se_free)
    scaled_by_dz = bool(np.nan_to_num(known_dz)[moving].any())
    g, q, residual, covariance, steps = _dz_scale(p, g, q, moving, known_dz if scaled_by_dz
                                                  else None, covariance, ne.residual)  # fmt: skip
    se = np.where(np.isfinite(se), np.sqrt(np.diag(covariance)), np.nan)
    g, shifts = g[:n_geo], g[n_geo:].reshape(n_videos, TIP, 2)
    q5 = np.where(used[:, None], np.pad(q, ((0, 0), (0, 2))), np.nan)
    return Adjustment(
        with_geometry(sensor, g), nominal, g, se, se_data, covariance, held, q5, residual,
        used, sigma, n_iter, shifts, p.noise_px,
        _warnings(q5, held, fixed, scaled_by_dz) + steps.warnings(), steps,
    )  # fmt: skip


def _usable(points_uv: np.ndarray, rest: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Which points count (F, 13) and which frames (F,): those with MIN_POINTS tracked;
    not the tip at rest (see the module notes). ValueError without a rest frame."""
    valid = np.isfinite(points_uv).all(axis=-1)
    used = valid.sum(axis=1) >= MIN_POINTS
    if not (rest & used).any():
        raise ValueError("no rest frame with enough tracked points: the depth has no zero")
    valid &= used[:, None]
    valid[rest, TIP] = False
    return valid, used


def _geometry_errors(free: np.ndarray, n_geo: int, se, se_data, cov):
    """The free parameters' SEs (with and without the tilt-dependent error) and
    covariance placed in the geometry's order: NaN SEs and zero covariance where held."""
    geo = free[free < n_geo]  # the free geometry comes first, then the shifts
    out_se, out_se_data = np.full((2, n_geo), np.nan)
    out_se[geo], out_se_data[geo] = se[: len(geo)], se_data[: len(geo)]
    covariance = np.zeros((n_geo, n_geo))
    covariance[np.ix_(geo, geo)] = cov[: len(geo), : len(geo)]
    return out_se, out_se_data, covariance


def _length_known(fixed: dict) -> bool:
    """A length (not an offset fixed at zero) is held at a given value: it sets the scale."""
    return any(n.endswith("_mm") and fixed[n] != 0 for n in fixed)


def _gain_variance(sensor: Sensor, g: np.ndarray, covariance: np.ndarray,
                   dz_mm: float = CHECK_DZ_MM) -> float:  # fmt: skip
    """Variance of dz's relative gain at ``dz_mm`` from the geometry's covariance."""
    r = dz_gain_response(PlateModel(with_geometry(sensor, g)), dz_mm)
    return float(r @ covariance @ r)


def _read_dz(p: _Problem, g: np.ndarray, q: np.ndarray, frames: np.ndarray) -> np.ndarray:
    """dz (mm) of ``frames`` (F,) as their images read at the geometry g: their poses
    refitted with the geometry held and without the known dz's prior; NaN elsewhere.
    Each video's mean residual at rest is taken out first, as the front end's rest
    offsets do: else the rest image's mismatch reads as dz in every moving frame."""
    still = replace(p, valid=p.valid & p.rest[:, None], free=np.zeros(0, int))
    rest_residual = _normal(still, g, q).residual
    offsets = np.zeros((int(p.video.max()) + 1, TIP + 1, 2))
    for v in np.unique(p.video[frames]):  # each video's rest offsets, as the front end's
        at_rest = rest_residual[p.rest & (p.video == v)]
        seen = np.isfinite(at_rest)
        offsets[v] = np.nansum(at_rest, axis=0) / np.maximum(seen.sum(axis=0), 1)
    sub = replace(p, obs=p.obs - offsets[p.video], valid=p.valid & frames[:, None],
                  free=np.zeros(0, int), known_dz=np.full(len(frames), np.nan))  # fmt: skip
    return np.where(frames, _solve(sub, g, q, frames)[1][:, 0], np.nan)


def step_levels(known_dz_mm: np.ndarray, video: np.ndarray, read_dz_mm: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Each pause's known dz and the median of its frames' read dz (mm): a pause is a run
    of consecutive frames of one video with one known dz (NaN frames end a run)."""
    has = np.isfinite(known_dz_mm) & np.isfinite(read_dz_mm)
    idx = np.flatnonzero(has)
    if not len(idx):
        return np.zeros(0), np.zeros(0)
    new = np.ones(len(idx), bool)
    new[1:] = ((np.diff(idx) > 1) | (np.diff(known_dz_mm[idx]) != 0)
               | (np.diff(video[idx]) != 0))  # fmt: skip
    runs = np.split(idx, np.flatnonzero(new)[1:])
    return (np.array([known_dz_mm[r[0]] for r in runs]),
            np.array([np.median(read_dz_mm[r]) for r in runs]))  # fmt: skip


def steps_gain(known_mm: np.ndarray, read_mm: np.ndarray) -> tuple[float, float]:
    """dz's gain (read over known, the slope of a line through the pauses' levels) and
    its SE: from the levels' scatter about the line, at least a stage step's error
    (``KNOWN_DZ_SD_MM`` per pause). NaN where fewer than MIN_STEP_LEVELS levels differ."""
    if len(np.unique(known_mm)) < MIN_STEP_LEVELS:
        return math.nan, math.nan
    slope, intercept = np.polyfit(known_mm, read_mm, 1)
    spread = float(np.sum((known_mm - known_mm.mean()) ** 2))
    scatter = float(np.sum((read_mm - slope * known_mm - intercept) ** 2)) / (len(known_mm) - 2)
    sd = max(math.sqrt(scatter), KNOWN_DZ_SD_MM)
    return float(slope), sd / math.sqrt(spread) / abs(float(slope))


def _dz_scale(p: _Problem, g, q, moving, known_dz, covariance, residual):
    """How well the fit knows dz's gain (:class:`DzScale`), and with known dz steps
    (``known_dz``, else None) the fit moved by them (:func:`_scale_from_steps`): returns
    g, q, the residuals, the covariance and the scale."""
    se_gain = math.sqrt(max(_gain_variance(p.sensor, g[: len(GEOMETRY_NAMES)], covariance), 0))
    scale = DzScale(se_gain, se_gain)
    if known_dz is None:
        return g, q, residual, covariance, scale
    return _scale_from_steps(p, g, q, moving, known_dz, covariance, scale)


def _scale_from_steps(p: _Problem, g, q, moving, known_dz, covariance, scale: DzScale):
    """The fit's geometry moved so that the known steps read at their dz: the gain the
    steps measure (:func:`steps_gain`, the poses read at the fitted geometry) taken as
    a measurement of the geometry (``dz_gain_response``), weighted against the fit's full
    covariance (Kalman update: the weakly determined directions move, mostly z_i with
    fx). Returns g, the poses and residuals at it, the updated covariance, and the scale."""
    n_geo = len(GEOMETRY_NAMES)
    frames = moving & np.isfinite(known_dz)
    level = float(np.mean(np.abs(known_dz[frames])))
    gain, gain_se = math.nan, math.nan
    for k in range(_STEP_PASSES):
        found, found_se = steps_gain(*step_levels(known_dz, p.video, _read_dz(p, g, q, frames)))
        if k == 0:
            gain, gain_se = found, found_se
            if not math.isfinite(gain):
                break
            r = dz_gain_response(PlateModel(with_geometry(p.sensor, g[:n_geo])), level)
            gain_c = covariance @ r
            k_gain = gain_c / (r @ gain_c + gain_se**2)
            covariance = covariance - np.outer(k_gain, gain_c)
        elif abs(found - 1.0) < STEP_GAIN_RTOL * gain_se:
            break
        g[:n_geo] += k_gain * (1.0 / found - 1.0)  # the gain's relative error, linearised
    fixed_geo = replace(p, free=np.zeros(0, int))
    g, q, ne, _ = _solve(fixed_geo, g, q, moving)
    se_after = math.sqrt(max(_gain_variance(p.sensor, g[:n_geo], covariance), 0.0))
    return g, q, ne.residual, covariance, replace(scale, se=se_after, steps_gain=gain,
                                                  steps_gain_se=gain_se)  # fmt: skip


def _checked_dz(known_dz_mm, known_dz_sd_mm, n_frames: int):
    """The known dz and its SD as (F,) arrays; ValueError naming what is malformed."""
    known = np.full(n_frames, np.nan) if known_dz_mm is None else np.asarray(known_dz_mm, float)
    sd = np.broadcast_to(np.asarray(known_dz_sd_mm, float), known.shape).copy()
    if known.shape != (n_frames,):
        raise ValueError(f"known_dz_mm must give one value (or NaN) per frame, {n_frames}")
    if not np.all(sd[np.isfinite(known)] > 0):
        raise ValueError("known_dz_sd_mm must be positive where a dz is known")
    return known, sd


def _warnings(q5: np.ndarray, held: dict, fixed: dict, known_dz: bool) -> list[str]:
    """What the user should know about the sweep and the gauge (``known_dz``: a
    moving frame's dz, not zero, is known, which fixes the scale)."""
    out = []
    phi_max = float(np.degrees(np.nanmax(np.hypot(q5[:, 1], q5[:, 2]))))
    if phi_max < PHI_MIN_SWEEP_DEG:
        out.append(
            f"the sweep's largest tilt is {phi_max:.1f} deg (< {PHI_MIN_SWEEP_DEG:g} deg): "
            "the depths and the distortion are poorly determined; sweep to ~30 deg"
        )
    lengths = [n for n in GEOMETRY_NAMES if n.endswith("_mm")]
    if not known_dz and not any(n in fixed for n in lengths):
        scale_held = [n for n in lengths if n in held]
        out.append(
            "no known length: the overall scale is not determined by images; "
            + (f"held {', '.join(scale_held)} at nominal" if scale_held else "the fit is unscaled")
            + " (give the square's side measured with calipers, or known dz steps)"
        )
    for name, why in held.items():
        if name not in fixed:
            out.append(f"{name} {why}")
    return out
