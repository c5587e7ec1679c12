"""A base that turns (a whisk): the whisker rotated about an axis through its base into a
wall's end or a cylinder, the contact stuck, as signals, a pose log and the true contact.

The planar frame is the stage simulator's (x the travel, y the shaft at rest, the base's
pivot at the origin). A whisk turns the base clockwise by w >= 0 (the shaft leans toward
+x, theta 0 as for a base travelling +x) about the pivot; the base itself sits ``pivot_mm``
along the shaft from it (0: the turn's axis goes through the base, as a whisking
actuator's; a robot's wrist lies behind the sensor, pivot_mm > 0, so the base also moves).

From first contact (the straight shaft's point at ``r0_mm`` touching the object at the
whisk angle ``w0_deg``) the contact sticks:

- a *wall*: its lower end, a corner the whisker pivots on and slides along (the planar
  simulator's stuck step, a rigid peg there); it holds while the load stays in the
  friction cone of the face (rising at ``face_deg`` from +x);
- a *cylinder*: as the stage simulator's bottle, the whisker stays tangent to it and the
  load is along its normal (no friction, so no cone to leave): the touching point moves
  over it as the whisker's slope turns, by the radius times that turn (a few mm); the
  shaft's point at r stays on it while the whisker slides along its own length.

Stuck only: the whisk ends at the last step whose load is in the cone (a slip is not
simulated), or where phi reaches :data:`PHI_STOP_DEG`. (A whisker rolling on the
cylinder without slipping along itself takes a friction load along its length that
moves dz, and MF, by tens of mm: not modelled here.) Each whisk angle's equilibrium is
solved in the base's frame with the object mapped into it; between steps phi and dz are
linear in the whisk angle (quasi-static). The 3-D lift is the space simulator's: the plane
is x-z of a frame turned and shifted into W (:data:`WORLD_TURN_DEG`); S has x_S along the
travel, z_S along the shaft, y_S across the plane (the turn's axis).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from camwhisker.files.tables import write_csv
from camwhisker.sim.mechanics.experiment import (
    FRONT_END_NOISE,
    THETA_TRUE_DEG,
    NoiseModel,
    measure_signals,
)
from camwhisker.sim.mechanics.scenes import BoxScene, CircleScene, PegScene, _solve, _stuck
from camwhisker.sim.mechanics.whisker import ElasticaError, WhiskerMechanics

__all__ = ["WHISK_KINDS", "PHI_STOP_DEG", "WORLD_TURN_DEG", "WORLD_SHIFT_MM", "WhiskProtocol",
           "WhiskObject", "WhiskRun", "draw_whisk_object", "simulate_whisk",
           "write_whisk"]  # fmt: skip

WHISK_KINDS = ("wall", "cylinder")
#: The whisk ends where phi reaches this (deg): inside the calibration's range.
PHI_STOP_DEG = 20.0
#: W: the simulator's 3-D frame turned by these Euler angles (zyx, deg) and shifted (mm).
WORLD_TURN_DEG = (35.0, -20.0, 50.0)
WORLD_SHIFT_MM = (120.0, -40.0, 300.0)
#: Whisk steps before the touch.
APPROACH_STEPS = 3
_WORLD = Rotation.from_euler("zyx", WORLD_TURN_DEG, degrees=True)


@dataclass(frozen=True)
class WhiskProtocol:
    """How the base moves: optional steps along the shaft, then the whisk in steps with
    pauses (jittered, >= 1 s as the stage protocol's), rests before and after."""

    step_deg: float = 0.5
    move_s: float = 0.25
    pause_s: tuple[float, float] = (1.2, 1.8)
    rest_s: float = 3.0
    max_whisk_deg: float = 20.0
    # Steps along the shaft (mm each, toward the tip) before the whisk, out of contact.
    shaft_steps: int = 0
    shaft_step_mm: float = 2.0
    pose_rate_hz: float = 20.0
    fps: float = 30.0
    offset_range_s: tuple[float, float] = (3.0, 8.0)


@dataclass(frozen=True)
class WhiskObject:
    """The object in the plane: ``kind`` wall (a face from its lower end at ``point``,
    rising at ``face_deg``) or cylinder (centre ``point``, ``radius_mm``); the shaft's
    point at ``r0_mm`` meets it at whisk angle ``w0_deg``; friction ``mu``."""

    kind: str
    point: tuple[float, float]
    r0_mm: float
    w0_deg: float
    mu: float
    pivot_mm: float = 0.0
    face_deg: float = math.nan
    radius_mm: float = math.nan


def _rot(angle_rad: float) -> np.ndarray:
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[c, -s], [s, c]])


