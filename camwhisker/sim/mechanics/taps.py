"""Taps in 3-D on spheres, planes and cylinders: planar stage runs placed exactly in space.

A tap: the base approaches an object across its shaft, presses in 1 mm steps with pauses
(>= 1 s, as the contact side's clock alignment wants) until phi reaches
:data:`PHI_STOP_DEG` or the travel :data:`MAX_PRESS_MM`, and rests there; it is one stage
run of the planar simulator (:func:`camwhisker.sim.mechanics.experiment.simulate_run`)
whose plane is put in a world frame W.

Why this is exact in 3-D: the base moves in the plane spanned by the shaft (z_S) and the
object's normal n at the first contact point, and the whisker, loaded in that plane, bends
in it. The object's section by that plane is then all the whisker can meet:

- a *sphere*: the plane holds the centre (n is a radius), so the section is a great
  circle: a :class:`~camwhisker.sim.mechanics.scenes.CircleScene` of the sphere's radius;
  the shaft is tangent to the sphere at the first contact, the whisker's side touches it
  there and the point of tangency slides toward the base as the whisker bends
  (frictionless, the planar circle's contact);
- a *cylinder* whose axis is perpendicular to that plane: its section is a circle of its
  radius (the same scene); only taps with the shaft across the axis are made;
- a *plane*: its section is a line. A whisker's side meets a line only at an end of it,
  so the plane is a plate, and a tap meets its rim where the rim runs straight across the
  tap's plane (a polygonal plate, an edge per tap): a
  :class:`~camwhisker.sim.mechanics.scenes.BoxScene` face, stuck at the rim (Coulomb
  friction) then slipping onto the face, as the walls of
  :mod:`camwhisker.sim.mechanics.objects`. Its face rises at :data:`FACE_DEG` from the
  travel (the shaft at 4-20 deg to the plane, leaning away from it); steeper or shallower
  taps are refused, as the walls there.

Left out: a section not through a sphere's centre (or a cylinder cut obliquely) pushes the
whisker out of its plane, where the planar simulator does not hold; tip contacts (a whisker
pointed at a surface) put the contact at the tip, beyond the calibrated 22.5-90 mm; and
the withdrawal, which with friction is not the press run backward (the log ends with a
rest at the deepest press).

Frames: a tap's S has z_S along the shaft and its axes as the sensor's mount puts them; the
base presses along d, across the shaft, which is the direction theta_tap in S (docs/sensor.md
section 9), so the signals' theta is the simulator's (0 for its +x) plus theta_tap. The
pose log gives S in W (R(q) p_S + t, q scalar first) on the stage's clock.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from camwhisker import __version__
from camwhisker.files.atomic import atomic_write_text
from camwhisker.files.jsonfile import dumps
from camwhisker.files.tables import write_csv
from camwhisker.io.poses import Mount
from camwhisker.io.rig import RigSensor
from camwhisker.sim.mechanics.experiment import (
    FRONT_END_NOISE,
    NoiseModel,
    StageProtocol,
    StageRun,
    simulate_run,
)
from camwhisker.sim.mechanics.scenes import BoxScene, CircleScene, sweep
from camwhisker.sim.mechanics.whisker import ElasticaError, WhiskerMechanics

__all__ = ["OBJECTS", "FACE_DEG", "MU", "TOP_MM", "PHI_STOP_DEG", "MAX_PRESS_MM",
           "MIN_DEPTH_MM", "press_travel_mm", "TAP_PROTOCOL", "Sphere", "Plane", "Cylinder",
           "Tap", "TapError", "TapRun",
           "tap_on", "simulate_tap", "object_record", "write_taps", "PAPER_SPHERE_RADII_MM",
           "STIMULI", "LOCATIONS_MM", "RIG", "Trial", "protocol_trial",
           "simulate_trial", "object_taps", "write_object_taps"]  # fmt: skip

OBJECTS = ("sphere", "plane", "cylinder")
#: A plate's face rises this steeply from the travel (the objects' walls: shallower or more
#: slippery faces snap off at first touch without a stick-slip trace).
FACE_DEG = (70.0, 86.0)
#: Coulomb friction of the plate (dry plastic on card).
MU = (0.4, 0.6)
#: A plate's face ends this far along the shaft from the base, within the calibrated radii.
TOP_MM = 90.0
#: The press stops at this phi (deg) or after this travel past first contact (mm).
PHI_STOP_DEG = 15.0
MAX_PRESS_MM = 20.0
#: ... or where the contact comes this close to the base (mm), near the calibration's
#: shortest radius (22.5 mm).
MIN_DEPTH_MM = 25.0
#: 1 mm steps with pauses, three of them before touch, as the stage runs.
TAP_PROTOCOL = StageProtocol(max_travel_mm=MAX_PRESS_MM, phi_stop_deg=PHI_STOP_DEG)


class TapError(ValueError):
    """A tap this simulator cannot make exactly (the message says why)."""


def _unit(v) -> np.ndarray:
    v = np.asarray(v, float)
    n = float(np.linalg.norm(v))
    if not n > 1e-9:
        raise TapError("a direction of zero length")
    return v / n


def _across(v, a) -> np.ndarray:
    """The unit part of v across the unit vector a."""
    v = np.asarray(v, float)
    return _unit(v - (v @ a) * a)


@dataclass(frozen=True)
class Sphere:
    """A sphere in W (mm)."""

    center: tuple
    radius_mm: float
    kind: str = "sphere"

    def params(self) -> dict:
        c = self.center
        return {"center_x_mm": c[0], "center_y_mm": c[1], "center_z_mm": c[2],
                "radius_mm": self.radius_mm}  # fmt: skip

    def first_contact(self, shaft, toward):
        """The first contact point and its outward normal for a shaft (unit, W) whose tap
        meets the sphere on the side that faces ``toward`` (a point of W)."""
        c = np.asarray(self.center, float)
        n = _across(np.asarray(toward, float) - c, shaft)
        return c + self.radius_mm * n, n


@dataclass(frozen=True)
class Cylinder:
    """A cylinder in W: a point of its axis, the axis (unit) and its radius (mm)."""

    center: tuple
    axis: tuple
    radius_mm: float
    kind: str = "cylinder"

    def params(self) -> dict:
        c, u = self.center, _unit(self.axis)
        return {"center_x_mm": c[0], "center_y_mm": c[1], "center_z_mm": c[2],
                "axis_x": u[0], "axis_y": u[1], "axis_z": u[2], "radius_mm": self.radius_mm}

    def first_contact(self, shaft, toward):
        u = _unit(self.axis)
        if abs(float(u @ shaft)) > 1e-6:
            raise TapError(f"the shaft is {math.degrees(math.acos(min(1.0, abs(u @ shaft)))):.1f}"
                           " deg from the axis: only taps with the shaft across it are exact")
        c = np.asarray(self.center, float)
        w = np.asarray(toward, float) - c
        n = _across(_across(w, u), shaft)  # across the axis and the shaft
        return c + (w @ u) * u + self.radius_mm * n, n


@dataclass(frozen=True)
class Plane:
    """A plate in W: its face's outward unit normal and distance (n . p = distance_mm)."""

    normal: tuple
    distance_mm: float
    kind: str = "plane"

    def params(self) -> dict:
        n = _unit(self.normal)
        return {"normal_x": n[0], "normal_y": n[1], "normal_z": n[2],
                "distance_mm": self.distance_mm}

    def face_deg(self, shaft) -> float:
        """The angle (deg) at which the face rises from a tap's travel: 90 less the shaft's."""
        return math.degrees(math.acos(float(np.clip(_unit(self.normal) @ shaft, -1.0, 1.0))))

    def first_contact(self, shaft, toward):
        """The rim point nearest ``toward`` and the face's normal."""
        n = _unit(self.normal)
        p = np.asarray(toward, float)
        return p - (p @ n - self.distance_mm) * n, n


