"""Pose sequences and camera conditions with known truth: the ordinary and the hard.

A :class:`Scenario` is a :class:`PoseTrack` (per-frame truth), the webcam
:class:`~camwhisker.sim.render.artefacts.Artefacts`, and changes to the sensor file
(lens distortion, an off-centre principal point) where the scene needs them.
Builders take the number of frames and a seed; nothing else is random.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from camwhisker.files.atomic import atomic_path
from camwhisker.sensor.plate import Pose
from camwhisker.sim.render.artefacts import Artefacts

__all__ = [
    "PoseTrack",
    "Scenario",
    "SCENARIOS",
    "make_scenario",
    "ordinary_track",
    "sweep_track",
    "wrap_deg",
]

#: Columns of the truth table written beside every rendered video.
TRUTH_COLUMNS = ("frame", "t_s", "dz_mm", "phi_deg", "theta_deg", "sx_mm", "sy_mm")


def wrap_deg(a: np.ndarray) -> np.ndarray:
    """Angles wrapped to (-180, 180]."""
    return 180.0 - np.mod(180.0 - np.asarray(a, dtype=float), 360.0)


@dataclass(frozen=True)
class PoseTrack:
    """Per-frame truth; every array has shape (n_frames,)."""

    t_s: np.ndarray
    dz_mm: np.ndarray
    phi_deg: np.ndarray
    theta_deg: np.ndarray
    sx_mm: np.ndarray
    sy_mm: np.ndarray

    def __len__(self) -> int:
        return len(self.t_s)

    def pose(self, i: int) -> Pose:
        return Pose.from_degrees(
            self.dz_mm[i], self.phi_deg[i], self.theta_deg[i], self.sx_mm[i], self.sy_mm[i]
        )

    def write_csv(self, path: Path) -> None:
        """The truth table: theta is left empty where phi is exactly 0 (undefined)."""
        with atomic_path(path) as tmp, open(tmp, "w", newline="") as fh:
            out = csv.writer(fh)
            out.writerow(TRUTH_COLUMNS)
            for i in range(len(self)):
                theta = "" if self.phi_deg[i] == 0 else f"{self.theta_deg[i]:.6f}"
                out.writerow(
                    [i, f"{self.t_s[i]:.6f}", f"{self.dz_mm[i]:.6f}", f"{self.phi_deg[i]:.6f}",
                     theta, f"{self.sx_mm[i]:.6f}", f"{self.sy_mm[i]:.6f}"]
                )  # fmt: skip

    @classmethod
    def read_csv(cls, path: Path) -> PoseTrack:
        with open(path, newline="") as fh:
            rows = list(csv.DictReader(fh))
        cols = {c: np.array([float(r[c] or "nan") for r in rows]) for c in TRUTH_COLUMNS[1:]}
        return cls(**cols)


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    track: PoseTrack
    artefacts: Artefacts
    fps: float
    #: Changes to the sensor file, as for :meth:`camwhisker.sensor.file.Sensor.replace`.
    sensor_changes: dict = field(default_factory=dict)


def ordinary_track(
    n: int,
    fps: float,
    rng: np.random.Generator,
    phi_max_deg: float = 30.0,
    dz_max_mm: float = 1.0,
    shift_max_mm: float = 0.0,
    hold_frames: int = 4,
) -> PoseTrack:
    """Rest frames, then stage-like holds at random poses, then smooth sweeps.

    A tenth of the frames (at least 3) are at rest, about 40% are holds of
    ``hold_frames`` frames each, the rest are one smooth sweep through the range.
    """
    n_rest = max(3, n // 10)
    n_hold = (int(0.4 * n) // hold_frames) * hold_frames
    n_sweep = n - n_rest - n_hold
    if n_sweep < 0:
        raise ValueError(f"too few frames ({n}) for rest, holds and sweeps")
    k = n_hold // hold_frames
    hold = {
        "phi": np.repeat(phi_max_deg * np.sqrt(rng.uniform(0, 1, k)), hold_frames),
        "theta": np.repeat(rng.uniform(-180, 180, k), hold_frames),
        "dz": np.repeat(rng.uniform(0, dz_max_mm, k), hold_frames),
        "sx": np.repeat(rng.uniform(-shift_max_mm, shift_max_mm, k), hold_frames),
        "sy": np.repeat(rng.uniform(-shift_max_mm, shift_max_mm, k), hold_frames),
    }
    s = (np.arange(n_sweep) + 0.5) / max(n_sweep, 1)
    theta0 = rng.uniform(-180, 180)
    sweep = {
        "phi": phi_max_deg * np.sin(np.pi * s) ** 2,
        "theta": theta0 + 540.0 * s,
        "dz": dz_max_mm * np.sin(1.5 * np.pi * s) ** 2,
        "sx": shift_max_mm * np.sin(2 * np.pi * s),
        "sy": shift_max_mm * np.cos(2 * np.pi * s) * np.sin(np.pi * s),
    }
    rest = np.zeros(n_rest)
    cat = {key: np.concatenate([rest, hold[key], sweep[key]]) for key in hold}
    return PoseTrack(
        t_s=np.arange(n) / fps,
        dz_mm=cat["dz"],
        phi_deg=cat["phi"],
        theta_deg=wrap_deg(cat["theta"]),
        sx_mm=cat["sx"],
        sy_mm=cat["sy"],
    )


def _ramp_track(n, fps, phi_deg, theta_deg, dz_mm=0.0, sx_mm=0.0, sy_mm=0.0, n_rest=3):
    """Rest, then a linear ramp of every given end value over the remaining frames."""
    s = np.concatenate([np.zeros(n_rest), np.linspace(0, 1, n - n_rest)])
    theta = np.full(n, float(theta_deg))
    return PoseTrack(np.arange(n) / fps, dz_mm * s, phi_deg * s, theta, sx_mm * s, sy_mm * s)


#: The nominal webcam of the benchmark: noise ~2 DN, blur 1.4 px, MJPG quality 88.
NOMINAL_ARTEFACTS = Artefacts(
    unevenness=0.15,
    vignetting=0.2,
    cast_bgr=(0.94, 1.0, 1.06),
    cast_drift=0.02,
    flicker=0.005,
    blur_sigma_px=1.4,
    noise_dn=2.0,
    jpeg_quality=88,
)

#: Barrel distortion of a cheap wide lens, with the principal point off centre.
DISTORTED_CAMERA = {
    "distortion": [-0.28, 0.11, 0.0012, -0.0009, -0.02],
    "cx_px": 618.3,
    "cy_px": 372.8,
}

#: The hard webcam: stronger uneven light, vignetting, cast, drift and flicker;
#: blur 2.6 px, noise 5 DN.
HARD_ARTEFACTS = replace(
    NOMINAL_ARTEFACTS,
    unevenness=0.3,
    vignetting=0.3,
    cast_bgr=(0.72, 1.0, 1.32),
    cast_drift=0.05,
    flicker=0.04,
    blur_sigma_px=2.6,
    noise_dn=5.0,
)


def _nominal(n, seed, fps=30.0):
    rng = np.random.default_rng(seed)
    return Scenario(
        "nominal",
        "ordinary holds and sweeps, phi 0-30 deg, dz 0-1 mm, nominal webcam",
        ordinary_track(n, fps, rng),
        NOMINAL_ARTEFACTS,
        fps,
    )


def _distortion(n, seed, fps=30.0):
    base = _nominal(n, seed, fps)
    return replace(
        base,
        name="distortion",
        description="nominal scene through a distorting lens, principal point off centre",
        sensor_changes={"camera": DISTORTED_CAMERA},
    )


def _hard(n, seed, fps=30.0):
    rng = np.random.default_rng(seed)
    return Scenario(
        "hard",
        "phi up to 34 deg, lateral shift, noise 5 DN, blur 2.6 px, strong cast, 4% flicker",
        ordinary_track(n, fps, rng, phi_max_deg=34.0, shift_max_mm=0.3),
        HARD_ARTEFACTS,
        fps,
    )


def _large_tilt(n, seed, fps=30.0):
    rng = np.random.default_rng(seed)
    return Scenario(
        "large_tilt",
        "ramp to phi 35 deg and dz 1 mm",
        _ramp_track(n, fps, 35.0, rng.uniform(-180, 180), dz_mm=1.0),
        NOMINAL_ARTEFACTS,
        fps,
    )


def _rest_bracketed(n, seed, fps=30.0):
    """1 s at rest (a quarter of a short scene), the nominal scene's holds and sweeps
    up to phi 35 deg, then at rest again."""
    n_rest = min(int(round(fps)), n // 4)
    middle = ordinary_track(n - 2 * n_rest, fps, np.random.default_rng(seed), phi_max_deg=35.0)
    keep = middle.phi_deg > 0  # its own rest frames go: the brackets are the rest
    pad = np.zeros(n_rest)
    cols = [np.concatenate([pad, getattr(middle, c)[keep], pad, np.zeros(n)])[:n]
            for c in ("dz_mm", "phi_deg", "theta_deg", "sx_mm", "sy_mm")]  # fmt: skip
    return Scenario(
        "rest_bracketed",
        "1 s at rest, holds and sweeps up to phi 35 deg and dz 1 mm, then at rest again; "
        "no colour drift",
        PoseTrack(np.arange(n) / fps, *cols),
        # The closing rest measures the zero the opening rest set; a drifting cast moves
        # it too (a 1.3 % drift by ~2 um), which is the light's error, not the zero's.
        replace(NOMINAL_ARTEFACTS, cast_drift=0.0),
        fps,
    )


def _tip_crossing(n, seed, fps=30.0):
    return Scenario(
        "tip_crossing",
        "the tip crosses the square's right edge onto the cloth (theta = 0)",
        _ramp_track(n, fps, 30.0, 0.0),
        NOMINAL_ARTEFACTS,
        fps,
    )


def _out_of_frame(n, seed, fps=30.0):
    return Scenario(
        "out_of_frame",
        "the plate is pushed down the image until the square's lower edge leaves the frame",
        _ramp_track(n, fps, 8.0, 90.0, sy_mm=6.0),
        NOMINAL_ARTEFACTS,
        fps,
    )


def _nominal_with(name: str, description: str, **artefact_changes):
    """A builder: the nominal scene's poses under changed webcam artefacts."""

    def build(n, seed, fps=30.0):
        track = ordinary_track(n, fps, np.random.default_rng(seed))
        changes = {k: v(n, fps) if callable(v) else v for k, v in artefact_changes.items()}
        return Scenario(name, description, track, replace(NOMINAL_ARTEFACTS, **changes), fps)

    return build