def _base(w_rad: float, pivot_mm: float) -> np.ndarray:
    """The base (S's origin) in the plane at whisk angle w: on the turned shaft's line."""
    return pivot_mm * np.array([math.sin(w_rad), math.cos(w_rad)])


def draw_whisk_object(kind: str, rng, pivot_mm: float | None = None) -> WhiskObject:
    """An object of ``kind`` (:data:`WHISK_KINDS`) drawn from ``rng``: first contact at r0
    35-80 mm (in the calibration's 22.5-90 mm) after a whisk of 1-2 deg."""
    if kind not in WHISK_KINDS:
        raise ValueError(f"unknown whisk object {kind!r} (known: {', '.join(WHISK_KINDS)})")
    r0 = rng.uniform(35.0, 80.0)
    w0 = rng.uniform(1.0, 2.0)
    mu = rng.uniform(0.6, 0.9)
    pivot = rng.uniform(0.0, 30.0) if pivot_mm is None else pivot_mm
    w = math.radians(w0)
    touch = _base(w, pivot) + r0 * np.array([math.sin(w), math.cos(w)])
    if kind == "wall":
        # Under the shaft's least rise (90 - 20 deg): the whisker past the end clears the face.
        face = rng.uniform(60.0, 70.0)
        return WhiskObject("wall", tuple(touch), r0, w0, mu, pivot, face_deg=face)
    radius = rng.uniform(15.0, 60.0)
    centre = touch + radius * np.array([math.cos(w), -math.sin(w)])  # across the shaft, +x
    return WhiskObject("cylinder", tuple(centre), r0, w0, mu, pivot, radius_mm=radius)


def _touch(obj: WhiskObject) -> np.ndarray:
    """Where the straight shaft first touches the object (the plane, mm)."""
    w = math.radians(obj.w0_deg)
    return _base(w, obj.pivot_mm) + obj.r0_mm * np.array([math.sin(w), math.cos(w)])


def _cylinder_step(obj: WhiskObject, mech, w_rad, prev):
    """The whisker on the cylinder at whisk angle w, in the base's frame: tangent to it,
    the load along its normal (the stage simulator's bottle); (solution, 0: no tangential
    load to leave the cone), or (None, inf) where it does not converge."""
    centre = _rot(w_rad) @ (np.asarray(obj.point) - _base(w_rad, obj.pivot_mm))
    scene = CircleScene(float(centre[0]), float(centre[1]), obj.radius_mm)
    guesses = (prev, PegScene(obj.r0_mm, centre[0] - obj.radius_mm).guess(mech, 0.0))
    try:
        return _solve(mech, 0.0, scene.constraint(mech), guesses), 0.0
    except ElasticaError:
        return None, math.inf


def _wall_step(obj: WhiskObject, mech, w_rad, prev):
    """The whisker held at the wall's end at whisk angle w: (solution, -T / N)."""
    rot = _rot(w_rad)
    corner = rot @ (np.asarray(obj.point) - _base(w_rad, obj.pivot_mm))
    scene = BoxScene(corner[0], corner[1], obj.face_deg + math.degrees(w_rad), obj.mu)
    return _stuck(scene, mech, 0.0, tuple(corner), (prev,))


