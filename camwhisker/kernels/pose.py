"""The compiled loops of :mod:`camwhisker.vision.pose` (see :mod:`camwhisker.kernels`)."""

import numpy as np

from camwhisker.kernels import kernel


@kernel("f8[:, ::1], f8[:, ::1], f8[::1]")
def observations_kernel(measured, offsets, weights):
    n = measured.shape[0]
    target = np.zeros((n, 2))
    use = np.zeros(n, np.bool_)
    sw = np.zeros((n, 1))
    for k in range(n):
        u, v = measured[k, 0] - offsets[k, 0], measured[k, 1] - offsets[k, 1]
        if np.isfinite(u) and np.isfinite(v) and weights[k] > 0:
            target[k, 0], target[k, 1] = u, v
            use[k] = True
            sw[k, 0] = np.sqrt(weights[k])
    return target, use, sw


@kernel("f8[:, ::1], f8[:, :, :], f8[:, ::1], f8[:, ::1], i8")
def normal_equations(uv, jac, target, sw, n_par):
    """J^T J (n_par, n_par), J^T r (n_par, 1) and r^T r of the weighted problem:
    residuals r = sw (target - uv), Jacobian J = sw jac[..., :n_par]; unused
    points have sw = 0 and add nothing."""
    jtj = np.zeros((n_par, n_par))
    jtr = np.zeros((n_par, 1))
    rr = 0.0
    for k in range(uv.shape[0]):
        w = sw[k, 0]
        if w == 0.0:
            continue
        for c in range(2):
            r = w * (target[k, c] - uv[k, c])
            rr += r * r
            for i in range(n_par):
                ji = w * jac[k, c, i]
                jtr[i, 0] += ji * r
                for j in range(i + 1):
                    jtj[i, j] += ji * w * jac[k, c, j]
    for i in range(n_par):
        for j in range(i):
            jtj[j, i] = jtj[i, j]
    return jtj, jtr, rr