@dataclass(frozen=True)
class Tap:
    """One tap's geometry: S's orientation in W, the base at first contact (W), the unit
    direction d it presses in (W), the shaft a, theta_tap (deg, d in S), the planar
    scene (x along d, y along a, the base at x = 0 at first contact) and the first
    contact's distance along the shaft."""

    rotation: Rotation
    origin: np.ndarray
    d: np.ndarray
    a: np.ndarray
    theta_deg: float
    scene: object
    depth_mm: float

    def to_world(self, x_mm, y_mm) -> np.ndarray:
        """Points of the tap's plane (x along d, y along a; arrays (N,)) in W, shape (N, 3)."""
        return self.origin + np.outer(x_mm, self.d) + np.outer(y_mm, self.a)


def tap_on(obj, rotation: Rotation, toward, depth_mm: float, mu: float = 0.5) -> Tap:
    """The tap of a sensor held at ``rotation`` (S in W) that meets ``obj`` (a
    :class:`Sphere`, :class:`Cylinder` or :class:`Plane`) at ``depth_mm`` along its shaft,
    on the side facing the point ``toward`` (a plate: at its rim point nearest it).

    Raises
    ------
    TapError
        A cylinder's axis not across the shaft, or a plate's face rising outside
        :data:`FACE_DEG` from the travel.
    """
    a = rotation.apply([0.0, 0.0, 1.0])
    point, n = obj.first_contact(a, toward)
    if obj.kind == "plane":
        rise = obj.face_deg(a)
        if not FACE_DEG[0] <= rise <= FACE_DEG[1]:
            raise TapError(f"the plate's face rises at {rise:.1f} deg from the travel, outside "
                           f"{FACE_DEG[0]:g}-{FACE_DEG[1]:g} deg")  # fmt: skip
        d = -_across(n, a)
        length = (TOP_MM - depth_mm) / math.sin(math.radians(rise))
        scene = BoxScene(0.0, depth_mm, face_angle_deg=rise, mu=mu, face_length_mm=length)
    else:
        d = -n  # the base presses toward the centre (the axis)
        scene = CircleScene(obj.radius_mm, depth_mm, obj.radius_mm)
    d_s = rotation.inv().apply(d)
    theta = float(_wrap_deg(math.degrees(math.atan2(d_s[1], d_s[0]))))
    return Tap(rotation, point - depth_mm * a, d, a, theta, scene, float(depth_mm))