def _whisk_steps(obj: WhiskObject, mech, angles_deg):
    """phi, dz and the contact (in the plane) at each whisk angle; the stuck steps end at
    the first whose load leaves the cone, phi reaches PHI_STOP_DEG, or the solve fails."""
    n = len(angles_deg)
    phi, dz = np.zeros(n), np.zeros(n)
    contact = np.full((n, 2), np.nan)
    step = _wall_step if obj.kind == "wall" else _cylinder_step
    prev, last = None, n
    for i, a in enumerate(angles_deg):
        if a <= obj.w0_deg + 1e-9:
            if a >= obj.w0_deg - 1e-9:  # the touch, on the grid: the straight shaft there
                contact[i] = _touch(obj)
            continue
        w = math.radians(a)
        sol, ratio = step(obj, mech, w, prev)
        if (sol is None or ratio > obj.mu or sol.force_n <= 0.0
                or sol.s_contact_mm > mech.length_mm or sol.phi_deg > PHI_STOP_DEG):
            last = i
            break
        prev = sol.unknowns
        phi[i], dz[i] = sol.phi_deg, sol.dz_mm
        contact[i] = _base(w, obj.pivot_mm) + _rot(-w) @ np.asarray(sol.contact_xy_mm)
    return phi[:last], dz[:last], contact[:last]


@dataclass
class WhiskRun:
    """One whisk: ``signals`` (camera clock), ``poses`` (t_s, p_mm, quat on the pose
    clock, t_camera = t_pose + ``offset_s``) and ``truth`` per frame (``contact_w``, (N, 3)
    in W, NaN out of contact; whisk_deg, phi_deg, dz_mm)."""

    name: str
    obj: WhiskObject
    offset_s: float
    signals: dict
    poses: tuple
    truth: dict
    info: dict = field(default_factory=dict)


def _schedule(protocol: WhiskProtocol, angles_deg, n_whisk: int, rng):
    """Breakpoints (t, shaft advance mm, whisk deg) of the motion, true time from 0."""
    w_start = float(angles_deg[0])
    t, s, w = [0.0, protocol.rest_s], [0.0, 0.0], [w_start, w_start]
    moves = [(protocol.shaft_step_mm, 0.0)] * protocol.shaft_steps
    moves += [(0.0, protocol.step_deg)] * n_whisk
    for ds, dw in moves:
        t.append(t[-1] + protocol.move_s)
        s.append(s[-1] + ds)
        w.append(w[-1] + dw)
        t.append(t[-1] + rng.uniform(*protocol.pause_s))
        s.append(s[-1])
        w.append(w[-1])
    t[-1] += protocol.rest_s - protocol.pause_s[0]  # the last pause is the closing rest
    return np.array(t), np.array(s) - s[-1], np.array(w)


def _lift(base_xy, w_rad, shaft_mm):
    """Poses in W: position (N, 3), quaternion (N, 4); the shaft advance moves the base
    along the (turned) shaft, behind its final place while it is negative."""
    p = np.column_stack([base_xy[:, 0] + shaft_mm * np.sin(w_rad), np.zeros(w_rad.size),
                         base_xy[:, 1] + shaft_mm * np.cos(w_rad)])  # fmt: skip
    # S in the simulator's 3-D frame: x_S, z_S turned clockwise by w in the x-z plane.
    frames = Rotation.from_euler("y", np.asarray(w_rad)[:, None])
    q = (_WORLD * frames).as_quat(scalar_first=True)
    return _WORLD.apply(p) + np.asarray(WORLD_SHIFT_MM), q


def _to_world_xy(xy):
    xy = np.atleast_2d(xy)
    p = np.column_stack([xy[:, 0], np.zeros(len(xy)), xy[:, 1]])
    return _WORLD.apply(p) + np.asarray(WORLD_SHIFT_MM)


