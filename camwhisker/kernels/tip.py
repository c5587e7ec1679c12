"""The compiled loops of :mod:`camwhisker.vision.tip` (see :mod:`camwhisker.kernels`)."""

import numpy as np

from camwhisker.kernels import kernel
from camwhisker.kernels.polygon import polygon_centroid


@kernel(
    "u1[:, :, ::1], f4[::1]",
    "u1[:, :, :], f4[::1]",
    "f4[:, :, ::1], f4[::1]",
    "f4[:, :, :], f4[::1]",
)
def brightness(bgr, gains):
    h, w = bgr.shape[0], bgr.shape[1]
    val = np.empty((h, w), np.float32)
    lum = np.empty((h, w), np.float32)
    for i in range(h):
        for j in range(w):
            vb = np.float32(bgr[i, j, 0]) * gains[0]
            vg = np.float32(bgr[i, j, 1]) * gains[1]
            vr = np.float32(bgr[i, j, 2]) * gains[2]
            val[i, j] = max(vb, vg, vr)
            lum[i, j] = np.float32(0.114) * vb + np.float32(0.587) * vg + np.float32(0.299) * vr
    return val, lum


@kernel(
    "u1[:, :, ::1], f4[::1], f8[:, ::1], f8, f4",
    "f4[:, :, ::1], f4[::1], f8[:, ::1], f8, f4",
)
def any_dark(frame, gains, centres, radius, level):
    """:func:`face_near`'s samples in one compiled pass (numpy's per-call cost dominates)."""
    h, w = frame.shape[0], frame.shape[1]
    step = np.array([-0.5, 0.0, 0.5]) * radius
    for k in range(centres.shape[0]):
        for dv in step:
            for du in step:
                u, v = centres[k, 0] + du, centres[k, 1] + dv
                if not (np.isfinite(u) and np.isfinite(v)):
                    continue
                col = int(np.rint(min(max(u, 0.0), w - 1.0)))
                row = int(np.rint(min(max(v, 0.0), h - 1.0)))
                val = max(np.float32(frame[row, col, 0]) * gains[0],
                          np.float32(frame[row, col, 1]) * gains[1],
                          np.float32(frame[row, col, 2]) * gains[2])  # fmt: skip
                if val < level:
                    return True
    return False


@kernel("f8[:, ::1], f8[::1]")
def polar(uv, c0):
    """Angles (sorted, with one wrapped copy at each end) and radii about c0, for np.interp."""
    n = uv.shape[0]
    ang = np.arctan2(uv[:, 1] - c0[1], uv[:, 0] - c0[0])
    rad = np.hypot(uv[:, 0] - c0[0], uv[:, 1] - c0[1])
    o = np.argsort(ang)
    a = np.empty(n + 2)
    r = np.empty(n + 2)
    a[1:-1], r[1:-1] = ang[o], rad[o]
    a[0], r[0] = a[n] - 2 * np.pi, r[n]
    a[-1], r[-1] = a[1] + 2 * np.pi, r[1]
    return a, r


@kernel("f8[:, ::1], f8[:, ::1], f8[:, ::1], i8, f8, f8")
def beside_body_kernel(pts, rim, hull, n_angles, protrusion, blur):
    c0 = polygon_centroid(rim)
    ah, rh = polar(hull, c0)
    ar, rr = polar(rim, c0)
    probe = -np.pi + 2 * np.pi * np.arange(n_angles) / n_angles
    r_rim = np.interp(probe, ar, rr)
    body = np.interp(probe, ah, rh) - r_rim > protrusion
    out = np.zeros(pts.shape[0], np.bool_)
    if not body.any():
        return out
    reach = blur / max(r_rim.mean(), 1.0) + np.pi / n_angles
    # Only the probes within reach of a ray can flag it: test those (and one more
    # on each side, so that rounding cannot leave one out).
    step = 2 * np.pi / n_angles
    span = int(reach / step) + 2
    for i in range(pts.shape[0]):
        ang = np.arctan2(pts[i, 1] - c0[1], pts[i, 0] - c0[0])
        nearest = int(np.floor((ang + np.pi) / step))
        for k in range(nearest - span, nearest + span + 1):
            k %= n_angles
            if body[k] and abs((ang - probe[k] + np.pi) % (2 * np.pi) - np.pi) <= reach:
                out[i] = True
                break
    return out