def _wrap_deg(theta):
    """Angles (deg) into (-180, 180]."""
    return 180.0 - (180.0 - np.asarray(theta, float)) % 360.0


class TapRun:
    """One simulated tap: the planar run, its tap, the poses of S in W on the stage's clock
    (t_s (N,), position (N, 3), quaternion (N, 4) scalar first) and the true contact point
    per camera frame in W (NaN out of contact)."""

    def __init__(self, name: str, tap: Tap, run: StageRun, poses: tuple, contact: np.ndarray):
        self.name, self.tap, self.run, self.poses, self.contact = name, tap, run, poses, contact

    @property
    def signals(self) -> dict:
        return self.run.signals


def _solved(scene, mech, n_steps: int, protocol: StageProtocol):
    """The sweep of the first ``n_steps`` presses (positions as simulate_run steps them),
    or None where the elastica fails on the way (the contact runs off toward the base)."""
    x = protocol.step_mm * np.arange(-protocol.approach_steps, n_steps + 1)
    try:
        return sweep(scene, mech, x)
    except ElasticaError:
        return None


def press_travel_mm(scene, mech=None, protocol: StageProtocol = TAP_PROTOCOL) -> float:
    """How far past first contact a tap presses: its protocol's travel, cut where the contact
    would reach :data:`MIN_DEPTH_MM` from the base (a sphere's point of tangency runs toward
    it) or the whisker leaves the object (NaN); at least one step."""
    mech = mech or WhiskerMechanics()
    n = int(round(protocol.max_travel_mm / protocol.step_mm))
    s = _solved(scene, mech, n, protocol)
    while s is None and n > 1:  # back off to the last press the elastica solves
        n -= 1
        s = _solved(scene, mech, n, protocol)
    if s is None:
        return protocol.step_mm
    k = protocol.approach_steps
    y, phi = s.contact_y_mm[k + 1:], s.phi_deg[k + 1:]
    bad = np.flatnonzero(~((y >= MIN_DEPTH_MM) & np.isfinite(phi)))
    steps = int(bad[0]) if bad.size else n
    return protocol.step_mm * max(1, steps)


