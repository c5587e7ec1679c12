"""A whisker sliding its tip along a textured surface, ringing in its first mode, filmed.

Same planar frame as :mod:`camwhisker.sim.mechanics.whisker` (base on y = 0
travelling +x at a constant speed, whisker along +y at rest). The surface runs
parallel to the travel at y = l_w - press, so the tip is pressed onto it, and
carries ridges toward the base: height h(x) = a (1 - cos(2 pi x / g)) / 2
(gap g: the ridges' spacing; amplitude a: their height, peak to valley).

- *Contact* (quasi-static, :func:`contact_response`): the elastica of
  :func:`~camwhisker.sim.mechanics.whisker.solve_elastica` with the load at the tip,
  on the tip's surface height, sliding: the load is the flat surface's normal
  plus Coulomb friction against the sliding (on the cone's edge). The ridges move
  the tip along the normal only; their slopes do not turn the load (a real tip
  catches on steep ridges: stick-slip, left out).
- *Tip track* (:func:`tip_track`): a ridge pushes harder, so the whisker leans
  further and its tip lags the base more. Where the lag grows faster than the
  base travels, the quasi-static tip cannot follow and jumps ahead (a fold).
- *Ringing*: the plate's pose follows the quasi-static pose through the first
  bending mode (:func:`~camwhisker.sim.mechanics.mode.first_mode_hz`, damping
  ratio :data:`MODE_DAMPING`), so the release at the surface's end rings freely.
- *Camera*: the pose sampled at the frame rate, with the front end's noise
  (:data:`~camwhisker.sim.mechanics.experiment.FRONT_END_NOISE` by default).

A run: rest, the tip pressed onto the surface over a lead-in, the texture slid
over at the speed, the surface's end (the tip lets go), free ringing, rest.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

from camwhisker.sim.mechanics.experiment import (
    FRONT_END_NOISE,
    NoiseModel,
    StageProtocol,
    measure_signals,
    theta_deg_for,
)
from camwhisker.sim.mechanics.mode import first_mode_hz
from camwhisker.sim.mechanics.scenes import wrap_angle
from camwhisker.sim.mechanics.whisker import WhiskerMechanics, solve_elastica

__all__ = ["TextureSurface", "TextureProtocol", "TextureRun", "MODE_DAMPING", "FRAME_RATES",
           "contact_response", "tip_track", "simulate_texture"]

#: The camera rates the texture is filmed at.
FRAME_RATES = (30.0, 120.0, 240.0)
# A polymer whisker on polymer flexures rings for a few cycles: a few percent of critical.
MODE_DAMPING = 0.05
# Heights at which the contact is solved; the response is interpolated between them
# (it is smooth in h: 33 points over 0.5 mm agree with 65 to 1e-6 mm in dz).
_HEIGHT_STEPS = 33
# The simulated time step: at least this rate, a whole number of steps per frame.
_FINE_HZ = 2000.0
# Tip positions per gap on which the fold of the tip track is found.
_TIP_STEPS_PER_GAP = 256


@dataclass(frozen=True)
class TextureSurface:
    """Ridges of height ``amplitude_mm`` every ``gap_mm``; the tip pressed ``press_mm`` into
    the flat surface's plane (its rest reach l_w minus the plane's distance from the base)."""

    gap_mm: float
    amplitude_mm: float
    press_mm: float = 0.5
    mu: float = 0.4

    def __post_init__(self):
        for name in ("gap_mm", "press_mm"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        if not (self.amplitude_mm >= 0 and self.mu >= 0):
            raise ValueError("amplitude_mm and mu must be >= 0")

    def height_mm(self, x_mm):
        """Ridge height h(x) (mm toward the base); 0 before x = 0 (the flat lead-in)."""
        x = np.asarray(x_mm, float)
        h = 0.5 * self.amplitude_mm * (1.0 - np.cos(2.0 * np.pi * x / self.gap_mm))
        return np.where(x >= 0.0, h, 0.0)


@dataclass(frozen=True)
class TextureProtocol:
    """The run's timing: rest, lead-in, slide, free ringing (s); the camera's rate and noise."""

    speed_mm_s: float = 2.0
    fps: float = 120.0
    rest_s: float = 1.0
    lead_in_s: float = 1.0
    slide_s: float | None = None  # default: 12 gaps, at least 6 s
    ring_s: float = 3.0
    noise: NoiseModel = field(default_factory=lambda: FRONT_END_NOISE)

    def __post_init__(self):
        if not (self.speed_mm_s > 0 and self.fps > 0):
            raise ValueError(f"speed_mm_s and fps must be positive, got {self.speed_mm_s}, "
                             f"{self.fps}")

    def slide_for(self, surface: TextureSurface) -> float:
        if self.slide_s is not None:
            return self.slide_s
        return max(12.0 * surface.gap_mm / self.speed_mm_s, 6.0)


@dataclass
class TextureRun:
    """Signal table, stage log (stage clock) and truth (camera clock) of one run; arrays (N,)."""

    signals: dict
    stage: dict
    truth: dict
    info: dict


def _tip_constraint(mech: WhiskerMechanics, y_surface_mm: float, load_angle_rad: float):
    length = mech.length_mm

    def residuals(st, u):
        return ((st["yc"] - y_surface_mm) / length,  # the tip on the surface
                u[3] - 1.0,  # the contact at the tip
                wrap_angle(u[2] - load_angle_rad))  # sliding: the load on the friction cone's edge

    return residuals


@functools.lru_cache(maxsize=16)
def contact_response(mech: WhiskerMechanics, press_mm: float, mu: float, max_height_mm: float):
    """The sliding tip's equilibrium on a grid of heights 0..max_height_mm.

    Returns
    -------
    dict of ndarray, shape (H,)
        ``height_mm``, ``phi_rad``, ``dz_mm``, ``lag_mm`` (tip x minus base x).
    """
    heights = np.linspace(0.0, max(max_height_mm, 1e-3), _HEIGHT_STEPS)
    # The surface pushes the tip toward the base (-y); friction opposes its +x sliding.
    load = math.atan2(-1.0, -mu)
    guess = (0.005, 0.01, load, 1.0)
    out = {k: np.empty(heights.size) for k in ("phi_rad", "dz_mm", "lag_mm")}
    for i, h in enumerate(heights):
        y = mech.length_mm - press_mm - h
        sol = solve_elastica(mech, 0.0, _tip_constraint(mech, y, load), guess)
        guess = sol.unknowns
        out["phi_rad"][i], out["dz_mm"][i] = sol.phi_rad, sol.dz_mm
        out["lag_mm"][i] = sol.contact_xy_mm[0]
    out["height_mm"] = heights
    return out


def tip_track(surface: TextureSurface, response: dict, base_x_mm):
    """Tip position and height under it for base positions (increasing), folds jumped.

    The base position that holds the tip at x_t is x_t - lag(h(x_t)); where that
    falls as x_t grows, the tip jumps ahead to where it rises past its last maximum.
    """
    xb = np.asarray(base_x_mm, float)
    lag = response["lag_mm"]
    step = surface.gap_mm / _TIP_STEPS_PER_GAP
    x_tip = np.arange(xb.min() + lag.min() - 2 * surface.gap_mm,
                      xb.max() + lag.max() + 2 * surface.gap_mm, step)
    h = surface.height_mm(x_tip)
    held_by = x_tip - np.interp(h, response["height_mm"], lag)
    reach = np.maximum.accumulate(held_by)
    keep = np.r_[True, np.diff(reach) > 0]
    tip = np.interp(xb, reach[keep], x_tip[keep])
    return tip, surface.height_mm(tip)


def _mode_response(t_s, qs, natural_hz: float, damping: float):
    """The pose through the first mode: x'' + 2 zeta w x' + w^2 x = w^2 x_qs, at rest at t = 0."""
    from scipy.signal import lsim

    w = 2.0 * math.pi * natural_hz
    _, y, _ = lsim(([w * w], [1.0, 2.0 * damping * w, w * w]), qs, t_s)
    return np.asarray(y, float)


