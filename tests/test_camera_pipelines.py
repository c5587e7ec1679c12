"""The reality suite's second imaging pipeline: a defocus lens, a Bayer sensor, 4:2:2."""

import dataclasses

import cv2
import numpy as np
import pytest

from camwhisker.sim.render.artefacts import (
    HALO_SCALE,
    HALO_SHARE,
    Artefacts,
    _lens,
    apply_artefacts,
)
from camwhisker.sim.render.builds import draw_build


def _flat(bgr, shape=(64, 96)):
    return np.broadcast_to(np.asarray(bgr, np.float32), (*shape, 3)).copy()


def test_a_demosaiced_flat_colour_is_that_colour():
    # No noise: each photosite keeps its own filter's value of a flat field, and the
    # interpolation between them gives it back, to the 8 bits' rounding.
    out = apply_artefacts(_flat((50, 100, 200)), 0.0, Artefacts(bayer=True),
                          np.random.default_rng(0))  # fmt: skip
    assert np.abs(out[2:-2, 2:-2].astype(int) - (50, 100, 200)).max() <= 1


def test_the_defocus_lens_keeps_the_light_and_has_its_stated_spread():
    sigma = 1.5
    delta = np.zeros((81, 81, 3), np.float32)
    delta[40, 40] = 1.0
    art = Artefacts(blur_sigma_px=sigma, psf="defocus")
    k = _lens(delta, art)[..., 0].astype(float)
    y, x = np.mgrid[-40:41, -40:41]
    assert k.sum() == pytest.approx(1.0, abs=1e-5)  # the kernels are normalised
    # Per axis: the disc's sigma^2 and the halo's (HALO_SCALE sigma)^2, mixed; 3 %
    # for the disc drawn on an 8x finer grid and averaged onto the pixels.
    want = (1 - HALO_SHARE) * sigma**2 + HALO_SHARE * (HALO_SCALE * sigma) ** 2
    assert (k * x * x).sum() == pytest.approx(want, rel=0.03)
    assert (k * y * y).sum() == pytest.approx(want, rel=0.03)


def test_422_keeps_luma_and_shares_chroma_between_pixel_pairs():
    rng = np.random.default_rng(1)
    # Mid-range colours: a pair's shared chroma never takes a channel past 0 or 255.
    scene = rng.uniform(80, 170, (32, 48, 3)).astype(np.float32)
    plain = apply_artefacts(scene, 0.0, Artefacts(), np.random.default_rng(0))
    sent = apply_artefacts(scene, 0.0, Artefacts(chroma_422=True), np.random.default_rng(0))
    y0, y1 = (cv2.cvtColor(f, cv2.COLOR_BGR2YCrCb).astype(int) for f in (plain, sent))
    # Luma as sent, up to the rounding of two colour conversions (2 DN).
    assert np.abs(y1[..., 0] - y0[..., 0]).max() <= 2
    # Chroma alike within each pair (the conversions' rounding), unlike before.
    assert np.abs(y1[:, 0::2, 1:] - y1[:, 1::2, 1:]).max() <= 2
    assert np.abs(y0[:, 0::2, 1:] - y0[:, 1::2, 1:]).max() > 10


def test_the_mosaic_pipeline_changes_the_camera_alone():
    webcam, mosaic = draw_build(7), draw_build(7, pipeline="mosaic")
    assert mosaic.sensor == webcam.sensor and mosaic.appearance == webcam.appearance
    assert {k: v for k, v in mosaic.webcam.items() if k in webcam.webcam} == webcam.webcam
    assert mosaic.webcam["bayer"] and mosaic.webcam["psf"] == "defocus"
    hard = draw_build(7, pipeline="mosaic", look="hard")
    assert (hard.webcam["blur_sigma_px"], hard.webcam["noise_dn"]) == (2.6, 5.0)
    # Every field a pipeline or look sets is one of the camera's.
    names = {f.name for f in dataclasses.fields(Artefacts)}
    assert set(hard.webcam) <= names
    with pytest.raises(ValueError, match="pipeline"):
        draw_build(7, pipeline="film")
