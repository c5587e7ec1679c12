"""The physical limit: Cramér-Rao bound on the pose from the pixels themselves.

For an image model I(q) observed with independent Gaussian noise of standard
deviation sigma_k in each pixel and channel k, the Fisher information is::

    F_ij = sum_k (dI_k / dq_i) (dI_k / dq_j) / sigma_k^2

and no unbiased estimator of q has a standard deviation below
sqrt(diag(F^-1)). The derivatives are central finite differences of the
noise-free image (blur, lighting and the cloth included; noise, JPEG and the
camera's 8-bit rounding left out, the rounding entering as its 1/12 DN^2 of
variance). The noise model is the renderer's: signal-dependent, from
:class:`~camwhisker.sim.render.artefacts.Artefacts`.

References
----------
S. M. Kay, Fundamentals of Statistical Signal Processing: Estimation Theory,
Prentice Hall, 1993, ch. 3 (eq. 3.31 for the Gaussian case).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import cv2
import numpy as np

from camwhisker.sensor.file import Sensor
from camwhisker.sensor.plate import Pose
from camwhisker.sim.render.artefacts import Artefacts, illumination_field
from camwhisker.sim.render.render import SceneRenderer

__all__ = [
    "fisher_information",
    "cramer_rao_bound",
    "pose_bound",
    "POSE_STEPS",
    "nominal_bound_pose",
]

#: Finite-difference half-steps for the pose parameters (file units). Each
#: moves the features by ~0.1-0.3 px: large against the renderer's coverage
#: quantisation (1/89 px), small against the blur scale.
POSE_STEPS = {"dz_mm": 0.004, "phi_deg": 0.02, "theta_deg": 0.1, "sx_mm": 0.004, "sy_mm": 0.004}

#: Finite differences leave relative errors of ~1e-8 in F; beyond this condition
#: number its inverse is noise.
SINGULAR_COND = 1e10

#: Variance of rounding to whole digital numbers, DN^2.
QUANTISATION_VAR = 1.0 / 12.0


def fisher_information(
    image: Callable[[np.ndarray], np.ndarray],
    params: np.ndarray,
    steps: np.ndarray,
    noise_var: np.ndarray | float,
) -> np.ndarray:
    """Fisher information of ``params`` for an image observed in Gaussian noise.

    Parameters
    ----------
    image : callable
        ``image(params) -> ndarray`` of any shape, the noise-free observation.
    params : ndarray, shape (P,)
    steps : ndarray, shape (P,)
        Central-difference half-steps.
    noise_var : ndarray or float
        Noise variance per element of the image (broadcastable to it).

    Returns
    -------
    ndarray, shape (P, P)
    """
    params = np.asarray(params, dtype=float)
    grads = []
    for i, h in enumerate(np.asarray(steps, dtype=float)):
        up, down = params.copy(), params.copy()
        up[i] += h
        down[i] -= h
        grads.append(((image(up).astype(float) - image(down).astype(float)) / (2 * h)).ravel())
    g = np.array(grads)
    w = np.broadcast_to(1.0 / np.asarray(noise_var, dtype=float), image(params).shape).ravel()
    return (g * w) @ g.T


def cramer_rao_bound(fisher: np.ndarray) -> np.ndarray:
    """Standard-deviation bound sqrt(diag(F^-1)), shape (P,).

    All inf where F is singular to working precision (condition number above
    ``SINGULAR_COND``): the image cannot tell the parameters apart.
    """
    fisher = np.asarray(fisher, dtype=float)
    if not np.isfinite(fisher).all() or np.linalg.cond(fisher) > SINGULAR_COND:
        return np.full(len(fisher), np.inf)
    cov = np.linalg.inv(fisher)
    d = np.diag(cov)
    return np.where(d > 0, np.sqrt(np.abs(d)), np.inf)


def pose_bound(
    sensor: Sensor,
    pose: Pose,
    artefacts: Artefacts,
    params: Sequence[str] = ("dz_mm", "phi_deg", "theta_deg"),
    renderer: SceneRenderer | None = None,
) -> dict[str, float]:
    """Cramér-Rao standard deviation of each pose parameter, in file units.

    Parameters not listed are held known (list ``sx_mm``, ``sy_mm`` to treat
    the lateral shift as a nuisance to be estimated too).
    """
    renderer = renderer or SceneRenderer(sensor)
    light = illumination_field(renderer.shape, artefacts) * artefacts.gain
    base = {
        "dz_mm": pose.dz_mm,
        "phi_deg": pose.phi_deg,
        "theta_deg": pose.theta_deg,
        "sx_mm": pose.sx_mm,
        "sy_mm": pose.sy_mm,
    }
    unknown = set(params) - set(base)
    if unknown:
        raise ValueError(f"unknown pose parameter {sorted(unknown)[0]!r} (known: {list(base)})")

    def image(q: np.ndarray) -> np.ndarray:
        values = dict(base, **dict(zip(params, q, strict=True)))
        scene = renderer.geometry(Pose.from_degrees(**values)) * light[..., None]
        if artefacts.blur_sigma_px > 0:
            scene = cv2.GaussianBlur(scene, (0, 0), artefacts.blur_sigma_px)
        return scene

    clean = image(np.array([base[p] for p in params]))
    f = 1 - artefacts.read_noise_fraction
    var = artefacts.noise_dn**2 * (artefacts.read_noise_fraction + f * np.maximum(clean, 0) / 128)
    fisher = fisher_information(
        image,
        np.array([base[p] for p in params]),
        np.array([POSE_STEPS[p] for p in params]),
        var + QUANTISATION_VAR,
    )
    return dict(zip(params, cramer_rao_bound(fisher).tolist(), strict=True))


def nominal_bound_pose() -> Pose:
    """The pose at which the bound is quoted: mid-range tilt and deflection."""
    return Pose.from_degrees(dz_mm=0.5, phi_deg=15.0, theta_deg=30.0)