def simulate_tap(tap: Tap, rng, name: str = "tap", noise: NoiseModel = FRONT_END_NOISE,
                 protocol: StageProtocol = TAP_PROTOCOL, mech=None) -> TapRun:  # fmt: skip
    """Simulate one tap: signals (theta turned to the tap's direction in S), poses, truth.
    The press stops at the protocol's phi or at :func:`press_travel_mm`."""
    mech = mech or WhiskerMechanics()
    travel = press_travel_mm(tap.scene, mech, protocol)
    protocol = dataclasses.replace(protocol, max_travel_mm=min(protocol.max_travel_mm, travel))
    run = simulate_run(name, "slide-box", tap.scene, rng, mech=mech, protocol=protocol,
                       noise=noise)  # fmt: skip
    run.signals["theta_deg"] = _wrap_deg(run.signals["theta_deg"] + tap.theta_deg)
    run.info["theta_deg"] = float(_wrap_deg(run.info["theta_deg"] + tap.theta_deg))
    x = np.asarray(run.stage["x_mm"], float)
    p = tap.origin + np.outer(x, tap.d)
    q = np.tile(tap.rotation.as_quat(scalar_first=True), (x.size, 1))
    contact = tap.to_world(run.truth["contact_x_mm"], run.truth["contact_y_mm"])
    return TapRun(name, tap, run, (np.asarray(run.stage["t_s"], float), p, q), contact)


def object_record(obj) -> dict:
    """The object in section 9's names: ``model`` and its parameters."""
    return {"model": obj.kind, **{k: float(v) for k, v in obj.params().items()}}


def write_taps(dest: str | Path, obj, taps: list[TapRun], record: dict | None = None
               ) -> list[Path]:  # fmt: skip
    """Write, per tap, ``NAME.signals.csv``, ``NAME.pose.csv`` (S in W, stage clock) and
    ``NAME.contact_truth.csv`` (camera clock: the true contact point in W), and
    ``object.json``: the object, each tap's true clock offset, theta and sensor, and
    ``record``'s keys (how it was made). Returns the paths written."""
    out = Path(dest)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for tr in taps:
        sig, (t, p, q) = tr.signals, tr.poses
        signals = {k: sig[k] for k in ("frame", "t_s", "dz_mm", "phi_deg", "theta_deg", "ok")}
        pose = {"t_s": t, "x_mm": p[:, 0], "y_mm": p[:, 1], "z_mm": p[:, 2],
                "qw": q[:, 0], "qx": q[:, 1], "qy": q[:, 2], "qz": q[:, 3]}
        c = tr.contact
        truth = {"t_s": tr.run.truth["t_s"], "px_mm": c[:, 0], "py_mm": c[:, 1],
                 "pz_mm": c[:, 2], "phi_deg": tr.run.truth["phi_deg"],
                 "slipping": tr.run.truth["slipping"].astype(int)}
        for suffix, cols, digits in (("signals", signals, 8), ("pose", pose, 9),
                                     ("contact_truth", truth, 6)):
            write_csv(out / f"{tr.name}.{suffix}.csv", cols, digits=digits)
            paths.append(out / f"{tr.name}.{suffix}.csv")
    doc = {"camwhisker": __version__, **(record or {}), "object": object_record(obj),
           "taps": [{"name": tr.name, "offset_s": tr.run.offset_s,
                     "theta_deg": tr.tap.theta_deg, **tr.run.info.get("sensor", {})}
                    for tr in taps]}  # fmt: skip
    atomic_write_text(out / "object.json", dumps(doc, indent=1) + "\n")
    return [*paths, out / "object.json"]


# --- a rig of sensors and seed 000's protocol ----------------------------------------------

