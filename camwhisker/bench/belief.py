"""Contact belief (eq. 1) on rendered video through the front end: onset error and false contacts.

The target: on simulated runs the onset is found within 2
frames of the true one, and 10 minutes of no-contact video (18,000 frames at
30 frames/s, nominal noise) give no false contact. Both use the front end's real
noise: frames rendered with the nominal webcam's artefacts, JPEG-compressed as
MJPG (quality 88), tracked by :func:`camwhisker.vision.stream.stream` as batch does
(rest segment held and re-measured), then :func:`~camwhisker.contact.belief.find_onsets`
with eta from the stream's own rest frames.

- Onsets: the mechanics' stage runs (:func:`~camwhisker.sim.mechanics.simulate_runs`,
  rigid and compliant pegs at 30 frames/s, the base at two speeds: :data:`PROTOCOLS`).
  Each run is rendered as 1 s at rest (the reference), then the frames around its
  true onset (the first frame whose base is past first contact); the pose before
  contact is the rest pose. The same runs' signal tables as the simulator writes them
  (Gaussian noise, no video) over 5 seeds, at the paper's noise, the front end's
  target and the rendered front end's own rest noise, give more runs.
- False contacts: the rest pose for N frames, rendered frame by frame (one geometry,
  the artefacts drawn anew per frame: noise, flicker, the colour cast's 20 s drift),
  streamed without holding them in memory.

``camwhisker dev belief-bench [--frames N --seed S]``
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Iterator

import numpy as np

from camwhisker.contact.belief import eta_from_rest, find_onsets
from camwhisker.sensor.file import Sensor
from camwhisker.sim.mechanics import (
    NOISE_LEVELS,
    NoiseModel,
    StageProtocol,
    signal_arrays,
    simulate_runs,
)
from camwhisker.sim.render.artefacts import apply_artefacts, illumination_field, jpeg_roundtrip
from camwhisker.sim.render.render import SceneRenderer
from camwhisker.sim.render.scenarios import NOMINAL_ARTEFACTS, PoseTrack
from camwhisker.vision.stream import Frame, stream

__all__ = ["FPS", "REST_S", "WINDOW_FRAMES", "PROTOCOLS", "render_poses", "belief_of_track",
           "onset_errors", "signal_onset_errors", "false_contacts", "main"]  # fmt: skip

FPS = 30.0
#: Rest before the onset window: the stream's rest reference averages up to 1 s.
REST_S = 1.0
#: Frames rendered on each side of a true onset: the detection lands a few frames after.
WINDOW_FRAMES = 20
#: Base speeds (1 mm steps): the simulator's stage (4 mm/s), and 10x slower, where the
#: deflection per frame is as small as eta and the onset must be refined back.
PROTOCOLS = {"4 mm/s": StageProtocol(), "0.4 mm/s": StageProtocol(move_s=2.5)}
#: Frames tracked per progress line of the false-contact run (one minute of video).
REPORT_EVERY = 1800


def render_poses(track: PoseTrack, seed: int) -> Iterator[np.ndarray]:
    """Frames of a pose track as the nominal webcam delivers them (MJPG), one at a time;
    the rest pose's geometry is drawn once (it is the same every frame)."""
    sensor, art = Sensor(), NOMINAL_ARTEFACTS
    renderer = SceneRenderer(sensor)
    light = illumination_field(renderer.shape, art)
    rng = np.random.default_rng(seed)
    rest = None
    for i in range(len(track)):
        at_rest = track.phi_deg[i] == 0 and track.dz_mm[i] == 0
        if at_rest and rest is None:
            rest = renderer.geometry(track.pose(i))
        scene = rest if at_rest else renderer.geometry(track.pose(i))
        frame = apply_artefacts(scene, float(track.t_s[i]), art, rng, light)
        yield jpeg_roundtrip(frame, art.jpeg_quality)


def belief_of_track(track: PoseTrack, seed: int):
    """Track a rendered pose track; returns (phi per frame, NaN where untrusted; rest rows)."""
    frames = (Frame(i, float(t), img) for i, (t, img) in
              enumerate(zip(track.t_s, render_poses(track, seed), strict=True)))  # fmt: skip
    log: list = []
    phi = np.array(
        [r.phi_deg if r.ok else np.nan for _, r in stream(frames, Sensor(), rest_log=log)]
    )
    return phi, np.arange(log[0].frames_used)


