"""Draw what the webcam sees for a plate pose: exact geometry, antialiased.

The scene, back to front: the white cloth, the blue square (plate z =
+square_offset), four grey serpentine springs (plate z = 0) whose inner ends
follow the plate, the red cross (plate z = -cross_offset), and the red rod
with its black end face, seen in perspective. :class:`Appearance` dresses it
otherwise for a real build (:mod:`camwhisker.sim.render.builds`): its colours,
white translucent springs along the cross's arms, a light cross centre.

Every plate feature is drawn by casting the pixel's own ray through the
camera model of :mod:`camwhisker.sensor.camera` (distortion included) and
intersecting it with the feature in the plate frame of :mod:`camwhisker.sensor.plate`,
so the image agrees with the forward model the front end inverts.

Antialiasing is adaptive supersampling. Each layer is first decided at pixel
centres; pixels whose 3x3 neighbourhood is not uniform are then sampled at
``samples`` points of a Fibonacci lattice. The lattice has as many distinct
column and row offsets as samples, so the coverage of a straight edge in any
orientation is exact to 1 / samples of a pixel (0.011 px for 89 samples).
The lattice is shifted by a fixed random amount in each pixel (a
Cranley-Patterson rotation), so that along an edge the rounding errors of
neighbouring pixels are independent and average out instead of adding up.
Sub-pixel ray directions are interpolated bilinearly from the per-pixel
rays, which is exact without distortion and within ~1e-6 px with it. A pixel's
ray is computed the first time a layer's box covers it (most of the frame is
cloth, which casts no ray).

The springs are not tracked; they are drawn as antialiased polylines from
their projected, deformed centre lines.

Colours are BGR in linear digital numbers (0-255) before the webcam
artefacts of :mod:`camwhisker.sim.render.artefacts`.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from camwhisker.sensor.camera import project, unproject
from camwhisker.sensor.file import Sensor
from camwhisker.sensor.plate import (
    Pose,
    cross_outline,
    in_cross,
    in_cross_centre,
    in_square,
    plate_to_camera,
    rod_frame,
    rod_rims,
    rotation_cam_from_plate,
    square_corners,
)

__all__ = ["Appearance", "SceneRenderer", "fibonacci_offsets"]


@dataclass(frozen=True)
class Appearance:
    """Colours and dressing of the scene. Colours are BGR, linear, 0-255."""

    cloth_bgr: tuple[float, float, float] = (222.0, 226.0, 230.0)
    square_bgr: tuple[float, float, float] = (185.0, 80.0, 40.0)
    cross_bgr: tuple[float, float, float] = (45.0, 50.0, 200.0)
    tip_bgr: tuple[float, float, float] = (24.0, 24.0, 26.0)
    spring_bgr: tuple[float, float, float] = (150.0, 150.0, 152.0)
    #: Relative amplitude of the cloth's folds (broad) and weave (fine).
    cloth_folds: float = 0.035
    cloth_weave: float = 0.015
    texture_seed: int = 7
    spring_inner_mm: float = 4.3
    spring_outer_mm: float = 16.0
    spring_turns: int = 9
    spring_amplitude_mm: float = 0.9
    spring_width_mm: float = 0.5
    #: "diagonal": springs leave the plate at 45, 135, 225 and 315 deg (the nominal
    #: sensor); "arms": along the cross's arms, from the square's edge.
    spring_layout: str = "diagonal"
    #: Opacity of the springs: translucent acrylic lets the cloth show through.
    spring_opacity: float = 1.0
    #: The rod's body colour; None paints it like the cross.
    rod_bgr: tuple[float, float, float] | None = None
    #: A light disc at the cross's centre (unpainted), or None for a red centre.
    cross_centre_bgr: tuple[float, float, float] | None = None
    cross_centre_diameter_mm: float = 1.6


def fibonacci_offsets(n: int) -> np.ndarray:
    """Sub-pixel sample offsets in [-0.5, 0.5)^2, shape (n, 2), on a rank-1 lattice.

    ``n`` must be a Fibonacci number (e.g. 34, 55, 89, 144); the generator is
    the previous Fibonacci number, which gives the lattice its low discrepancy.
    """
    a, b = 1, 2
    while b < n:
        a, b = b, a + b
    if b != n:
        raise ValueError(f"samples must be a Fibonacci number, got {n}")
    i = np.arange(n)
    return np.column_stack([(i + 0.5) / n, ((i * a) % n + 0.5) / n]) - 0.5


class SceneRenderer:
    """Noise-free geometry of the scene for any pose, for one sensor.

    Parameters
    ----------
    sensor : Sensor
    appearance : Appearance, optional
    samples : int
        Supersamples per edge pixel; a Fibonacci number.
    """

    #: Extra pixels around each layer's projected outline (covers the 3x3 test).
    BBOX_MARGIN_PX = 4
    #: Seed of the per-pixel lattice shifts: fixed, so every render is reproducible.
    LATTICE_SEED = 20261122
    #: Side of the square tiles whose pixel rays are computed together when first needed.
    RAY_TILE_PX = 32

    def __init__(self, sensor: Sensor, appearance: Appearance | None = None, samples: int = 89):
        self.sensor = sensor
        self.appearance = appearance or Appearance()
        self.offsets = fibonacci_offsets(samples)
        cam = sensor.camera
        rng = np.random.default_rng(self.LATTICE_SEED)
        self._shifts = rng.uniform(0.0, 1.0, (cam.height_px, cam.width_px, 2))
        self.shape = (cam.height_px, cam.width_px)
        self._ray_cache = np.full((cam.height_px, cam.width_px, 2), np.nan)
        t = self.RAY_TILE_PX
        self._ray_tiles = np.zeros((-(-cam.height_px // t), -(-cam.width_px // t)), bool)
        self.background = self._cloth()
        self._spring_paths = self._spring_centrelines()

    # ------------------------------------------------------------------ public
    def geometry(self, pose: Pose) -> np.ndarray:
        """Noise-free image of the scene, float32, shape (height, width, 3), BGR."""
        app, plate = self.appearance, self.sensor.plate
        img = self.background.copy()
        square = self._planar_layer(pose, square_corners(plate), in_square)
        self._composite(img, *square, app.square_bgr)
        self._composite_springs(img, pose)
        cross = self._planar_layer(pose, cross_outline(plate), in_cross)
        self._composite(img, *cross, app.cross_bgr)
        if app.cross_centre_bgr is not None:
            self._composite(img, *self._cross_centre(pose), app.cross_centre_bgr)
        self._composite_rod(img, pose)
        return img

    # ---------------------------------------------------------------- layers
    def rays(self, rows: slice, cols: slice) -> np.ndarray:
        """Normalised ray of each pixel centre in a region, shape (rows, cols, 2), as
        :func:`camwhisker.sensor.camera.pixel_rays` gives them."""
        t, (h, w) = self.RAY_TILE_PX, self.shape
        r0, c0 = rows.start // t, cols.start // t
        todo = np.argwhere(~self._ray_tiles[r0 : -(-rows.stop // t), c0 : -(-cols.stop // t)])
        if len(todo):
            tiles = [np.mgrid[i * t : min(i * t + t, h), j * t : min(j * t + t, w)]
                     for i, j in todo + (r0, c0)]  # fmt: skip
            v = np.concatenate([vv.ravel() for vv, _ in tiles])
            u = np.concatenate([uu.ravel() for _, uu in tiles])
            self._ray_cache[v, u] = unproject(np.column_stack([u, v]).astype(float),
                                              self.sensor.camera)  # fmt: skip
            self._ray_tiles[tuple((todo + (r0, c0)).T)] = True
        return self._ray_cache[rows, cols]

    def _rays_at(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Bilinearly interpolated normalised rays at sub-pixel positions, shape (N, 2)."""
        h, w = self.shape
        u0 = np.clip(np.floor(u).astype(int), 0, w - 2)
        v0 = np.clip(np.floor(v).astype(int), 0, h - 2)
        fu = (u - u0)[:, None]
        fv = (v - v0)[:, None]
        self.rays(slice(v0.min(), v0.max() + 2), slice(u0.min(), u0.max() + 2))
        r = self._ray_cache
        top = r[v0, u0] * (1 - fu) + r[v0, u0 + 1] * fu
        bottom = r[v0 + 1, u0] * (1 - fu) + r[v0 + 1, u0 + 1] * fu
        return top * (1 - fv) + bottom * fv

    def _sample_positions(self, rows: np.ndarray, cols: np.ndarray):
        """Supersample positions (u, v), each shape (N, samples), in the given pixels."""
        shifted = np.mod(self.offsets[None] + 0.5 + self._shifts[rows, cols][:, None], 1.0) - 0.5
        return cols[:, None] + shifted[..., 0], rows[:, None] + shifted[..., 1]

    def _bbox(self, points_in_camera: np.ndarray) -> tuple[slice, slice] | None:
        uv = project(points_in_camera, self.sensor.camera)
        uv = uv[np.isfinite(uv).all(axis=1)]
        if len(uv) == 0:
            return None
        h, w = self.shape
        m = self.BBOX_MARGIN_PX
        u0, v0 = np.floor(uv.min(axis=0)).astype(int) - m
        u1, v1 = np.ceil(uv.max(axis=0)).astype(int) + m + 1
        u0, v0, u1, v1 = max(u0, 0), max(v0, 0), min(u1, w), min(v1, h)
        if u0 >= u1 or v0 >= v1:
            return None
        return slice(v0, v1), slice(u0, u1)

    def _mixed(self, labels: np.ndarray) -> np.ndarray:
        kernel = np.ones((3, 3), np.uint8)
        lab = labels.astype(np.uint8)
        return cv2.dilate(lab, kernel) != cv2.erode(lab, kernel)

    def _planar_layer(self, pose: Pose, outline: np.ndarray, inside):
        """Coverage of a flat feature with the given outline, shape (M, 3), in the plate
        frame (constant z), and membership test ``inside(x, y, plate)``.

        Returns (coverage, bbox), coverage float32 in [0, 1] over the bbox.
        """
        plate = self.sensor.plate
        rot = rotation_cam_from_plate(pose.phi_rad, pose.theta_rad)
        t = np.array([pose.sx_mm, pose.sy_mm, plate.z_i_mm - pose.dz_mm])
        z_plate = outline[0, 2]
        box = self._bbox(plate_to_camera(_densify(outline, 16), pose, plate))
        if box is None:
            return None, None
        rt = rot.T
        rt_t = rt @ t
        normal = rot[:, 2]
        depth = normal @ (rot @ np.array([0.0, 0.0, z_plate]) + t)  # n . (point on plane)

        def hit(xy):
            d = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
            denom = d @ normal
            with np.errstate(divide="ignore", invalid="ignore"):
                s = depth / denom
            p = s[:, None] * (d @ rt.T) - rt_t
            return inside(p[:, 0], p[:, 1], plate) & (s > 0)

        return self._coverage(box, hit), box

    def _cross_centre(self, pose: Pose):
        """Coverage and bbox of the light disc at the cross's centre."""
        plate = self.sensor.plate
        r = self.appearance.cross_centre_diameter_mm / 2
        ang = np.linspace(0.0, 2 * np.pi, 32, endpoint=False)
        centre = cross_outline(plate).mean(axis=0)
        disc = centre + np.column_stack([r * np.cos(ang), r * np.sin(ang), np.zeros(32)])
        return self._planar_layer(pose, disc, lambda x, y, p: in_cross_centre(x, y, p, r))

    def _coverage(self, box, hit) -> np.ndarray:
        rows, cols = box
        rays = self.rays(rows, cols)
        shape = rays.shape[:2]
        centre = hit(rays.reshape(-1, 2)).reshape(shape)
        cover = centre.astype(np.float32)
        mixed = np.nonzero(self._mixed(centre))
        if len(mixed[0]):
            u, v = self._sample_positions(mixed[0] + rows.start, mixed[1] + cols.start)
            inside = hit(self._rays_at(u.ravel(), v.ravel())).reshape(u.shape)
            cover[mixed] = inside.mean(axis=1)
        return cover

    @staticmethod
    def _composite(img, cover, box, bgr) -> None:
        if cover is None:
            return
        region = img[box]
        a = cover[..., None]
        region *= 1 - a
        region += a * np.asarray(bgr, np.float32)

    # ------------------------------------------------------------------ rod
    def _rod_shade(self, xy: np.ndarray, pose: Pose) -> tuple[np.ndarray, np.ndarray]:
        """Label (0 miss, 1 body, 2 end face) and BGR colour of each ray, shape (N,), (N, 3).

        The rod is the cylinder x^2 + y^2 = rho^2, z_tip <= z <= -cross_offset in
        its own frame (:func:`camwhisker.sensor.plate.rod_frame`; the plate's, with
        z_tip = -h_r, for the nominal rod); its end face z = z_tip faces the camera.
        """
        plate, app = self.sensor.plate, self.appearance
        rho = plate.rod_diameter_mm / 2
        rot = rotation_cam_from_plate(pose.phi_rad, pose.theta_rad)
        t = np.array([pose.sx_mm, pose.sy_mm, plate.z_i_mm - pose.dz_mm])
        origin = -(rot.T @ t)  # camera centre in the plate frame
        d = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        dp = d @ rot  # = (R^T d^T)^T: ray directions in the plate frame
        rod_rot, rod_origin, z_tip = rod_frame(plate)
        if rod_rot is not None:  # into the rod's frame
            origin = rod_rot.T @ (origin - rod_origin)
            dp = dp @ rod_rot
        ox, oy, oz = origin
        # End face: plane z = z_tip.
        with np.errstate(divide="ignore", invalid="ignore"):
            s_face = (z_tip - oz) / dp[:, 2]
        fx, fy = ox + s_face * dp[:, 0], oy + s_face * dp[:, 1]
        face = (fx * fx + fy * fy <= rho * rho) & (s_face > 0)
        # Side: nearest root of |o_xy + s d_xy|^2 = rho^2.
        qa = dp[:, 0] ** 2 + dp[:, 1] ** 2
        qb = 2 * (ox * dp[:, 0] + oy * dp[:, 1])
        qc = ox * ox + oy * oy - rho * rho
        disc = qb * qb - 4 * qa * qc
        ok = (disc > 0) & (qa > 1e-12)
        s_side = np.full(len(xy), np.inf)
        s_side[ok] = (-qb[ok] - np.sqrt(disc[ok])) / (2 * qa[ok])
        z_side = oz + s_side * dp[:, 2]
        side = ok & (z_side >= z_tip) & (z_side <= -plate.cross_offset_mm) & (s_side > 0)
        label = np.where(face & ~(side & (s_side < s_face)), 2, np.where(side, 1, 0))
        colour = np.zeros((len(xy), 3))
        colour[label == 2] = app.tip_bgr
        body = label == 1
        if body.any():
            px = ox + s_side[body] * dp[body, 0]
            py = oy + s_side[body] * dp[body, 1]
            cos_view = np.abs(px * dp[body, 0] + py * dp[body, 1]) / rho
            # Lambert shading with the LEDs beside the lens: the flanks darken.
            body_bgr = app.cross_bgr if app.rod_bgr is None else app.rod_bgr
            colour[body] = np.outer(0.45 + 0.55 * cos_view, body_bgr)
        return label, colour

    def _composite_rod(self, img: np.ndarray, pose: Pose) -> None:
        plate = self.sensor.plate
        box = self._bbox(plate_to_camera(rod_rims(plate), pose, plate))
        if box is None:
            return
        rows, cols = box
        rays = self.rays(rows, cols)
        shape = rays.shape[:2]
        label, colour = self._rod_shade(rays.reshape(-1, 2), pose)
        label = label.reshape(shape)
        cover = (label > 0).astype(np.float32)
        paint = colour.reshape(*shape, 3).astype(np.float32)
        mixed = np.nonzero(self._mixed(label))
        if len(mixed[0]):
            u, v = self._sample_positions(mixed[0] + rows.start, mixed[1] + cols.start)
            lab, col = self._rod_shade(self._rays_at(u.ravel(), v.ravel()), pose)
            lab = lab.reshape(u.shape)
            col = col.reshape(*u.shape, 3)
            hits = (lab > 0).sum(axis=1)
            cover[mixed] = hits / lab.shape[1]
            with np.errstate(invalid="ignore", divide="ignore"):
                paint[mixed] = np.where(hits[:, None] > 0, col.sum(axis=1) / hits[:, None], 0.0)
        region = img[box]
        a = cover[..., None]
        region *= 1 - a
        region += a * paint

    # -------------------------------------------------------------- springs
    def _spring_centrelines(self) -> list[np.ndarray]:
        """Centre line of each spring in the plate plane z = 0, at rest, (N, 3) each."""
        app = self.appearance
        n = app.spring_turns
        r0, r1, amp = app.spring_inner_mm, app.spring_outer_mm, app.spring_amplitude_mm
        half = (r1 - r0) / (2 * n)
        pts = [(r0, 0.0)]
        for j in range(2 * n):  # a meander: across at r, then outward by half a pitch
            side = amp if j % 2 == 0 else -amp
            pts += [(r0 + j * half, side), (r0 + (j + 1) * half, side)]
        pts.append((r1, 0.0))
        path = np.array(pts)
        path = _densify_open(path, 6)
        lines = []
        angles = (
            [45.0, 135.0, 225.0, 315.0]
            if app.spring_layout == "diagonal"
            else [0.0, 90.0, 180.0, 270.0]
        )
        for angle in np.radians(angles):
            er = np.array([np.cos(angle), np.sin(angle)])
            et = np.array([-np.sin(angle), np.cos(angle)])
            xy = path[:, :1] * er + path[:, 1:] * et
            lines.append(np.column_stack([xy, np.zeros(len(xy)), path[:, 0]]))
        return lines

    def _composite_springs(self, img: np.ndarray, pose: Pose) -> None:
        app, plate, cam = self.appearance, self.sensor.plate, self.sensor.camera
        mask = np.zeros(self.shape, np.uint8)
        width_px = max(1, round(app.spring_width_mm * cam.fx_px / plate.z_i_mm))
        shift_bits = 4
        rest = Pose()
        r0, r1 = app.spring_inner_mm, app.spring_outer_mm
        for line in self._spring_paths:
            pts, radius = line[:, :3], line[:, 3]
            # The inner end moves with the plate, the outer end is clamped.
            w = np.clip((r1 - radius) / (r1 - r0), 0.0, 1.0)[:, None] ** 2
            moved = w * plate_to_camera(pts, pose, plate) + (1 - w) * plate_to_camera(
                pts, rest, plate
            )
            uv = project(moved, cam)
            uv = uv[np.isfinite(uv).all(axis=1)]
            fixed = np.round(uv * (1 << shift_bits)).astype(np.int32)
            cv2.polylines(mask, [fixed], False, 255, width_px, cv2.LINE_AA, shift_bits)
        a = (mask.astype(np.float32) / 255.0)[..., None]
        if app.spring_opacity != 1.0:
            a *= np.float32(app.spring_opacity)
        img *= 1 - a
        img += a * np.asarray(app.spring_bgr, np.float32)

    # ---------------------------------------------------------------- cloth
    def _cloth(self) -> np.ndarray:
        app = self.appearance
        rng = np.random.default_rng(app.texture_seed)
        h, w = self.shape
        folds = cv2.GaussianBlur(rng.standard_normal((h, w)).astype(np.float32), (0, 0), 40)
        weave = cv2.GaussianBlur(rng.standard_normal((h, w)).astype(np.float32), (0, 0), 1.2)
        folds /= folds.std()
        weave /= weave.std()
        texture = 1.0 + app.cloth_folds * folds + app.cloth_weave * weave
        return texture[..., None] * np.asarray(app.cloth_bgr, np.float32)


def _densify(polygon: np.ndarray, n: int) -> np.ndarray:
    """Closed polygon (M, 3) with n points per edge, (M * n, 3)."""
    nxt = np.roll(polygon, -1, axis=0)
    f = (np.arange(n) / n)[None, :, None]
    return (polygon[:, None] * (1 - f) + nxt[:, None] * f).reshape(-1, polygon.shape[1])


def _densify_open(path: np.ndarray, n: int) -> np.ndarray:
    f = (np.arange(n) / n)[None, :, None]
    seg = path[:-1, None] * (1 - f) + path[1:, None] * f
    return np.concatenate([seg.reshape(-1, path.shape[1]), path[-1:]])
