"""The bundle adjustment's normal equations, assembled over all frames at once, against
a frame-by-frame assembly written out here as the reference.

The problem is small (two videos, 24 frames) but has every part: rest frames, an
untracked point, the tip not counting at rest, the corners' shifts free, known dz
on some frames, per-point noise and Huber distances, a residual beyond its Huber
distance. Both assemblies sum the same products in another order: they must agree
to rounding, 1e-10 of each array's largest entry.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from camwhisker.calibration import adjust
from camwhisker.calibration.adjust import bias_terms, corner_shift_jacobian
from camwhisker.sensor.file import Sensor
from camwhisker.sensor.model import GEOMETRY_NAMES, TIP, PlateModel, geometry_vector, with_geometry

#: Rounding of sums of ~1e3 products in another order: far above 1e-16, far below an error.
RTOL = 1e-10
N_FRAMES = 24
N_REST = 4


def _loop_normal(p, g, q):
    """The normal equations frame by frame: the reference for the library's assembly."""
    n_geo = len(GEOMETRY_NAMES)
    shifts = g[n_geo:].reshape(-1, TIP, 2)
    model = PlateModel(with_geometry(p.sensor, g[:n_geo]))
    n_f, n = len(q), len(p.free)
    U, bg = np.zeros((n, n)), np.zeros(n)
    V, bp, W = np.zeros((n_f, 3, 3)), np.zeros((n_f, 3)), np.zeros((n_f, n, 3))
    bg_frame, leverage = np.zeros((n_f, n)), np.zeros((n_f, TIP + 1))
    residual, weight = np.full((n_f, TIP + 1, 2), np.nan), np.zeros((n_f, TIP + 1))
    d_shift, systematic = np.zeros((TIP + 1, 2, shifts.size)), np.zeros((TIP + 1, 2, 3, n))
    cost, q5 = 0.0, np.zeros(5)
    for f in np.flatnonzero(p.valid.any(axis=1)):
        q5[:3] = q[f]
        jac, d_corner = model.jacobians(q5), corner_shift_jacobian(model, q5)
        d_shift[:] = 0.0
        first = 2 * TIP * p.video[f]
        for j in range(TIP):
            d_shift[j, :, first + 2 * j : first + 2 * j + 2] = d_corner[j]
        m = p.valid[f]
        uv = jac.uv.copy()
        uv[:TIP] += np.einsum("jab,jb->ja", d_corner, shifts[p.video[f]])
        r = p.obs[f][m] - uv[m]
        rho, w = adjust._huber(np.linalg.norm(r, axis=1), p.huber_px[m])
        residual[f][m], weight[f][m] = r, w
        cost += float(np.sum(rho / p.noise_px[m] ** 2))
        sw = np.repeat(np.sqrt(w) / p.noise_px[m], 2)
        rw = r.reshape(-1) * sw
        d_all = np.concatenate([jac.geometry, d_shift], axis=2)
        jg = (d_all[m][:, :, p.free] * p.tol[p.free]).reshape(len(rw), n) * sw[:, None]
        U += jg.T @ jg
        bg_frame[f] = jg.T @ rw
        bg += bg_frame[f]
        if not p.rest[f]:
            jp = jac.pose[m][:, :, :3].reshape(-1, 3) * sw[:, None]
            V[f], bp[f], W[f] = jp.T @ jp, jp.T @ rw, jg.T @ jp
            if np.isfinite(p.known_dz[f]):
                r_dz = (p.known_dz[f] - q[f, 0]) / p.known_dz_sd[f]
                V[f][0, 0] += p.known_dz_sd[f] ** -2
                bp[f][0] += r_dz / p.known_dz_sd[f]
                cost += r_dz**2
            v_inv = np.linalg.pinv(V[f])
            leverage[f][m] = np.einsum("ij,jk,ik->i", jp, v_inv, jp).reshape(-1, 2).sum(axis=1)
            reduced = (jg - jp @ v_inv @ W[f].T) * sw[:, None]
            systematic[m] += np.einsum("jcn,k->jckn", reduced.reshape(len(rw) // 2, 2, n),
                                       bias_terms(q[f]))  # fmt: skip
    cost += adjust._add_shift_prior(p, g, U, bg)  # the library's: not per frame
    return adjust._Normal(cost, U, bg, V, bp, W, residual, weight, bg_frame, leverage, systematic)


@pytest.fixture(scope="module")
def problem():
    """A small problem with every part of the assembly in it, its geometry and poses."""
    rng = np.random.default_rng(11)
    sensor = Sensor()
    q = np.zeros((N_FRAMES, 3))
    tilt = np.radians(25.0) * np.linspace(0.2, 1.0, N_FRAMES - N_REST)
    turn = np.linspace(0.0, 5.0, N_FRAMES - N_REST)
    q[N_REST:] = np.column_stack([0.3 * np.sin(turn), tilt * np.cos(turn), tilt * np.sin(turn)])
    video = (np.arange(N_FRAMES) >= N_FRAMES // 2).astype(int)
    rest = np.isin(np.arange(N_FRAMES), [0, 1, N_FRAMES // 2, N_FRAMES // 2 + 1])
    model = PlateModel(sensor)
    obs = np.array([model.project(np.pad(qq, (0, 2)), jacobian=False)[0] for qq in q])
    obs += rng.normal(0.0, 0.1, obs.shape)
    obs[7, 3] += 3.0  # beyond the Huber distance
    obs[9, 5] = np.nan  # not tracked
    valid = np.isfinite(obs).all(axis=-1)
    valid[rest, TIP] = False
    known_dz = np.full(N_FRAMES, np.nan)
    known_dz[15:19] = 0.25
    n_geo = len(GEOMETRY_NAMES)
    shift_prior = rng.normal(0.0, 0.004, 2 * 2 * TIP)
    tol = np.concatenate([adjust.tolerances(sensor), np.full(2 * 2 * TIP, 0.006)])
    free = np.array([0, 2, 4, 9, 10, 13, *range(n_geo + 3, n_geo + 40)])
    p = adjust._Problem(obs, valid, rest, video, sensor, tol, shift_prior, free, 0.5,
                        rng.uniform(0.3, 0.5, TIP + 1), rng.uniform(0.05, 0.2, TIP + 1),
                        known_dz, np.full(N_FRAMES, 0.002))  # fmt: skip
    g = np.concatenate([geometry_vector(sensor), shift_prior + rng.normal(0, 0.003, 4 * TIP)])
    q_lin = q + rng.normal(0.0, [0.01, 0.002, 0.002], q.shape)
    return p, g, q_lin


@pytest.mark.parametrize("free", ["some", "none"])
def test_normal_equations_over_all_frames_equal_the_frame_by_frame_ones(problem, free):
    p, g, q = problem
    if free == "none":  # the poses alone, as the fit starts
        p = replace(p, free=np.zeros(0, int))
    fast, ref = adjust._normal(p, g, q), _loop_normal(p, g, q)
    assert fast.cost == pytest.approx(ref.cost, rel=RTOL)
    for name in ("U", "bg", "V", "bp", "W", "weight", "bg_frame", "leverage", "systematic"):
        a, b = getattr(fast, name), getattr(ref, name)
        assert a.shape == b.shape, name
        assert np.abs(a - b).max(initial=0) <= RTOL * np.abs(b).max(initial=0), name
    assert np.array_equal(np.isnan(fast.residual), np.isnan(ref.residual))
    np.testing.assert_allclose(fast.residual, ref.residual, rtol=0,
                               atol=RTOL * np.nanmax(np.abs(ref.residual)))  # fmt: skip
    # The problem has every part: a prior on dz, a Huber weight below one, a dropped point.
    assert np.isfinite(p.known_dz[~p.rest]).any() and fast.weight.min() == 0.0
    assert 0.0 < fast.weight[7, 3] < 1.0 and fast.systematic.shape[-1] == len(p.free)


def test_poses_jacobians_many_equal_one_at_a_time(problem):
    p, _, q = problem
    model = PlateModel(p.sensor)
    q5 = np.pad(q, ((0, 0), (0, 2)))
    many = model.jacobians_many(q5)
    for f in (0, 7, N_FRAMES - 1):
        one = model.jacobians(q5[f])
        # The same projection and the same products: equal to the last bit.
        for name in ("uv", "pose", "geometry", "corner_point"):
            assert np.array_equal(getattr(many, name)[f], getattr(one, name)), name
    assert corner_shift_jacobian(model, q5).shape == (N_FRAMES, TIP, 2, 2)
