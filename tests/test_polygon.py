"""Polygon centroid's derivative against central differences and hand values."""

import numpy as np

from camwhisker.sensor.polygon import polygon_centroid, polygon_centroid_jacobian


def _ellipse(n=64, centre=(300.0, 200.0), axes=(40.0, 25.0), angle=0.4):
    t = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    c, s = np.cos(angle), np.sin(angle)
    x, y = axes[0] * np.cos(t), axes[1] * np.sin(t)
    return np.column_stack([centre[0] + c * x - s * y, centre[1] + s * x + c * y])


def test_centroid_jacobian_matches_central_differences():
    rng = np.random.default_rng(4)
    uv = _ellipse() + 0.3 * rng.standard_normal((64, 2))
    duv = rng.standard_normal((64, 2, 3))
    jac = polygon_centroid_jacobian(uv, duv)
    h = 1e-5
    for p in range(3):
        fd = (polygon_centroid(uv + h * duv[:, :, p]) - polygon_centroid(uv - h * duv[:, :, p]))
        np.testing.assert_allclose(jac[:, p], fd / (2 * h), rtol=0, atol=1e-7)


def test_translation_moves_the_centroid_one_for_one():
    uv = _ellipse()
    duv = np.zeros((64, 2, 2))
    duv[:, 0, 0] = 1.0  # every vertex right
    duv[:, 1, 1] = 1.0  # every vertex down
    np.testing.assert_allclose(polygon_centroid_jacobian(uv, duv), np.eye(2), atol=1e-12)


def test_scaling_about_the_origin_moves_the_centroid_by_itself():
    uv = _ellipse()
    jac = polygon_centroid_jacobian(uv, uv[:, :, None])
    np.testing.assert_allclose(jac[:, 0], polygon_centroid(uv), rtol=1e-12)
