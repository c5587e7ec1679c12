"""Renderer geometry against the plate model, in pixels.

The square is blue on the white cloth; in the red channel the contrast is
~190 DN, and the renderer's background and colours are known, so each
pixel's coverage alpha = (I - cloth) / (blue - cloth) is read exactly. Summed
across an edge, the coverages give the edge's sub-pixel position in that row
(exact area coverage of a straight edge). The renderer quantises coverage to
1/89 px per pixel (Fibonacci supersampling), so 0.02 px holds with margin in
every row, and the mean over rows is far tighter.
"""

import numpy as np
import pytest

from camwhisker.sensor.camera import project, unproject
from camwhisker.sensor.file import Sensor
from camwhisker.sensor.plate import Pose, plate_to_camera, square_corners
from camwhisker.sim.render.render import SceneRenderer, fibonacci_offsets

RED = 2
HALF_WINDOW = 6  # px either side of the predicted edge; the cross stays > 20 px away


@pytest.fixture(scope="module")
def plain():
    return SceneRenderer(Sensor())


@pytest.fixture(scope="module")
def distorted():
    cam = {"distortion": [-0.28, 0.11, 0.0012, -0.0009, -0.02], "cx_px": 618.3, "cy_px": 372.8}
    return SceneRenderer(Sensor().replace(camera=cam))


def edge_u(renderer, img, v, u_pred, square_on_right):
    """Sub-pixel column of the square's edge in row v, from coverage."""
    j0 = int(np.floor(u_pred)) - HALF_WINDOW
    j1 = int(np.floor(u_pred)) + HALF_WINDOW
    bg = renderer.background[v, j0 : j1 + 1, RED]
    blue = renderer.appearance.square_bgr[RED]
    alpha = (img[v, j0 : j1 + 1, RED] - bg) / (blue - bg)
    if square_on_right:
        return j1 + 0.5 - alpha.sum()
    return j0 - 0.5 + alpha.sum()


def model_edge(renderer, pose, corner_a, corner_b, rows):
    """Model column of the square edge a-b at each row, through the exact camera model."""
    plate = renderer.sensor.plate
    c = square_corners(plate)
    t = np.linspace(0, 1, 4001)[:, None]
    pts = c[corner_a] * (1 - t) + c[corner_b] * t
    uv = project(plate_to_camera(pts, pose, plate), renderer.sensor.camera)
    order = np.argsort(uv[:, 1])
    return np.interp(rows, uv[order, 1], uv[order, 0])


def middle_rows(renderer, pose, corner_a, corner_b):
    uv = project(
        plate_to_camera(square_corners(renderer.sensor.plate), pose, renderer.sensor.plate),
        renderer.sensor.camera,
    )
    va, vb = sorted([uv[corner_a, 1], uv[corner_b, 1]])
    span = vb - va
    return np.arange(int(va + 0.25 * span), int(vb - 0.25 * span))


@pytest.mark.parametrize(
    "pose",
    [Pose(), Pose.from_degrees(0.4, 12.0, 40.0), Pose.from_degrees(0.9, 25.0, 10.0, 0.2, -0.1)],
    ids=["rest", "tilt12", "tilt25_shift"],
)
@pytest.mark.parametrize("which", ["plain", "distorted"])
def test_square_left_edge_lies_on_the_model_within_002_px(request, pose, which):
    renderer = request.getfixturevalue(which)
    img = renderer.geometry(pose)
    rows = middle_rows(renderer, pose, 0, 3)  # left edge: top-left to bottom-left corner
    pred = model_edge(renderer, pose, 0, 3, rows)
    meas = np.array([edge_u(renderer, img, v, u, True) for v, u in zip(rows, pred, strict=True)])
    err = meas - pred
    assert len(rows) > 60
    assert np.abs(err).max() < 0.02
    assert abs(err.mean()) < 0.003  # quantisation averages out along the edge


def test_square_width_follows_pinhole_with_dz(plain):
    widths = {}
    for dz in (0.0, 0.5, 1.0):
        pose = Pose(dz_mm=dz)
        img = plain.geometry(pose)
        rows = middle_rows(plain, pose, 0, 3)
        rows = rows[np.abs(rows - 359.5) > 45]  # keep clear of the cross's horizontal arm
        left = model_edge(plain, pose, 0, 3, rows)
        right = model_edge(plain, pose, 1, 2, rows)
        w = [
            edge_u(plain, img, v, r, False) - edge_u(plain, img, v, lft, True)
            for v, lft, r in zip(rows, left, right, strict=True)
        ]
        widths[dz] = float(np.mean(w))
    for dz, width in widths.items():
        assert width == pytest.approx(5.0 * 1258.79 / (26.5 - dz), abs=0.01)
    change = widths[1.0] - widths[0.0]
    assert change == pytest.approx(5.0 * 1258.79 * (1 / 25.5 - 1 / 26.5), abs=0.01)


def test_interior_colours_are_exact(plain):
    img = plain.geometry(Pose())
    app = plain.appearance
    assert img[300, 560] == pytest.approx(app.square_bgr)  # blue, between arms
    assert img[359, 560] == pytest.approx(app.cross_bgr)  # left arm
    assert img[359, 639] == pytest.approx(app.tip_bgr)  # end face, on axis
    assert img[50, 640] == pytest.approx(plain.background[50, 640])  # cloth


def test_tilt_shows_the_rod_body_between_tip_and_cross(plain):
    img = plain.geometry(Pose.from_degrees(0.0, 25.0, 0.0))
    tip_u = project(np.array([7.5 * np.sin(np.radians(25)), 0, 25 - 7.5 * np.cos(np.radians(25))]),
                    plain.sensor.camera)[0]  # fmt: skip
    between = img[359, int(tip_u) - 60]
    red = np.asarray(plain.appearance.cross_bgr)
    # Shaded red body: dominated by the red channel, darker than the flat cross.
    assert between[2] > 2 * between[0] and between[2] <= red[2] + 1e-3


def test_fibonacci_offsets_have_distinct_rows_and_columns():
    off = fibonacci_offsets(89)
    assert len(np.unique(off[:, 0])) == 89 and len(np.unique(off[:, 1])) == 89
    assert off.min() > -0.5 and off.max() < 0.5
    with pytest.raises(ValueError, match="Fibonacci"):
        fibonacci_offsets(64)


def test_geometry_does_not_touch_the_background(plain):
    before = plain.background.copy()
    plain.geometry(Pose.from_degrees(0.5, 20.0, 100.0))
    assert np.array_equal(before, plain.background)


def test_rays_computed_when_first_needed_are_the_cameras(distorted):
    # Each pixel's ray is unprojected on its own, so tiles computed as layers ask for them
    # (in any order, over any region) equal the region's rays computed at once, to the
    # bit: renders stay reproducible.
    cam = distorted.sensor.camera
    fresh = SceneRenderer(distorted.sensor)
    for rows, cols in [(slice(300, 331), slice(17, 90)), (slice(0, 720), slice(1200, 1280)),
                       (slice(100, 500), slice(500, 800))]:  # fmt: skip
        v, u = np.mgrid[rows, cols].astype(float)
        at_once = unproject(np.stack([u, v], axis=-1), cam)
        assert np.array_equal(fresh.rays(rows, cols), at_once, equal_nan=True)
    assert fresh._ray_tiles.mean() < 0.3  # only the asked tiles were computed
