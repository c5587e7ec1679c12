"""Simulated linear-stage experiments with known truth.

One *run* is one scene swept by the stage: a rest, 1 mm steps with pauses of
jittered length (>= 1 s, like the paper), a rest. The run produces

- a stage log on the stage's own clock (``t_s, x_mm`` and, for calibration
  runs, ``r_mm``),
- a signal table on the camera's clock (docs/sensor.md section 6), whose clock is
  offset from the stage's by several seconds (``t_camera = t_stage + offset_s``),
- the truth per frame (contact point, r, slipping, ...).

Kinds (see :data:`KINDS`): ``rigid`` (pegs at the paper's radii), ``compliant``
(pegs on springs, the paper's pipe cleaner radii), ``slide-box`` (a tilted box:
stick at its corner, then Coulomb slip up its face), ``slide-circle`` (a water
bottle swept past on both sides, the stage travelling +x then -x: the whisker's
side slides down the bottle), ``eq8`` (phi generated from eq. (8) with
C = 132 instead of mechanics, so C recovery can be tested), and the paper's
accuracy tests of Sec. III-A on a rigid whisker (:mod:`camwhisker.sim.mechanics.rigid`):
``test1`` (stepped past a contact at a known r, phi 0-18 deg, the stage log
carries ``r_mm``) and ``test2`` (pushed along its axis in known dz steps of
0-1 mm, the stage log carries the applied ``dz_mm``), two trials each.

Every scene is solved with the stage travelling +x (:mod:`camwhisker.sim.mechanics.scenes`);
a run in -x solves the mirrored scene and maps x back, so its stage log, truth
and scene are in the lab frame and its whisker leans toward +x (theta 180 deg).

:func:`signal_arrays` gives the noise-free time series of a run at any frame
rate, for a video renderer.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field, fields, replace

import numpy as np

from camwhisker.contact.eq8 import eq8_phi_deg
from camwhisker.sim.mechanics.rigid import AxialPush, axial_push_sweep, rigid_peg_sweep
from camwhisker.sim.mechanics.scenes import BoxScene, CircleScene, PegScene, Sweep, sweep
from camwhisker.sim.mechanics.whisker import WhiskerMechanics, beam_dz_from_phi

__all__ = [
    "KINDS",
    "PAPER_RIGID_RADII_MM",
    "PAPER_COMPLIANT_RADII_MM",
    "peg_radii",
    "PAPER_C",
    "StageProtocol",
    "continuous_protocol",
    "NoiseModel",
    "measure_signals",
    "PAPER_NOISE",
    "FRONT_END_NOISE",
    "NOISE_LEVELS",
    "StageRun",
    "simulate_runs",
    "simulate_run",
    "signal_arrays",
]

PAPER_RIGID_RADII_MM = (22.5, 27.5, 33.5, 42.5, 50.0, 60.0, 72.5, 90.0)
PAPER_COMPLIANT_RADII_MM = (35.0, 55.0, 90.0)
PAPER_C = 132.0

# Lateral stiffness of the simulated pipe cleaner: with the default whisker it
# makes eq.-(8)-style GM overestimate r by ~15-35 mm, like Table III (-23.5 mm).
COMPLIANT_K_N_PER_MM = 6.0e-4

# Direction (deg, docs/sensor.md section 2) in which the magnifier tip moves when the
# whisker leans toward -x, with lab x along the image's u axis.
THETA_TRUE_DEG = 0.0

# theta is left empty below this phi: 4.5 sigma of the paper's phi noise.
THETA_MIN_PHI_DEG = 1.0

# Coulomb friction coefficient of the box (dry plastic on card, 0.3-0.5). Its
# face rises at 78 deg: with mu = 0.5 the whisker sticks at the corner up to
# phi ~ 14 deg, then slides up the face with phi steady while r grows from 41 to
# ~100 mm (Fig. 9's failure mode).
BOX_MU = 0.5
# The bottle: 90 mm across, its axis 55 mm from the base line.
BOTTLE = CircleScene(0.0, 55.0, 45.0)

# Per-frame noise levels of the simulated front end (docs/sensor.md section 6 signals).
# PAPER_NOISE: the paper's measured RMSE (Sec. III-A: phi 0.22 deg, dz 0.04 mm).
# FRONT_END_NOISE: what our vision front end is built to reach (its targets:
# phi RMSE <= 0.05 deg, dz RMSE <= 0.02 mm); every score is reported at both.
PAPER_NOISE_PHI_DEG, PAPER_NOISE_DZ_MM = 0.22, 0.04
FRONT_END_NOISE_PHI_DEG, FRONT_END_NOISE_DZ_MM = 0.05, 0.02

KINDS = ("rigid", "compliant", "slide-box", "slide-circle", "eq8", "test1", "test2")


@dataclass(frozen=True)
class StageProtocol:
    """How the stage moves and how both clocks sample the run."""

    step_mm: float = 1.0
    move_s: float = 0.25
    pause_s: tuple[float, float] = (1.2, 1.8)  # uniform jitter; >= 1 s as in the paper
    rest_s: float = 3.0
    approach_steps: int = 3
    max_travel_mm: float = 40.0
    phi_stop_deg: float = 30.0
    stage_rate_hz: float = 20.0
    fps: float = 30.0
    offset_range_s: tuple[float, float] = (3.0, 8.0)  # |offset|, sign drawn at random


def continuous_protocol(speed_mm_s: float, **kwargs) -> StageProtocol:
    """A stage that sweeps at a constant speed without pausing (a rest at each end only)."""
    if not speed_mm_s > 0:
        raise ValueError(f"speed_mm_s must be positive, got {speed_mm_s}")
    step = kwargs.pop("step_mm", StageProtocol.step_mm)
    return StageProtocol(step_mm=step, move_s=step / speed_mm_s, pause_s=(0.0, 0.0), **kwargs)


@dataclass(frozen=True)
class NoiseModel:
    """Per-frame measurement noise; defaults are the paper's RMSE (Sec. III-A)."""

    phi_deg: float = PAPER_NOISE_PHI_DEG
    dz_mm: float = PAPER_NOISE_DZ_MM
    dropout: float = 0.01  # fraction of frames with ok = 0 and empty cells


