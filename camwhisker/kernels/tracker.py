"""The compiled loops of :mod:`camwhisker.vision.tracker` (see :mod:`camwhisker.kernels`)."""

import numpy as np

from camwhisker.kernels import kernel


@kernel("f8[:, ::1], i8, i8, i8")
def patch_corners(uv, half, h, w):
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