@kernel("f8[:, ::1], f8[:, ::1], i8, f8, f8, i8")
def rim_shift_kernel(pts, rim, n_iter, tol, outlier, min_rays):
    c0 = polygon_centroid(rim)
    ar, rr = polar(rim, c0)
    n = pts.shape[0]
    ux, uy, res = np.empty(n), np.empty(n), np.empty(n)
    tx = ty = 0.0
    for _ in range(n_iter):
        for i in range(n):
            dx, dy = pts[i, 0] - c0[0] - tx, pts[i, 1] - c0[1] - ty
            rho = np.hypot(dx, dy)
            ux[i], uy[i] = dx / rho, dy / rho
            res[i] = rho - np.interp(np.arctan2(dy, dx), ar, rr)
        sx, sy, ok = shift_step(ux, uy, res, np.ones(n, np.bool_))
        if not ok:
            return np.full(2, np.nan), np.nan
        keep = np.abs(res - ux * sx - uy * sy) <= outlier
        if not keep.all() and keep.sum() >= min_rays:
            sx, sy, ok = shift_step(ux, uy, res, keep)
            if not ok:
                return np.full(2, np.nan), np.nan
        tx += sx
        ty += sy
        if max(abs(sx), abs(sy)) < tol:
            break
    out = np.empty(2)
    out[0], out[1] = c0[0] + tx, c0[1] + ty
    return out, rr[1:-1].mean()


@kernel()
def shift_step(ux, uy, res, use):
    """Least-squares (sx, sy) of res = u . s over the used points, and whether solvable."""
    a = b = c = p = q = 0.0
    for i in range(ux.shape[0]):
        if use[i]:
            a += ux[i] * ux[i]
            b += ux[i] * uy[i]
            c += uy[i] * uy[i]
            p += ux[i] * res[i]
            q += uy[i] * res[i]
    det = a * c - b * b
    if not abs(det) > 1e-12 * max(a * c, 1e-300):
        return 0.0, 0.0, False
    return (c * p - b * q) / det, (a * q - b * p) / det, True


@kernel(
    "f4[:, ::1], f4[:, ::1], f4[:, ::1], f8, i8, f8[::1], f8, f8, f8",
)
def ray_edges(prof, rise, vrise, thr, win, radii, step, min_rise, agree):
    """Per ray: the steepest rise within ``win`` samples of the first sample at or
    above ``thr``, placed by a parabola; radius and whether the ray is usable
    (a crossing, an inner peak, ``vrise``'s peak within ``agree`` px of it, a rise
    >= ``min_rise`` times the median)."""
    n_rays, n = rise.shape
    r_edge = np.full(n_rays, np.nan)
    peak = np.full(n_rays, -np.inf)
    valid = np.zeros(n_rays, np.bool_)
    for k in range(n_rays):
        first = -1
        for i in range(n):
            if prof[k, i] >= thr:
                first = i
                break
        if first <= 0:
            continue
        lo, hi = max(first - win, 1), min(first + win, n - 2)
        if hi < lo:
            continue
        j = lo + np.argmax(rise[k, lo : hi + 1])
        if abs(j - lo - np.argmax(vrise[k, lo : hi + 1])) * step > agree:
            continue
        peak[k] = rise[k, j]
        valid[k] = True
        ym, y0, yp = rise[k, j - 1], rise[k, j], rise[k, j + 1]
        den = ym - 2 * y0 + yp
        frac = min(max(0.5 * (ym - yp) / den, -0.5), 0.5) if den < 0 else 0.0
        r_edge[k] = radii[j] + frac * step
    if valid.sum() >= 1:
        med = np.median(peak[valid])
        for k in range(n_rays):
            valid[k] = valid[k] and peak[k] >= min_rise * med
    return r_edge, valid