def _timeline(surface: TextureSurface, protocol: TextureProtocol):
    """Breakpoints (s) of the run: lead-in start, texture start, release, end."""
    t_lead = protocol.rest_s
    t_tex = t_lead + protocol.lead_in_s
    t_release = t_tex + protocol.slide_for(surface)
    return t_lead, t_tex, t_release, t_release + protocol.ring_s


def _quasi_static(surface, protocol, mech, t_s):
    """Base x, tip x, height under the tip, contact and the quasi-static phi, dz per time."""
    t_lead, t_tex, t_release, _ = _timeline(surface, protocol)
    v = protocol.speed_mm_s
    moving_t = np.clip(t_s, t_lead, t_release) - t_lead
    resp = contact_response(mech, surface.press_mm, surface.mu, surface.amplitude_mm)
    # Surface coordinates: the tip, lagging on flat ground, reaches the first ridge at t_tex.
    base_x = v * (moving_t - protocol.lead_in_s) - resp["lag_mm"][0]
    tip_x, h = tip_track(surface, resp, base_x)
    contact = (t_s >= t_lead) & (t_s < t_release)
    press = np.clip((t_s - t_lead) / protocol.lead_in_s, 0.0, 1.0)
    press = 0.5 * (1.0 - np.cos(np.pi * press))  # the lead-in's ramp, smooth at both ends
    phi = np.where(contact, press * np.interp(h, resp["height_mm"], resp["phi_rad"]), 0.0)
    dz = np.where(contact, press * np.interp(h, resp["height_mm"], resp["dz_mm"]), 0.0)
    return base_x, tip_x, np.where(contact, h, np.nan), contact, phi, dz