PAPER_NOISE = NoiseModel()
FRONT_END_NOISE = NoiseModel(phi_deg=FRONT_END_NOISE_PHI_DEG, dz_mm=FRONT_END_NOISE_DZ_MM)
NOISE_LEVELS = {"paper": PAPER_NOISE, "front-end": FRONT_END_NOISE}

# Test 1: two trials at known contact distances, 1 mm steps from one pause before
# touch until phi reaches 18 deg (the paper's range).
TEST1_RADII_MM = (30.0, 40.0)
TEST1_PROTOCOL = StageProtocol(approach_steps=1, phi_stop_deg=18.0)
# Test 2: two trials of 0.1 mm dz steps from touch to 1 mm (the paper's range; its
# manual stage is good to 0.05 mm); the stage reads TEST2_TOUCH_X_MM at touch.
TEST2_TRIALS = 2
TEST2_PROTOCOL = StageProtocol(step_mm=0.1, approach_steps=0, max_travel_mm=1.0)
TEST2_TOUCH_X_MM = 25.0
_PROTOCOLS = {"test1": TEST1_PROTOCOL, "test2": TEST2_PROTOCOL}


@dataclass
class StageRun:
    """One simulated run. Arrays are shape (N,) per table; see module docstring."""

    name: str
    kind: str
    scene: object
    offset_s: float
    travel_sign: float
    stage: dict
    signals: dict
    truth: dict
    steps: Sweep
    schedule_t_s: np.ndarray
    schedule_x_mm: np.ndarray
    info: dict = field(default_factory=dict)


def _scenes(kind: str, radii_mm=None):
    """The runs of an experiment kind: (name, scene in the lab frame, travel sign);
    ``radii_mm``: a rigid or eq8 kind's pegs (default: the paper's)."""
    if radii_mm is not None and kind not in ("rigid", "eq8"):
        raise ValueError(f"radii_mm applies to rigid and eq8 runs, not {kind!r}")
    if kind in ("rigid", "eq8"):
        radii = PAPER_RIGID_RADII_MM if radii_mm is None else radii_mm
        return [(f"r{r:g}", PegScene(float(r)), 1.0) for r in radii]
    if kind == "compliant":
        return [(f"c{r:g}", PegScene(r, k_obj_n_per_mm=COMPLIANT_K_N_PER_MM), 1.0)
                for r in PAPER_COMPLIANT_RADII_MM]
    if kind == "slide-box":
        return [("box", BoxScene(0.0, 40.0, face_angle_deg=78.0, mu=BOX_MU), 1.0)]
    if kind == "slide-circle":
        return [("left", BOTTLE, 1.0), ("right", BOTTLE, -1.0)]
    if kind == "test1":
        return [(f"r{r:g}", PegScene(r), 1.0) for r in TEST1_RADII_MM]
    if kind == "test2":
        return [(f"trial{i + 1}", AxialPush(TEST2_TOUCH_X_MM), 1.0) for i in range(TEST2_TRIALS)]
    raise ValueError(f"unknown experiment kind {kind!r} (known: {', '.join(KINDS)})")