#: Seed 000's stimuli: spheres of 200, 300 and 600 mm diameter, and a plane.
PAPER_SPHERE_RADII_MM = (100.0, 150.0, 300.0)
STIMULI = (("sphere", 100.0), ("sphere", 150.0), ("sphere", 300.0), ("plane", math.nan))
#: Seed 000's ten locations L1-L10, 40 mm apart across the stimulus (mm).
LOCATIONS_MM = tuple(-180.0 + 40.0 * k for k in range(10))
#: The carrier's origin this far out from the stimulus (mm), before each tap's approach.
STANDOFF_MM = 60.0
#: Where along the shaft the first contact lies (mm): a sphere's side, a plate's rim; both
#: within the calibrated 22.5-90 mm with room for the sphere's contact sliding toward the
#: base and the plate's sliding onto its face (up to TOP_MM).
SPHERE_DEPTH_MM = (60.0, 88.0)
PLATE_DEPTH_MM = (35.0, 60.0)


def _mount(name: str, x_mm: float, yaw_deg: float, rise_deg: float, roll_deg: float
           ) -> RigSensor:  # fmt: skip
    """A sensor at x_mm across the carrier, its shaft turned yaw_deg about y_c from z_c and
    raised rise_deg toward y_c, rolled roll_deg about the shaft."""
    y, r = math.radians(yaw_deg), math.radians(rise_deg)
    a = np.array([math.sin(y) * math.cos(r), math.sin(r), math.cos(y) * math.cos(r)])
    x0 = _unit(np.cross([0.0, 1.0, 0.0], a))
    frame = np.column_stack([x0, np.cross(a, x0), a])
    turn = Rotation.from_matrix(frame) * Rotation.from_euler("z", roll_deg, degrees=True)
    return RigSensor(name, Mount(np.array([x_mm, 0.0, 0.0]), turn.as_quat(scalar_first=True)))


#: Five sensors in a fan across the carrier (z_c forward, y_c away from the stimulus): their
#: shafts 6-16 deg off the stimulus's facing plane, rolled differently so that theta
#: differs; the plate's face then rises at 74-84 deg from each tap's travel.
RIG = (_mount("s1", -60.0, -40.0, 8.0, 0.0), _mount("s2", -30.0, -20.0, 12.0, 35.0),
       _mount("s3", 0.0, 0.0, 16.0, -60.0), _mount("s4", 30.0, 20.0, 10.0, 90.0),
       _mount("s5", 60.0, 40.0, 14.0, 150.0))  # fmt: skip


@dataclass
class Trial:
    """One trial of the protocol: the stimulus, its location index, the carrier's
    orientation in W and a tap per sensor of the rig."""

    seed: int
    stimulus: int
    location: int
    obj: object
    taps: list
    sensors: list


def _rig_taps(obj, top, carrier: Rotation, location_mm: float, rng, rig) -> list[Tap]:
    """A tap per sensor of ``rig``: the carrier (``carrier``: its orientation in W, y_c away
    from the object) brought STANDOFF_MM out from ``top`` and ``location_mm`` across, then
    moved so that each sensor taps the side of the object facing it (a plate: its rim)."""
    x_c, y_c, _ = carrier.as_matrix().T
    origin = top + STANDOFF_MM * y_c + location_mm * x_c
    depths = SPHERE_DEPTH_MM if obj.kind == "sphere" else PLATE_DEPTH_MM
    return [tap_on(obj, carrier * m.mount.rotation, origin + carrier.apply(m.mount.position_mm),
                   rng.uniform(*depths), mu=rng.uniform(*MU)) for m in rig]  # fmt: skip