def _onset_track(run) -> tuple[PoseTrack, int]:
    """1 s at rest, then the frames around the run's true onset; and that onset's index."""
    sig = signal_arrays(run, FPS)
    x = np.interp(sig["t_s"], run.schedule_t_s, run.schedule_x_mm)
    first = np.flatnonzero(x > run.travel_sign * run.info["x_first_contact_mm"])[0]
    window = np.arange(max(first - WINDOW_FRAMES, 0), first + WINDOW_FRAMES)
    n_rest = int(REST_S * FPS)
    t = np.r_[np.arange(n_rest) / FPS, sig["t_s"][window] + REST_S]
    phi = np.r_[np.zeros(n_rest), sig["phi_deg"][window]]
    dz = np.r_[np.zeros(n_rest), sig["dz_mm"][window]]
    theta = np.nan_to_num(np.r_[np.zeros(n_rest), sig["theta_deg"][window]])
    zeros = np.zeros_like(t)
    return PoseTrack(t, dz, phi, theta, zeros, zeros.copy()), n_rest + (first - window[0])


def onset_errors(
    seed: int = 0, protocol: StageProtocol | None = None, kinds=("rigid", "compliant")
) -> list[dict]:
    """Per run: true onset, refined onset and detection frame (window indices), eta."""
    out = []
    for k, kind in enumerate(kinds):
        for j, run in enumerate(simulate_runs(kind, seed, protocol=protocol)):
            track, true = _onset_track(run)
            phi, rest = belief_of_track(track, seed * 1000 + 100 * k + j)
            eta = eta_from_rest(phi[rest])
            _, _, onsets = find_onsets(phi, eta)
            found = onsets[0] if onsets else None
            out.append({"run": f"{kind}:{run.name}", "true": int(true), "eta_deg": eta,
                        "rest_ms_deg2": float(np.nanmean(phi[rest] ** 2)),
                        "phi_per_frame_deg": float(np.diff(track.phi_deg[true:true + 3]).mean()),
                        "onset": found.frame if found else None,
                        "detected": found.detected_frame if found else None,
                        "onsets": len(onsets)})  # fmt: skip
    return out


def signal_onset_errors(
    seeds, protocol: StageProtocol, noise: NoiseModel, kinds=("rigid", "compliant")
) -> np.ndarray:
    """Onset error (frames) per run on the simulator's own signal tables (no video: its
    Gaussian noise), eta from the first 1 s at rest."""
    errs = []
    for seed in seeds:
        for kind in kinds:
            for run in simulate_runs(kind, seed, protocol=protocol, noise=noise):
                phi = np.where(run.signals["ok"] == 1, run.signals["phi_deg"], np.nan)
                true = int(np.flatnonzero(run.truth["in_contact"])[0])
                _, _, onsets = find_onsets(phi, eta_from_rest(phi[: int(REST_S * FPS)]))
                errs.append(onsets[0].frame - true if onsets else np.nan)
    return np.array(errs, float)


