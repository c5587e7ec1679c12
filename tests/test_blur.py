"""The image's blur: measured at rest, given back to warped templates and to the tip's rim."""

import math

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.special import ndtr

from camwhisker.sensor.polygon import polygon_centroid
from camwhisker.vision.blur import REBLUR_PAD_PX, erf_sigmas, reblur_templates, square_blur_px
from camwhisker.vision.tip import blurred_rim, rim_centre, tip_edge_points

SUPER = 8  # supersampling of the drawn shapes: their edges' own sampling blur is 1/8 px


def _square_share(sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """A share map (0 outside, 1 inside) of a square, 8x supersampled then blurred by
    ``sigma`` (px), and its corners in order around it."""
    n, lo, hi = 200, 40.3, 160.7
    big = np.zeros((n * SUPER, n * SUPER), np.float32)
    a, b = int(round((lo + 0.5) * SUPER)), int(round((hi + 0.5) * SUPER))
    big[a:b, a:b] = 1.0
    img = cv2.resize(big, (n, n), interpolation=cv2.INTER_AREA)
    img = cv2.GaussianBlur(img, (0, 0), sigma)
    lo_, hi_ = a / SUPER - 0.5, b / SUPER - 0.5
    corners = np.array([[lo_, lo_], [hi_, lo_], [hi_, hi_], [lo_, hi_]])
    return img, corners


def test_square_blur_is_the_gaussian_with_the_pixels_own():
    # The pixel's area adds 1/12 px^2 to the drawn blur; the fit's noise-free error is
    # a few hundredths of a px: 0.03 px allowed, a tenth of what the reblur's 1.6-2.6 px
    # sigmas need to tell a corner's place to 0.005 px.
    for sigma in (1.0, 1.8, 2.6):
        img, corners = _square_share(sigma)
        expected = math.sqrt(sigma**2 + 1.0 / 12.0)
        assert abs(square_blur_px(img, corners) - expected) < 0.03, sigma


def test_square_blur_is_nan_without_a_square():
    flat = np.zeros((100, 100), np.float32)
    corners = np.array([[20.0, 20.0], [80.0, 20.0], [80.0, 80.0], [20.0, 80.0]])
    assert math.isnan(square_blur_px(flat, corners))
    assert math.isnan(square_blur_px(flat, np.full((4, 2), np.nan)))


def _one_row_fit(x, p, f_scale):
    """scipy's least_squares on one row, converged far past erf_sigmas' own stop."""
    lo, hi = [-np.inf, 0.0, x[0], 0.05], [np.inf, np.inf, x[-1], 2.0 * x[-1]]
    q0 = [p[0], max(p[-1] - p[0], 0.5 * f_scale), 0.0, 1.0]
    fit = least_squares(lambda q: q[0] + q[1] * ndtr((x - q[2]) / q[3]) - p, q0, bounds=(lo, hi),
                        loss="soft_l1", f_scale=f_scale, x_scale="jac", xtol=1e-14,
                        ftol=1e-14, gtol=1e-14)  # fmt: skip
    return fit.x


def test_erf_sigmas_are_the_soft_l1_optimum_of_each_row():
    # Noisy blurred steps with outliers, a flat row, a falling one and a row with a NaN.
    rng = np.random.default_rng(3)
    x = np.arange(-6.0, 6.0 + 1e-9, 0.25)
    sigma = rng.uniform(0.6, 2.8, 40)
    prof = 20 + 150 * ndtr((x - rng.uniform(-1.5, 1.5, (40, 1))) / sigma[:, None])
    prof += rng.normal(0.0, 2.0, prof.shape)
    prof[rng.random(prof.shape) < 0.04] += 60.0
    prof[1], prof[2], prof[3, 7] = 90.0, prof[2, ::-1], np.nan
    got = erf_sigmas(x, prof, 2.0)
    assert np.isnan(got[1:4]).all()
    for k in range(4, 40):
        ref = _one_row_fit(x, prof[k], 2.0)
        # The same minimum: erf_sigmas stops where a step gains < 1e-10 of the cost,
        # within ~2e-5 px of it on real profiles; 1e-4 px is 1/300 of the 0.03 px the
        # blur's use needs.
        assert abs(got[k] - ref[3]) < 1e-4, k


def _corner(sigma_u: float, sigma_v: float, n: int) -> np.ndarray:
    """A blurred quadrant (1 where u, v > 0) sampled on an n x n grid centred on it."""
    x = np.arange(n) - (n - 1) / 2
    return (ndtr(x[:, None] / sigma_v) * ndtr(x[None, :] / sigma_u)).astype(np.float32)


def test_reblur_gives_a_foreshortened_template_the_images_blur():
    # A corner blurred by sigma, foreshortened by cos 30 deg along v: the rest template
    # warped to it is blurred sigma cos 30 deg along v, the image sigma. Reblurred, it
    # is the image up to float32 rounding and the transform's wrap-around, which the
    # padding takes (1e-4 of the step allowed); not reblurred, it is off by ~4 %.
    sigma, c, half = 2.0, math.cos(math.radians(30.0)), 12
    n = 2 * (half + REBLUR_PAD_PX) + 1
    warped = _corner(sigma, sigma * c, n)[None]
    image = _corner(sigma, sigma, 2 * half + 1)
    affine = np.diag([1.0, c])[None]
    out = reblur_templates(warped, affine, sigma)
    assert out.shape == (1, 2 * half + 1, 2 * half + 1)
    assert np.abs(out[0] - image).max() < 1e-4
    cropped = warped[0, REBLUR_PAD_PX:-REBLUR_PAD_PX, REBLUR_PAD_PX:-REBLUR_PAD_PX]
    assert np.abs(cropped - image).max() > 0.03


def test_reblur_leaves_an_unmoved_or_magnified_template_as_it_is():
    # At rest (A = I) nothing is added; where A magnifies (the plate nearer the
    # camera) the template is already the blurrier: nothing can be taken out.
    n = 2 * (12 + REBLUR_PAD_PX) + 1
    warped = _corner(1.5, 1.5, n)[None].repeat(2, axis=0)
    affine = np.stack([np.eye(2), 1.02 * np.eye(2)])
    out = reblur_templates(warped, affine, 1.5)
    p = REBLUR_PAD_PX
    assert np.abs(out - warped[:, p:-p, p:-p]).max() < 1e-5


def _blurred_disc(radius: float, sigma: float, centre: np.ndarray) -> np.ndarray:
    """A black disc on grey cloth (BGR uint8), 8x supersampled, blurred by ``sigma``."""
    n = 120
    yy, xx = np.mgrid[0 : n * SUPER, 0 : n * SUPER]
    r = np.hypot((xx + 0.5) / SUPER - 0.5 - centre[0], (yy + 0.5) / SUPER - 0.5 - centre[1])
    big = np.where(r <= radius, 20.0, 180.0).astype(np.float32)
    img = cv2.GaussianBlur(cv2.resize(big, (n, n), interpolation=cv2.INTER_AREA), (0, 0), sigma)
    return np.repeat(img[..., None], 3, axis=2).round().astype(np.uint8)


def test_the_blurred_rim_places_a_partly_hidden_face():
    # Half of a blurred face's edge (the other half hidden, as beside the rod's body
    # at tilt): the model's rim fitted to it sits ~1.27 sigma^2 / (2 r) = 0.13 px
    # away from the seen half; the rim moved to where the blur shows the edge, within
    # 0.03 px (the steepest rise's own sampling error on a 20 px disc).
    radius, sigma = 20.0, 2.0
    centre = np.array([60.3, 59.6])
    frame = _blurred_disc(radius, sigma, centre)
    pts, _, why = tip_edge_points(frame, np.ones(3), centre + 1.0, radius, 6.0)
    assert pts is not None, why
    angles = np.linspace(0, 2 * np.pi, 181)[:-1]
    rim = centre + radius * np.column_stack([np.cos(angles), np.sin(angles)])
    assert np.abs(polygon_centroid(rim) - centre).max() < 1e-9
    seen = pts[pts[:, 0] > centre[0]]  # the half of the edge toward +u
    plain = rim_centre(seen, rim).centre_uv - centre
    moved = rim_centre(seen, blurred_rim(rim, sigma)).centre_uv - centre
    assert plain[0] < -0.08  # pulled away from the seen half
    assert np.abs(moved).max() < 0.03
    assert np.array_equal(blurred_rim(rim, math.nan), rim)