def simulate_whisk(name: str, obj: WhiskObject, rng, mech: WhiskerMechanics | None = None,
                   protocol: WhiskProtocol | None = None,
                   noise: NoiseModel = FRONT_END_NOISE) -> WhiskRun:  # fmt: skip
    """Simulate one whisk of ``obj`` (see the module docstring)."""
    mech = mech or WhiskerMechanics()
    protocol = protocol or WhiskProtocol()
    n_max = int(round(protocol.max_whisk_deg / protocol.step_deg))
    # The touch on the grid, APPROACH_STEPS before it: phi is linear between steps.
    angles = obj.w0_deg + protocol.step_deg * (np.arange(n_max + 1) - APPROACH_STEPS)
    phi, dz, contact = _whisk_steps(obj, mech, angles)
    n_whisk = phi.size - 1
    sched_t, sched_s, sched_w = _schedule(protocol, angles, n_whisk, rng)
    magnitude = rng.uniform(*protocol.offset_range_s)
    offset_s = float(magnitude if rng.random() < 0.5 else -magnitude)
    t_true = np.arange(-1.0, sched_t[-1] + 1.0, 1.0 / protocol.pose_rate_hz)
    w_pose = np.radians(np.interp(t_true, sched_t, sched_w))
    base = np.array([_base(w, obj.pivot_mm) for w in w_pose])
    p, q = _lift(base, w_pose, np.interp(t_true, sched_t, sched_s))
    t_cam = np.arange(int(math.floor(sched_t[-1] * protocol.fps)) + 1) / protocol.fps
    w_cam = np.interp(t_cam, sched_t, sched_w)
    grid = angles[:phi.size]
    clean_phi, clean_dz = np.interp(w_cam, grid, phi), np.interp(w_cam, grid, dz)
    touching = (w_cam > obj.w0_deg) & (w_cam <= grid[-1])
    cx = np.where(touching, np.interp(w_cam, grid, np.nan_to_num(contact[:, 0])), np.nan)
    cy = np.where(touching, np.interp(w_cam, grid, np.nan_to_num(contact[:, 1])), np.nan)
    signals = measure_signals(clean_phi, clean_dz, THETA_TRUE_DEG, noise, rng)
    signals = {"frame": np.arange(t_cam.size), "t_s": t_cam, **signals}
    truth = {"t_s": t_cam, "whisk_deg": w_cam, "phi_deg": clean_phi, "dz_mm": clean_dz,
             "contact_w": np.where(touching[:, None], _to_world_xy(np.column_stack([cx, cy])),
                                   np.nan)}  # fmt: skip
    info = {"whisk_deg": float(grid[-1]), "steps": int(n_whisk), "kind": obj.kind}
    return WhiskRun(name, obj, offset_s, signals, (t_true - offset_s, p, q), truth, info)


def write_whisk(dest, kind: str, seed: int, protocol: WhiskProtocol | None = None) -> WhiskRun:
    """Simulate a whisk of a ``kind`` object drawn from ``seed`` and write NAME.signals.csv,
    NAME.pose.csv (pose clock) and NAME.truth.csv (the true contact in W, camera clock),
    NAME = f"{kind}{seed}", into the folder ``dest``; the true offset is in the run."""
    from pathlib import Path

    out = Path(dest)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    run = simulate_whisk(f"{kind}{seed}", draw_whisk_object(kind, rng), rng, protocol=protocol)
    t, p, q = run.poses
    sig = {k: run.signals[k] for k in ("frame", "t_s", "dz_mm", "phi_deg", "theta_deg", "ok")}
    write_csv(out / f"{run.name}.signals.csv", sig, digits=8)
    write_csv(out / f"{run.name}.pose.csv", {"t_s": t, "x_mm": p[:, 0], "y_mm": p[:, 1],
                                             "z_mm": p[:, 2], "qw": q[:, 0], "qx": q[:, 1],
                                             "qy": q[:, 2], "qz": q[:, 3]}, digits=9)
    c = run.truth["contact_w"]
    write_csv(out / f"{run.name}.truth.csv", {"t_s": run.truth["t_s"], "cx_mm": c[:, 0],
                                              "cy_mm": c[:, 1], "cz_mm": c[:, 2]}, digits=9)
    return run
