"""The compiled loops of :mod:`camwhisker.vision.lk` (see :mod:`camwhisker.kernels`)."""

import numpy as np

from camwhisker.kernels import kernel


@kernel("f4[:, ::1], f8[:, :, ::1], f8[:, ::1], i8")
def warp(m, affine, centre, half):
    # Exact bilinear interpolation in float64, the same weights getRectSubPix uses,
    # so that an unmoved frame reproduces its template exactly (cv2.warpAffine
    # rounds the weights to 1/32 px).
    n = 2 * half + 1
    h, w = m.shape
    out = np.empty((len(centre), n, n), np.float32)
    for k in range(len(centre)):
        a00, a01, a10, a11 = affine[k, 0, 0], affine[k, 0, 1], affine[k, 1, 0], affine[k, 1, 1]
        det = a00 * a11 - a01 * a10
        i00, i01, i10, i11 = a11 / det, -a01 / det, -a10 / det, a00 / det  # A^-1
        for i in range(n):
            gy = i - half
            for j in range(n):
                gx = j - half
                x = i00 * gx + i01 * gy + centre[k, 0]
                y = i10 * gx + i11 * gy + centre[k, 1]
                x = min(max(x, 0.0), w - 1.000001)
                y = min(max(y, 0.0), h - 1.000001)
                x0, y0 = int(x), int(y)  # x, y >= 0: the floor
                fx, fy = x - x0, y - y0
                top = m[y0, x0] * (1 - fx) + m[y0, x0 + 1] * fx
                bottom = m[y0 + 1, x0] * (1 - fx) + m[y0 + 1, x0 + 1] * fx
                out[k, i, j] = top * (1 - fy) + bottom * fy
    return out


@kernel(
    "f4[:, :, ::1], i8[::1], f4[:, :, ::1], f8[:, ::1], b1[::1],"
    " f8[:, :, ::1], f8[:, :, ::1], f8, i8",
)
def refine(images, which, templates, d0, ok, weights, in_mean, tol, max_iter):
    """Per point: inverse-compositional translation LK on the mean-removed window
    (the template without its one-pixel gradient border), each pixel's equation
    weighted by ``weights`` (K, m, m) and the offset removed over ``in_mean`` (K, m, m),
    iterated until the step is below ``tol``; then
    the zero-mean NCC of the whole window at the result. NaN where it failed."""
    k_all, n, _ = templates.shape
    m = n - 2
    half = (m - 1) // 2
    h, w = images.shape[1], images.shape[2]
    lo, hi_x, hi_y = half + 1, w - 2 - half, h - 2 - half
    d_out = np.full((k_all, 2), np.nan)
    quality = np.full(k_all, np.nan)
    tx = np.empty((m, m))
    ty = np.empty((m, m))
    t = np.empty((m, m))
    e = np.empty((m, m))
    for k in range(k_all):
        if not ok[k]:
            continue
        tk = templates[k]
        img = images[which[k]]
        hxx = hxy = hyy = 0.0
        for i in range(m):
            for j in range(m):
                t[i, j] = tk[i + 1, j + 1]
                tx[i, j] = (tk[i + 1, j + 2] - tk[i + 1, j]) * 0.5
                ty[i, j] = (tk[i + 2, j + 1] - tk[i, j + 1]) * 0.5
                wx, wy = weights[k, i, j] * tx[i, j], weights[k, i, j] * ty[i, j]
                hxx += wx * tx[i, j]
                hxy += wx * ty[i, j]
                hyy += wy * ty[i, j]
        det = hxx * hyy - hxy * hxy
        if not det > 1e-12:
            continue
        dx, dy = d0[k, 0], d0[k, 1]
        alive = True
        for _ in range(max_iter):
            if not (lo <= dx <= hi_x and lo <= dy <= hi_y):
                alive = False
                break
            sample(img, dx, dy, half, m, e)
            mean = count = 0.0
            for i in range(m):
                for j in range(m):
                    e[i, j] -= t[i, j]
                    mean += in_mean[k, i, j] * e[i, j]
                    count += in_mean[k, i, j]
            mean /= count
            bx = by = 0.0
            for i in range(m):
                for j in range(m):
                    bx += weights[k, i, j] * tx[i, j] * (e[i, j] - mean)
                    by += weights[k, i, j] * ty[i, j] * (e[i, j] - mean)
            sx = (hyy * bx - hxy * by) / det
            sy = (hxx * by - hxy * bx) / det
            dx -= sx
            dy -= sy
            if max(abs(sx), abs(sy)) < tol:
                break
        if not alive or not (lo <= dx <= hi_x and lo <= dy <= hi_y):
            continue
        sample(img, dx, dy, half, m, e)
        pm = tm = 0.0
        for i in range(m):
            for j in range(m):
                pm += e[i, j]
                tm += t[i, j]
        pm /= m * m
        tm /= m * m
        pp = tt = pt = 0.0
        for i in range(m):
            for j in range(m):
                pz, tz = e[i, j] - pm, t[i, j] - tm
                pp += pz * pz
                tt += tz * tz
                pt += pz * tz
        d_out[k, 0], d_out[k, 1] = dx, dy
        den = np.sqrt(pp * tt)
        quality[k] = pt / den if den > 0 else np.nan
    return d_out, quality


@kernel()
def sample(img, dx, dy, half, m, out):
    """Bilinear m x m window of ``img`` centred at (dx, dy), into ``out`` (float64)."""
    ix, iy = int(np.floor(dx)), int(np.floor(dy))
    fx, fy = dx - ix, dy - iy
    for i in range(m):
        r = iy - half + i
        for j in range(m):
            c = ix - half + j
            top = img[r, c] * (1 - fx) + img[r, c + 1] * fx
            bottom = img[r + 1, c] * (1 - fx) + img[r + 1, c + 1] * fx
            out[i, j] = top * (1 - fy) + bottom * fy