def false_contacts(frames: int, seed: int = 0) -> dict:
    """The rest pose for ``frames`` frames through the front end: onsets found (all false),
    frames flagged in contact, and the largest phi against the contact level 2 eta."""
    zeros = np.zeros(frames)
    track = PoseTrack(np.arange(frames) / FPS, zeros, zeros, zeros, zeros, zeros)
    start = time.perf_counter()
    frames_iter = (Frame(i, float(t), img) for i, (t, img) in
                   enumerate(zip(track.t_s, render_poses(track, seed), strict=True)))  # fmt: skip
    log: list = []
    phi = np.full(frames, np.nan)
    eta = None
    for frame, r in stream(frames_iter, Sensor(), rest_log=log):
        phi[frame.index] = r.phi_deg if r.ok else np.nan
        if eta is None and log and frame.index + 1 == log[0].frames_used:
            eta = eta_from_rest(phi[: log[0].frames_used])
        if (frame.index + 1) % REPORT_EVERY == 0 and eta is not None:
            seen = phi[: frame.index + 1]
            print(f"  {frame.index + 1} frames ({time.perf_counter() - start:.0f} s): "
                  f"{len(find_onsets(seen, eta)[2])} false onset(s), max phi "
                  f"{np.nanmax(seen):.4f} deg, 2 eta {2 * eta:.4f} deg", flush=True)  # fmt: skip
    _, flag, onsets = find_onsets(phi, eta)
    return {"frames": frames, "wall_s": time.perf_counter() - start, "eta_deg": eta,
            "false_onsets": len(onsets), "frames_in_contact": int(flag.sum()),
            "untrusted": int(np.isnan(phi).sum()),
            "phi_q50_q99_max_deg": [float(v) for v in np.nanquantile(phi, [0.5, 0.99, 1.0])],
            "max_over_2eta": float(np.nanmax(phi) / (2 * eta))}  # fmt: skip


def _print_onsets(speed: str, protocol: StageProtocol, seed: int) -> list[dict]:
    start = time.perf_counter()
    rows = onset_errors(seed, protocol)
    print(f"onsets on {len(rows)} rendered runs, base at {speed} (seed {seed}), "
          f"{time.perf_counter() - start:.0f} s:")  # fmt: skip
    print("run | eta deg | phi/frame deg | onset error (frames) | detection delay | onsets")
    for r in rows:
        err = None if r["onset"] is None else r["onset"] - r["true"]
        delay = None if r["detected"] is None else r["detected"] - r["true"]
        print(f"{r['run']} | {r['eta_deg']:.4f} | {r['phi_per_frame_deg']:.4f} | {err} | "
              f"{delay} | {r['onsets']}")  # fmt: skip
    errs = [abs(r["onset"] - r["true"]) for r in rows if r["onset"] is not None]
    print(f"max |onset error| {max(errs) if errs else None} frames, "
          f"{sum(e <= 2 for e in errs)}/{len(rows)} within 2 frames", flush=True)  # fmt: skip
    return rows


def _fmt(v) -> str:
    if isinstance(v, list):
        return "[" + ", ".join(_fmt(x) for x in v) + "]"
    return f"{v:.4g}" if isinstance(v, float) else str(v)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="camwhisker dev belief-bench", description=__doc__)
    p.add_argument(
        "--frames",
        type=int,
        default=18000,
        help="no-contact frames (default 18000: 10 min at 30 frames/s)",
    )
    p.add_argument("--seed", type=int, default=0, help="mechanics and render seed")
    p.add_argument("--skip-onsets", action="store_true", help="only the no-contact run")
    args = p.parse_args(argv)
    if not args.skip_onsets:
        rows = [r for speed, protocol in PROTOCOLS.items()
                for r in _print_onsets(speed, protocol, args.seed)]  # fmt: skip
        # The rendered front end's own noise per tilt component (|d| is Rayleigh at rest).
        sigma = math.sqrt(np.mean([r["rest_ms_deg2"] for r in rows]) / 2)
        levels = {**NOISE_LEVELS, f"rendered ({sigma:.4f} deg)": NoiseModel(phi_deg=sigma)}
        seeds = range(args.seed, args.seed + 5)
        print(f"onsets on the simulator's signal tables (seeds {seeds.start}-{seeds.stop - 1}):")
        for speed, protocol in PROTOCOLS.items():
            for level, noise in levels.items():
                e = signal_onset_errors(seeds, protocol, noise)
                print(f"  base {speed}, {level} phi noise: {e.size} runs, "
                      f"{np.mean(np.abs(e) <= 2):.0%} within 2 frames, error "
                      f"{np.nanmin(e):+.0f} to {np.nanmax(e):+.0f} frames", flush=True)  # fmt: skip
    if args.frames < 1:
        return 0
    print(f"no-contact video, {args.frames} frames (seed {args.seed}):", flush=True)
    fc = false_contacts(args.frames, args.seed)
    print(", ".join(f"{k} {_fmt(v)}" for k, v in fc.items()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
