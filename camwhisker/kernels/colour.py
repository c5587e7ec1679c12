"""The compiled loops of :mod:`camwhisker.vision.colour` (see :mod:`camwhisker.kernels`)."""

import numpy as np

from camwhisker.kernels import kernel


@kernel(
    "u1[:, :, ::1], i8[::1], i8[::1], f8, i8",
    "f4[:, :, ::1], i8[::1], i8[::1], f8, i8",
)
def gray_world(frame, rows, cols, min_fraction, saturated):
    """:func:`white_balance_gains` in one compiled pass (numpy's per-call cost
    dominates on so few samples); float32 sums in numpy's order."""
    n = rows.shape[0]
    px = np.empty((n, 3), np.float32)
    level = np.empty(n, np.float32)
    for k in range(n):
        for c in range(3):
            px[k, c] = frame[rows[k], cols[k], c]
        level[k] = px[k, 0] + px[k, 1] + px[k, 2]
    ones = np.ones(3, np.float32)
    if n == 0:
        return ones
    med = np.float32(np.median(level))
    total = np.zeros(3, np.float32)
    m = 0
    for k in range(n):
        if level[k] >= min_fraction * med and max(px[k, 0], px[k, 1], px[k, 2]) < saturated:
            total += px[k]
            m += 1
    if m < 3 or not med > 0:
        return ones
    mean = total / np.float32(m)
    if not (mean[0] > 0 and mean[1] > 0 and mean[2] > 0):
        return ones
    gains = (mean[0] + mean[1] + mean[2]) / np.float32(3) / mean
    return gains / ((gains[0] + gains[1] + gains[2]) / np.float32(3))


@kernel(
    "u1[:, :, ::1], i8[:, ::1], i8, f4[:, ::1]",
    "f4[:, :, ::1], i8[:, ::1], i8, f4[:, ::1]",
)
def share_patches(frame, top_left, size, weights):
    out = np.empty((len(top_left), size, size), np.float32)
    for k in range(len(top_left)):
        u, v = top_left[k, 0], top_left[k, 1]
        wb, wg, wr = weights[k, 0], weights[k, 1], weights[k, 2]
        for i in range(size):
            for j in range(size):
                b, g, r = frame[v + i, u + j, 0], frame[v + i, u + j, 1], frame[v + i, u + j, 2]
                out[k, i, j] = np.float32(b) * wb + np.float32(g) * wg + np.float32(r) * wr
    return out


@kernel(
    "u1[:, :, ::1], i8[::1], i8[::1], f4[::1]",
    "f4[:, :, ::1], i8[::1], i8[::1], f4[::1]",
)
def cloth_level(frame, rows, cols, gains):
    """:func:`cloth_level` in one compiled pass, summed in float64."""
    total = 0.0
    for k in range(rows.shape[0]):
        for c in range(3):
            total += np.float32(frame[rows[k], cols[k], c]) * gains[c]
    return total / (3 * rows.shape[0])