@functools.lru_cache(maxsize=64)
def scene_by_name(kind: str, name: str):
    """The scene (lab frame) of run ``name`` of ``kind`` (as named by :func:`simulate_runs`)."""
    scenes = {run: scene for run, scene, _ in _scenes(kind)}
    if name not in scenes:
        raise ValueError(f"no run {name!r} in {kind!r} experiments (runs: {', '.join(scenes)})")
    return scenes[name]


def theta_deg_for(travel_sign: float) -> float:
    """The plate's tilt direction (deg) while the whisker lags a base travelling this way."""
    return THETA_TRUE_DEG if travel_sign > 0 else THETA_TRUE_DEG + 180.0


def _cached_sweep(scene, mech, positions, model):
    """:func:`sweep`, solved once per process for each scene, whisker and positions (runs
    repeat across noise levels, seeds and speeds); each caller gets its own arrays."""
    solved = _solved_sweep(scene, mech, positions, model)
    return replace(solved, **{f.name: np.copy(getattr(solved, f.name)) for f in fields(solved)})


@functools.lru_cache(maxsize=64)
def _solved_sweep(scene, mech, positions, model):
    return sweep(scene, mech, np.array(positions), model)


def _eq8_sweep(scene: PegScene, mech: WhiskerMechanics, positions, c: float) -> Sweep:
    xs = np.asarray(positions, float)
    dx = np.clip(xs - scene.x_mm, 0.0, None)
    phi = eq8_phi_deg(scene.r_mm, dx, c, mech.length_mm)
    dz = beam_dz_from_phi(mech, scene.r_mm, np.radians(phi))
    contact = dx > 0
    nan = np.where(contact, 0.0, np.nan)
    return Sweep(
        base_x_mm=xs, in_contact=contact, phi_deg=phi, dz_mm=dz,
        r_mm=scene.r_mm + nan, s_contact_mm=scene.r_mm + nan,
        contact_x_mm=scene.x_mm + nan, contact_y_mm=scene.r_mm + nan,
        force_n=np.full(xs.size, np.nan), slipping=np.zeros(xs.size, bool),
        elastica=np.zeros(xs.size, bool),
    )


def _steps(kind: str, scene, mech: WhiskerMechanics, positions, model: str, c: float) -> Sweep:
    """The equilibria of a run's stage positions, by the model its kind stands for."""
    if kind == "eq8":
        return _eq8_sweep(scene, mech, positions, c)
    if kind == "test1":
        return rigid_peg_sweep(scene, mech, positions)
    if kind == "test2":
        return axial_push_sweep(scene, mech, positions)
    return _cached_sweep(scene, mech, positions, model)


def _schedule(n_steps, x_start, protocol: StageProtocol, rng):
    """Breakpoints (t, x) of the piecewise-linear stage motion, true time from 0."""
    t, x = [0.0, protocol.rest_s], [x_start, x_start]
    for k in range(n_steps):
        t.append(t[-1] + protocol.move_s)
        x.append(x_start + (k + 1) * protocol.step_mm)
        if protocol.pause_s[1] > 0:  # a continuous protocol has no breakpoint to pause at
            t.append(t[-1] + rng.uniform(*protocol.pause_s))
            x.append(x[-1])
    t.append(t[-1] + protocol.rest_s)
    x.append(x[-1])
    return np.array(t), np.array(x)


