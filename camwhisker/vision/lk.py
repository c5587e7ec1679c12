"""Translation-only Lucas-Kanade on small patches, all tracked points in one call.

:func:`refine_first_template` places each point against its first template,
the rest frame's patch, so errors do not accumulate (the drift correction of
Matthews, Ishikawa & Baker, 2004). The rest patch is first warped by the
affine map the plate model predicts between the rest pose and the current
pose (:func:`warp_templates`), so the remaining motion is a pure translation
even at large tilts. The fit may leave out each corner's apex (``apex_px``):
a blurred apex is rounded, while an edge's half level does not move with blur
(the front end gives the warped templates the image's blur back,
:func:`~camwhisker.vision.blur.reblur_templates`; the calibration's sweep leaves
the apex out).

References
----------
.. [1] I. Matthews, T. Ishikawa, S. Baker, "The template update problem",
   IEEE TPAMI 26(6), 2004. doi:10.1109/TPAMI.2004.16
.. [2] S. Baker, I. Matthews, "Lucas-Kanade 20 years on: a unifying
   framework", IJCV 56(3), 2004. doi:10.1023/B:VISI.0000011205.11775.fd
"""

from __future__ import annotations

import functools

import numpy as np

from camwhisker.kernels import lk as kernels

__all__ = [
    "PATCH_HALF_PX",
    "warp_templates",
    "refine_first_template",
]

#: Half size of the LK window (px): 25 x 25 covers a corner's two edges out to
#: 3 blur sigma of the hard scene and stays clear of the neighbouring features.
PATCH_HALF_PX = 12
#: Inverse-compositional iterations stop, per point, when the step is below this
#: (px): far under a corner's ~0.05 px noise.
LK_STEP_TOL_PX = 0.002
#: Cap on the iterations per point; a converging point needs a handful.
LK_MAX_ITER = 20


def warp_templates(
    rest_map: np.ndarray,
    rest_origin: np.ndarray,
    rest_uv: np.ndarray,
    affine: np.ndarray,
    half: int = PATCH_HALF_PX,
) -> np.ndarray:
    """Rest patches warped into the current frame's shape.

    Parameters
    ----------
    rest_map : ndarray, shape (h, w), float32
        Contrast map of the rest frame over a region.
    rest_origin : ndarray, shape (2,)
        Pixel (u, v) of ``rest_map[0, 0]``.
    rest_uv : ndarray, shape (K, 2)
        Rest positions of the points.
    affine : ndarray, shape (K, 2, 2)
        Linear part A of the map rest -> current around each point.
    half : int

    Returns
    -------
    templates : ndarray, shape (K, 2 half + 1, 2 half + 1), float32
        ``templates[k][y, x]`` is the rest map at rest_uv[k] + A^-1 ((x, y) - half).
    """
    centre = np.asarray(rest_uv, float) - np.asarray(rest_origin, float)
    return kernels.warp(np.ascontiguousarray(rest_map, np.float32),
                        np.ascontiguousarray(affine, float), centre, half)  # fmt: skip


def refine_first_template(
    image: np.ndarray,
    origin: np.ndarray,
    templates: np.ndarray,
    start_uv: np.ndarray,
    active: np.ndarray,
    apex_px: float = 0.0,
    keep: np.ndarray | None = None,
):
    """Inverse-compositional translation LK of each template in ``image``.

    Intensities are compared after removing each patch's mean, so a uniform
    change of contrast offset does not move the estimate.

    Parameters
    ----------
    image : ndarray, shape (h, w) or (K, h, w), float32
        Current map over a region, or one region per point; ``origin``, shape
        (2,) or (K, 2), is the frame pixel of each region's [0, 0].
    templates : ndarray, shape (K, n, n), float32
        From :func:`warp_templates`; the template centre is the point.
    start_uv : ndarray, shape (K, 2)
        Starting positions (pixels of the full frame).
    active : ndarray of bool, shape (K,)
        Points to refine; the others come back NaN.
    apex_px : float
        The fit leaves out the window's pixels closer than this to its centre (px).
    keep : ndarray of bool, shape (K, n - 2, n - 2), optional
        Each window's pixels the fit may use (the template's border excluded);
        default all.

    Returns
    -------
    uv : ndarray, shape (K, 2)
        Refined positions (NaN where inactive, diverged or out of the region).
    quality : ndarray, shape (K,)
        Zero-mean normalised cross-correlation of the template and the final
        patch, in [-1, 1]; NaN where there is none.
    """
    k_all = templates.shape[0]
    image = np.asarray(image, np.float32)
    stack = image.reshape((-1, *image.shape[-2:]))
    which = np.arange(k_all) if image.ndim == 3 else np.zeros(k_all, np.intp)
    origins = np.empty((k_all, 2))
    origins[:] = origin
    d0 = np.asarray(start_uv, float) - origins
    ok = np.asarray(active, bool) & np.isfinite(d0).all(axis=1)
    weights, in_mean = _fit_weights(k_all, templates.shape[1] - 2, apex_px)
    if keep is not None:
        weights = weights * keep
        # The intensity offset is taken over the pixels kept: what lies outside them (a
        # spring crossing the window) must not move it.
        in_mean = np.ascontiguousarray(keep, np.float64)
    d, quality = kernels.refine(stack, which, np.ascontiguousarray(templates, np.float32), d0, ok,
                                weights, in_mean, LK_STEP_TOL_PX, LK_MAX_ITER)  # fmt: skip
    return d + origins, quality


@functools.lru_cache(maxsize=8)
def _fit_weights(k: int, m: int, apex_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Each pixel's weight in the fit over k m x m windows, shape (k, m, m): 0 closer
    than ``apex_px`` to its centre, else 1; and the offset's weights, all 1. Made once
    (the kernel only reads them): each frame's LK calls take the same."""
    r = np.arange(m) - (m - 1) / 2
    one = (np.hypot(r[:, None], r[None, :]) >= apex_px).astype(np.float64)
    return np.ascontiguousarray(np.broadcast_to(one, (k, m, m))), np.ones((k, m, m))