def protocol_trial(seed: int, rig=RIG) -> Trial:
    """Seed 000's trial ``seed``: stimulus seed % 4 (:data:`STIMULI`) at location
    (seed // 4) % 10 (:data:`LOCATIONS_MM`); the carrier's orientation, the stimulus's
    place, each tap's depth and a plate's friction drawn from the seed (:func:`_rig_taps`)."""
    rng = np.random.default_rng(seed)
    stimulus, location = seed % len(STIMULI), (seed // len(STIMULI)) % len(LOCATIONS_MM)
    kind, radius = STIMULI[stimulus]
    carrier = Rotation.random(random_state=rng)
    y_c = carrier.apply([0.0, 1.0, 0.0])
    q = rng.uniform(-200.0, 200.0, 3)
    if kind == "sphere":
        obj, top = Sphere(tuple(q), radius), q + radius * y_c
    else:
        obj, top = Plane(tuple(y_c), float(y_c @ q)), q
    taps = _rig_taps(obj, top, carrier, LOCATIONS_MM[location], rng, rig)
    return Trial(seed, stimulus, location, obj, taps, [m.name for m in rig])


def _cylinder_taps(obj: Cylinder, rng, n: int) -> list[Tap]:
    """``n`` taps with the shaft across the axis: at points spread along it and around it,
    each sensor rolled at random about its shaft."""
    u = _unit(obj.axis)
    e1 = _across(rng.standard_normal(3), u)
    taps = []
    for k in range(n):
        b = 2.0 * math.pi * k / n + rng.uniform(-0.3, 0.3)
        out = math.cos(b) * e1 + math.sin(b) * np.cross(u, e1)  # the side tapped
        a = np.cross(u, out)  # the shaft: across the axis and along the surface
        x0 = _across(rng.standard_normal(3), a)
        frame = np.column_stack([x0, np.cross(a, x0), a])
        toward = np.asarray(obj.center) + rng.uniform(-60.0, 60.0) * u + 2.0 * obj.radius_mm * out
        taps.append(tap_on(obj, Rotation.from_matrix(frame), toward,
                           rng.uniform(*SPHERE_DEPTH_MM)))  # fmt: skip
    return taps


def object_taps(kind: str, seed: int, n_cylinder: int = 6) -> Trial:
    """Taps on one object of ``kind`` (:data:`OBJECTS`) drawn from ``seed``: a sphere
    (radius 50-300 mm) or a plate tapped by the rig at a random location; a cylinder
    (radius 30-150 mm) tapped ``n_cylinder`` times by one sensor with its shaft across the
    axis."""
    if kind not in OBJECTS:
        raise ValueError(f"unknown object {kind!r} (known: {', '.join(OBJECTS)})")
    rng = np.random.default_rng(seed)
    q = rng.uniform(-200.0, 200.0, 3)
    if kind == "cylinder":
        obj = Cylinder(tuple(q), tuple(_unit(rng.standard_normal(3))), rng.uniform(30.0, 150.0))
        taps = _cylinder_taps(obj, rng, n_cylinder)
        return Trial(seed, -1, -1, obj, taps, [f"t{k + 1}" for k in range(len(taps))])
    carrier = Rotation.random(random_state=rng)
    y_c = carrier.apply([0.0, 1.0, 0.0])
    location = int(rng.integers(len(LOCATIONS_MM)))
    if kind == "sphere":
        obj = Sphere(tuple(q), rng.uniform(50.0, 300.0))
        top = q + obj.radius_mm * y_c
    else:
        obj, top = Plane(tuple(y_c), float(y_c @ q)), q
    taps = _rig_taps(obj, top, carrier, LOCATIONS_MM[location], rng, RIG)
    return Trial(seed, -1, location, obj, taps, [m.name for m in RIG])


def simulate_trial(trial: Trial, noise: NoiseModel = FRONT_END_NOISE) -> list[TapRun]:
    """Every tap of a trial, each with its own noise and clock offset (seeded by the trial)."""
    children = np.random.SeedSequence([trial.seed, 7]).spawn(len(trial.taps))
    runs = []
    for tap, name, child in zip(trial.taps, trial.sensors, children, strict=True):
        where = f"L{trial.location + 1}" if trial.location >= 0 else ""
        tr = simulate_tap(tap, np.random.default_rng(child), f"{where}{name}", noise)
        tr.run.info["sensor"] = {"sensor": name, "depth_mm": tap.depth_mm}
        runs.append(tr)
    return runs


def write_object_taps(dest: str | Path, kind: str, seed: int, command: str = "",
                      noise: NoiseModel = FRONT_END_NOISE) -> list[Path]:  # fmt: skip
    """Simulate :func:`object_taps` and write them with :func:`write_taps`."""
    trial = object_taps(kind, seed)
    return write_taps(dest, trial.obj, simulate_trial(trial, noise),
                      {"command": command, "kind": kind, "seed": seed})  # fmt: skip