def simulate_run(
    name: str,
    kind: str,
    scene,
    rng: np.random.Generator,
    mech: WhiskerMechanics | None = None,
    protocol: StageProtocol | None = None,
    noise: NoiseModel | None = None,
    model: str = "auto",
    c: float = PAPER_C,
    travel_sign: float = 1.0,
) -> StageRun:
    """Simulate one run of one scene (see module docstring).

    ``scene`` is in the lab frame; with ``travel_sign`` -1 the stage travels
    in -x. ``steps`` and the ``schedule_*`` arrays stay in the travel frame
    (x -> -x), where every scene is solved. Without a ``protocol``, test 1 and
    2 take their own (:data:`TEST1_PROTOCOL`, :data:`TEST2_PROTOCOL`), other
    kinds the default.
    """
    if travel_sign not in (1.0, -1.0):
        raise ValueError(f"travel_sign must be +1 or -1, got {travel_sign}")
    mech = mech or WhiskerMechanics()
    protocol = protocol or _PROTOCOLS.get(kind, StageProtocol())
    noise = noise or NoiseModel()
    lab_scene = scene
    if travel_sign < 0:
        scene = scene.mirrored()
    x_first = scene.first_contact_x(mech)
    x_start = x_first - protocol.approach_steps * protocol.step_mm
    n_max = protocol.approach_steps + int(round(protocol.max_travel_mm / protocol.step_mm))
    positions = tuple(float(v) for v in x_start + protocol.step_mm * np.arange(n_max + 1))
    steps = _steps(kind, scene, mech, positions, model, c)
    stop = np.flatnonzero(~(steps.phi_deg < protocol.phi_stop_deg))  # also stops at NaN
    n_steps = int(stop[0]) if stop.size else n_max
    sched_t, sched_x = _schedule(n_steps, x_start, protocol, rng)
    duration = sched_t[-1]

    # Clocks: camera time = true time; stage time = true time - offset.
    magnitude = rng.uniform(*protocol.offset_range_s)
    offset_s = float(magnitude if rng.random() < 0.5 else -magnitude)
    t_stage_true = np.arange(-1.0, duration + 1.0, 1.0 / protocol.stage_rate_hz)
    x_stage = np.interp(t_stage_true, sched_t, sched_x)
    stage = {"t_s": t_stage_true - offset_s, "x_mm": travel_sign * x_stage}
    used = slice(0, n_steps + 1)
    stage.update(_known_columns(kind, scene, steps, used, x_first, x_stage))

    n_frames = int(math.floor(duration * protocol.fps)) + 1
    t_cam = np.arange(n_frames) / protocol.fps
    x_cam = np.interp(t_cam, sched_t, sched_x)
    clean = signal_arrays_from(steps, used, x_cam)
    theta_deg = theta_deg_for(travel_sign)
    truth = _truth(steps, used, x_first, t_cam, x_cam, clean, travel_sign)
    signals = measure_signals(clean["phi_deg"], clean["dz_mm"], theta_deg, noise, rng)
    signals = {"frame": np.arange(n_frames), "t_s": t_cam, **signals}
    return StageRun(
        name=name, kind=kind, scene=lab_scene, offset_s=offset_s, travel_sign=travel_sign,
        stage=stage, signals=signals, truth=truth, steps=steps,
        schedule_t_s=sched_t, schedule_x_mm=sched_x,
        info={"n_steps": n_steps, "x_first_contact_mm": travel_sign * x_first,
              "theta_deg": theta_deg, "model": model,
              "noise": noise.__dict__, "protocol": protocol.__dict__, "mechanics": mech.__dict__},
    )


def _along_x(steps: Sweep, used, x_first: float, values, x):
    """A per-step quantity at base positions x, from the steps in contact (NaN before)."""
    v = np.asarray(values, float)[used]
    good = steps.in_contact[used] & np.isfinite(v)
    if not good.any():
        return np.full(np.shape(x), np.nan)
    out = np.interp(x, steps.base_x_mm[used][good], v[good])
    return np.where(x > x_first, out, np.nan)


def _known_columns(kind: str, scene, steps: Sweep, used, x_first: float, x_stage):
    """The stage log's known values: r_mm (rigid, eq8, test 1) or the applied dz_mm (test 2)."""
    if kind in ("rigid", "eq8"):
        r_mm = _along_x(steps, used, x_first, steps.r_mm, x_stage)
        return {"r_mm": np.where(np.isfinite(r_mm), r_mm, scene.r_mm)}
    if kind == "test1":  # the paper's r (along the rest axis) stays put for a rigid whisker
        return {"r_mm": np.full(x_stage.shape, scene.r_mm)}
    if kind == "test2":
        return {"dz_mm": signal_arrays_from(steps, used, x_stage)["dz_mm"]}
    return {}


