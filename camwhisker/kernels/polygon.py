"""The compiled shoelace sums of :mod:`camwhisker.sensor.polygon`."""

import numpy as np

from camwhisker.kernels import kernel


@kernel("f8[:, ::1],", "f8[:, :],")
def polygon_centroid(uv: np.ndarray) -> np.ndarray:
    """Area centroid of a closed polygon, shape (N, 2) -> (2,) (shoelace formula)."""
    n = uv.shape[0]
    area = cx = cy = 0.0
    for i in range(n):
        j = (i + 1) % n
        cross = uv[i, 0] * uv[j, 1] - uv[j, 0] * uv[i, 1]
        area += cross
        cx += cross * (uv[i, 0] + uv[j, 0])
        cy += cross * (uv[i, 1] + uv[j, 1])
    out = np.empty(2)
    out[0], out[1] = cx / (3.0 * area), cy / (3.0 * area)
    return out


@kernel("f8[:, ::1],", "f8[:, :],")
def polygon_area(uv: np.ndarray) -> float:
    """Unsigned area of a closed polygon, shape (N, 2) (shoelace formula)."""
    n = uv.shape[0]
    twice = 0.0
    for i in range(n):
        j = (i + 1) % n
        twice += uv[i, 0] * uv[j, 1] - uv[j, 0] * uv[i, 1]
    return abs(twice) / 2.0


@kernel("f8[:, ::1], f8[:, :, ::1]", "f8[:, ::1], f8[:, :, :]")
def polygon_centroid_jacobian(uv: np.ndarray, duv: np.ndarray) -> np.ndarray:
    """Derivative of :func:`polygon_centroid` along the vertices' derivatives.

    Parameters
    ----------
    uv : ndarray, shape (N, 2)
        The polygon's vertices.
    duv : ndarray, shape (N, 2, P)
        d uv / d p for P parameters p.

    Returns
    -------
    ndarray, shape (2, P)
        d centroid / d p, by differentiating the shoelace sums: with
        c_i = x_i y_(i+1) - x_(i+1) y_i, A2 = sum c_i and
        C_x = sum c_i (x_i + x_(i+1)) / (3 A2).
    """
    n, n_p = uv.shape[0], duv.shape[2]
    a2 = sx = sy = 0.0
    da2, d_sx, d_sy = np.zeros(n_p), np.zeros(n_p), np.zeros(n_p)
    for i in range(n):
        j = (i + 1) % n
        x, y, xn, yn = uv[i, 0], uv[i, 1], uv[j, 0], uv[j, 1]
        c = x * yn - xn * y
        a2 += c
        sx += c * (x + xn)
        sy += c * (y + yn)
        for k in range(n_p):
            dx, dy, dxn, dyn = duv[i, 0, k], duv[i, 1, k], duv[j, 0, k], duv[j, 1, k]
            dc = dx * yn + x * dyn - dxn * y - xn * dy
            da2[k] += dc
            d_sx[k] += dc * (x + xn) + c * (dx + dxn)
            d_sy[k] += dc * (y + yn) + c * (dy + dyn)
    a3 = 3.0 * a2
    out = np.empty((2, n_p))
    for k in range(n_p):
        out[0, k] = (d_sx[k] - sx / a3 * 3.0 * da2[k]) / a3
        out[1, k] = (d_sy[k] - sy / a3 * 3.0 * da2[k]) / a3
    return out