_lighting_jump = _nominal_with(
    "lighting_jump",
    "the LEDs drop to 70% halfway through",
    lighting_jump=lambda n, fps: ((n // 2) / fps, 0.7),
)
_saturated = _nominal_with(
    "saturated", "exposure 35% too high: the cloth and highlights clip at 255", gain=1.35
)
_heavy_blur = _nominal_with("heavy_blur", "defocus blur sigma 4 px", blur_sigma_px=4.0)


def sweep_track(
    n: int, fps: float, phi_max_deg: float = 30.0, dz_max_mm: float = 0.5, n_rest: int = 10
) -> PoseTrack:
    """Rest frames, then the tilt swept through every direction twice, up to phi_max.

    A calibration sweep: the tilt rises and falls twice while its direction turns
    two and a half times, so every direction is seen at small and large tilt.
    """
    n_rest = min(n_rest, max(1, n // 5))
    s = np.concatenate([np.zeros(n_rest), (np.arange(n - n_rest) + 0.5) / max(n - n_rest, 1)])
    moving = np.arange(n) >= n_rest
    phi = np.where(moving, phi_max_deg * np.sin(2 * np.pi * s) ** 2, 0.0)
    theta = np.where(moving, 900.0 * s, 0.0)
    dz = np.where(moving, dz_max_mm * np.sin(3 * np.pi * s) ** 2, 0.0)
    zero = np.zeros(n)
    return PoseTrack(np.arange(n) / fps, dz, phi, wrap_deg(theta), zero, zero.copy())


def _calibration_sweep(n, seed, fps=30.0):
    return Scenario(
        "calibration_sweep",
        "rest, then the tilt swept through every direction up to 30 deg (for calibrate-sensor)",
        sweep_track(n, fps),
        NOMINAL_ARTEFACTS,
        fps,
    )


#: The paper's test 2 (docs/sensor.md section 7): 0.1 mm axial steps up to 1.0 mm,
#: each reached in a 0.2 s ramp and held 1.5 s, after 1 s at rest.
DZ_STEP_MM = 0.1
DZ_STEPS = 10
DZ_RAMP_S = 0.2
DZ_PAUSE_S = 1.5
DZ_REST_S = 1.0


def dz_steps_track(n: int, fps: float) -> PoseTrack:
    """Rest, then known axial steps (``DZ_STEPS`` of ``DZ_STEP_MM``) with pauses,
    no tilt; a track longer than the steps holds the last one."""
    t = np.arange(n) / fps
    step_s = DZ_RAMP_S + DZ_PAUSE_S
    k = np.clip((t - DZ_REST_S) / step_s, 0.0, None)
    whole = np.floor(k)
    ramp = np.clip((k - whole) * step_s / DZ_RAMP_S, 0.0, 1.0)
    dz = DZ_STEP_MM * np.minimum(whole + ramp, DZ_STEPS)
    zero = np.zeros(n)
    return PoseTrack(t, dz, zero, zero.copy(), zero.copy(), zero.copy())


def dz_steps_frames(fps: float = 30.0) -> int:
    """Frames that the steps take, from the rest to the last pause's end."""
    return int(math.ceil((DZ_REST_S + DZ_STEPS * (DZ_RAMP_S + DZ_PAUSE_S)) * fps))


def _dz_steps(n, seed, fps=30.0):
    return Scenario(
        "dz_steps",
        "rest, then 0.1 mm axial steps to 1.0 mm, 1.5 s pauses (the paper's test 2, "
        "for calibrate-sensor --dz-steps)",
        dz_steps_track(n, fps),
        NOMINAL_ARTEFACTS,
        fps,
    )


SCENARIOS: dict[str, Callable[..., Scenario]] = {
    "nominal": _nominal,
    "distortion": _distortion,
    "hard": _hard,
    "large_tilt": _large_tilt,
    "tip_crossing": _tip_crossing,
    "rest_bracketed": _rest_bracketed,
    "out_of_frame": _out_of_frame,
    "lighting_jump": _lighting_jump,
    "saturated": _saturated,
    "heavy_blur": _heavy_blur,
    "calibration_sweep": _calibration_sweep,
    "dz_steps": _dz_steps,
}


def make_scenario(name: str, n_frames: int, seed: int, fps: float = 30.0) -> Scenario:
    """Build a named scenario (see :data:`SCENARIOS`)."""
    try:
        builder = SCENARIOS[name]
    except KeyError:
        raise ValueError(f"unknown scenario {name!r} (known: {', '.join(SCENARIOS)})") from None
    if n_frames < 1:
        raise ValueError(f"n_frames must be positive, got {n_frames}")
    if not math.isfinite(fps) or fps <= 0:
        raise ValueError(f"fps must be positive, got {fps}")
    return builder(n_frames, seed, fps)