def _truth(steps: Sweep, used, x_first: float, t_cam, x_cam, clean, travel_sign: float):
    """The camera-clock truth table of a run (lab frame)."""
    return {
        "t_s": t_cam,
        "x_mm": travel_sign * x_cam,
        "dx_mm": np.clip(x_cam - x_first, 0.0, None),
        "phi_deg": clean["phi_deg"],
        "dz_mm": clean["dz_mm"],
        "r_mm": _along_x(steps, used, x_first, steps.r_mm, x_cam),
        "contact_x_mm": travel_sign * _along_x(steps, used, x_first, steps.contact_x_mm, x_cam),
        "contact_y_mm": _along_x(steps, used, x_first, steps.contact_y_mm, x_cam),
        "in_contact": (x_cam > x_first).astype(int),
        "slipping": np.interp(x_cam, steps.base_x_mm[used], steps.slipping[used].astype(float))
        > 0.5,
    }


def signal_arrays_from(steps: Sweep, used, x_mm):
    """Noise-free phi and dz at base positions x (quasi-static: linear between solved steps)."""
    xs = steps.base_x_mm[used]
    phi = np.interp(x_mm, xs, np.nan_to_num(steps.phi_deg[used]))
    dz = np.interp(x_mm, xs, np.nan_to_num(steps.dz_mm[used]))
    return {"phi_deg": phi, "dz_mm": dz}


def signal_arrays(run: StageRun, fps: float):
    """Noise-free signals of a run on the camera clock at a chosen frame rate.

    For driving a video renderer: the plate pose per frame.

    Returns
    -------
    dict of ndarray, shape (N,)
        ``t_s``, ``phi_deg``, ``dz_mm``, ``theta_deg`` (NaN where phi = 0).
    """
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps}")
    t = np.arange(int(math.floor(run.schedule_t_s[-1] * fps)) + 1) / fps
    x = np.interp(t, run.schedule_t_s, run.schedule_x_mm)
    n = run.info["n_steps"] + 1
    out = signal_arrays_from(run.steps, slice(0, n), x)
    theta = np.where(out["phi_deg"] > 0.0, run.info["theta_deg"], np.nan)
    return {"t_s": t, "phi_deg": out["phi_deg"], "dz_mm": out["dz_mm"], "theta_deg": theta}


def measure_signals(phi_deg, dz_mm, theta_deg, noise: NoiseModel, rng):
    """Add the front end's noise: isotropic on the 2D tilt vector, Gaussian on dz."""
    n = phi_deg.size
    th = math.radians(theta_deg)
    tu = phi_deg * math.cos(th) + noise.phi_deg * rng.standard_normal(n)
    tv = phi_deg * math.sin(th) + noise.phi_deg * rng.standard_normal(n)
    phi_m = np.hypot(tu, tv)
    theta_m = np.where(phi_m >= THETA_MIN_PHI_DEG, np.degrees(np.arctan2(tv, tu)), np.nan)
    dz_m = dz_mm + noise.dz_mm * rng.standard_normal(n)
    ok = rng.random(n) >= noise.dropout
    ok[0] = True  # the rest reference frame
    bad = ~ok
    phi_m[bad] = dz_m[bad] = theta_m[bad] = np.nan
    return {"dz_mm": dz_m, "phi_deg": phi_m, "theta_deg": theta_m, "ok": ok.astype(int)}


def peg_radii(n: int = len(PAPER_RIGID_RADII_MM)) -> tuple[float, ...]:
    """Radii (mm) of ``n`` calibration pegs: the paper's eight, or ``n`` spaced evenly in
    log r over the same 22.5-90 mm (rounded to 0.1 mm)."""
    if n == len(PAPER_RIGID_RADII_MM):
        return PAPER_RIGID_RADII_MM
    if n < 2:
        raise ValueError(f"calibration needs two or more pegs, got {n}")
    lo, hi = PAPER_RIGID_RADII_MM[0], PAPER_RIGID_RADII_MM[-1]
    return tuple(float(r) for r in np.round(np.geomspace(lo, hi, n), 1))


def simulate_runs(kind: str, seed: int, radii_mm=None, **kwargs) -> list[StageRun]:
    """All runs of an experiment kind, each with its own clock offset and noise.

    ``radii_mm``: the pegs of a "rigid" or "eq8" experiment (default: the paper's).
    ``kwargs`` go to :func:`simulate_run` (mech, protocol, noise, model, c).
    """
    scenes = _scenes(kind, radii_mm)
    children = np.random.SeedSequence(seed).spawn(len(scenes))
    return [
        simulate_run(name, kind, scene, np.random.default_rng(child), travel_sign=sign, **kwargs)
        for (name, scene, sign), child in zip(scenes, children, strict=True)
    ]