def simulate_texture(surface: TextureSurface, protocol: TextureProtocol, seed: int,
                     mech: WhiskerMechanics | None = None,
                     stage: StageProtocol | None = None) -> TextureRun:
    """One run (see the module docstring): signals with noise, stage log, truth, info."""
    mech = mech or WhiskerMechanics()
    stage = stage or StageProtocol()
    rng = np.random.default_rng(seed)
    natural_hz = first_mode_hz(mech)
    *_, t_end = _timeline(surface, protocol)
    per_frame = max(1, math.ceil(_FINE_HZ / protocol.fps))
    n_frames = int(math.floor(t_end * protocol.fps)) + 1
    t_fine = np.arange((n_frames - 1) * per_frame + 1) / (protocol.fps * per_frame)
    base_x, tip_x, h, contact, phi_qs, dz_qs = _quasi_static(surface, protocol, mech, t_fine)
    phi_rad = _mode_response(t_fine, phi_qs, natural_hz, MODE_DAMPING)[::per_frame]
    dz_mm = _mode_response(t_fine, dz_qs, natural_hz, MODE_DAMPING)[::per_frame]
    frames = slice(None, None, per_frame)
    t_cam = t_fine[frames]
    phi_deg = np.degrees(np.abs(phi_rad))
    theta = theta_deg_for(1.0)
    signals = {"frame": np.arange(n_frames), "t_s": t_cam,
               **measure_signals(phi_deg, dz_mm, theta, protocol.noise, rng)}
    magnitude = rng.uniform(*stage.offset_range_s)
    offset_s = float(magnitude if rng.random() < 0.5 else -magnitude)
    t_stage = np.arange(-1.0, t_end + 1.0, 1.0 / stage.stage_rate_hz)
    x_stage = np.interp(t_stage, t_fine, base_x)
    truth = {"t_s": t_cam, "x_mm": base_x[frames], "tip_x_mm": tip_x[frames],
             "height_mm": h[frames], "phi_deg": phi_deg, "dz_mm": dz_mm,
             "in_contact": contact[frames].astype(int)}
    t_lead, t_tex, t_release, _ = _timeline(surface, protocol)
    info = {"surface": vars(surface), "speed_mm_s": protocol.speed_mm_s, "fps": protocol.fps,
            "seed": int(seed), "natural_hz": natural_hz, "damping": MODE_DAMPING,
            "texture_frequency_hz": protocol.speed_mm_s / surface.gap_mm,
            "lead_in_s": [t_lead, t_tex], "slide_s": [t_tex, t_release],
            "ring_s": [t_release, t_end], "offset_s": offset_s,
            "noise": vars(protocol.noise), "mechanics": vars(mech)}
    return TextureRun(signals=signals, stage={"t_s": t_stage - offset_s, "x_mm": x_stage},
                      truth=truth, info=info)
