"""Objects for shape percepts: walls, cylinders and box corners, each swept by the stage.

A percept sweep is one object swept by one or more stage runs, each run in its
own stage frame placed in the object's (common) frame by a pose (common =
origin + R(angle) stage). The whisker touches an object where the
scenes of :mod:`camwhisker.sim.mechanics.scenes` can model it:

- a *wall* (a plank seen edge-on, rising at 70-86 deg): a run in +x meets
  its lower end, sticks there (Coulomb friction), then slips up its face;
  :func:`turned_wall_run` sweeps it again from a turned stage frame;
- a *cylinder* (radius 15-80 mm, its axis 30-90 mm from the base line): a run
  from each side, the whisker's side sliding down the near flank (as the
  bottle of the stage experiments);
- a *box corner* (opening 60-120 deg): a run in +x meets the apex and slips up
  one face, and a run in -x, its stage frame turned so that the other face
  rises steeply in it, slips along the other;
- *nothing*: a wall's run with the whisker untouched (the campaign's signals
  are the front end's noise alone).

Slip comes from the scenes' friction and tangency; the objects are rigid (the
simulator makes compliance only for pegs).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from camwhisker.sim.mechanics.scenes import BoxScene, CircleScene

__all__ = ["OBJECT_KINDS", "MirroredBox", "SweepRun", "PerceptSweep", "draw_sweep",
           "turned_wall_run"]

OBJECT_KINDS = ("none", "wall", "cylinder", "corner")


@dataclass(frozen=True)
class MirroredBox:
    """A :class:`BoxScene` seen from its other side: the lab frame of a run in -x."""

    box: BoxScene
    kind: str = field(default="box", init=False)

    def mirrored(self) -> BoxScene:
        return self.box

    def outline(self):
        x, y = self.box.outline()
        return -x, y

    def profile_distance(self, x_mm, y_mm):
        return self.box.profile_distance(-np.asarray(x_mm), y_mm)


@dataclass(frozen=True)
class SweepRun:
    """One stage run of a sweep: its lab-frame scene, travel and pose in the common frame."""

    scene: object
    travel_sign: float
    pose: tuple[float, float, float]  # x0_mm, y0_mm, angle_deg


@dataclass(frozen=True)
class PerceptSweep:
    """An object, its true parameters (common frame) and the runs that sweep it."""

    kind: str
    truth: dict
    runs: tuple[SweepRun, ...]


# Faces rise this steeply from the travel direction, with this friction: on a
# shallower face, or a more slippery one, the stuck load leaves the friction cone at
# first touch and the simulated whisker snaps off without a stick-slip trace.
FACE_DEG = (70.0, 86.0)
MU = (0.4, 0.6)
# Contacts stay within the radii the contact back end is calibrated on (the paper's
# pegs, 22.5-90 mm): faces end at this height in their run's frame, and a cylinder's
# first contact (at its centre's height) lies below it.
TOP_MM = 90.0


def _face(y_end: float, angle_deg: float, mu: float, x_end: float = 0.0) -> BoxScene:
    """A face from its lower end at (x_end, y_end), rising at angle_deg, ending at TOP_MM."""
    length = (TOP_MM - y_end) / math.sin(math.radians(angle_deg))
    return BoxScene(x_end, y_end, face_angle_deg=angle_deg, mu=mu, face_length_mm=length)


def _wall(rng):
    angle = rng.uniform(*FACE_DEG)
    y_end = rng.uniform(30.0, 60.0)
    box = _face(y_end, angle, rng.uniform(*MU))
    a = math.radians(angle)
    truth = {"angle_deg": angle, "distance_mm": abs(y_end * math.cos(a)),
             "end_x_mm": 0.0, "end_y_mm": y_end}
    return PerceptSweep("wall", truth, (SweepRun(box, 1.0, (0.0, 0.0, 0.0)),))


def turned_wall_run(first: SweepRun, turn_deg: float) -> SweepRun:
    """A wall's run (``first``, travelling in +x at pose 0) again, from a stage frame turned
    by ``turn_deg`` about the first run's origin: the face rises at its angle less
    ``turn_deg`` there (and, as every face here, ends at TOP_MM)."""
    box, t = first.scene, math.radians(turn_deg)
    x, y = box.corner_x_mm, box.corner_y_mm
    end = (x * math.cos(t) + y * math.sin(t), -x * math.sin(t) + y * math.cos(t))
    scene = _face(end[1], box.face_angle_deg - turn_deg, box.mu, x_end=end[0])
    return SweepRun(scene, 1.0, (0.0, 0.0, float(turn_deg)))


def _cylinder(rng):
    radius = rng.uniform(15.0, 80.0)
    cy = rng.uniform(max(30.0, radius + 5.0), max(TOP_MM, radius + 5.0))
    c = CircleScene(0.0, cy, radius)
    truth = {"center_x_mm": 0.0, "center_y_mm": cy, "radius_mm": radius}
    return PerceptSweep("cylinder", truth, (SweepRun(c, 1.0, (0.0, 0.0, 0.0)),
                                           SweepRun(c, -1.0, (0.0, 0.0, 0.0))))


def _corner(rng):
    """Apex at (0, ya), face 1 rising at a1 (the first run's), face 2 at a1 - opening.

    The second run travels -x in a frame turned by theta, where face 2 rises at b2 in
    the simulator's (mirrored) frame: 180 - (a2 - theta) = b2.
    """
    a1, b2 = rng.uniform(*FACE_DEG, 2)
    opening = rng.uniform(60.0, 120.0)
    a2 = a1 - opening
    ya, h2 = rng.uniform(30.0, 60.0, 2)
    mu1, mu2 = rng.uniform(*MU, 2)
    theta = math.radians(b2 + a2 - 180.0)
    first = SweepRun(_face(ya, a1, mu1), 1.0, (0.0, 0.0, 0.0))
    origin = (h2 * math.sin(theta), ya - h2 * math.cos(theta))  # the apex at (0, ya)
    second = SweepRun(MirroredBox(_face(h2, b2, mu2)), -1.0,
                      (*origin, math.degrees(theta)))
    truth = {"apex_x_mm": 0.0, "apex_y_mm": ya, "face1_deg": a1, "face2_deg": a2 % 360.0,
             "opening_deg": opening}
    return PerceptSweep("corner", truth, (first, second))


def _nothing(rng):
    # A wall's runs; the campaign keeps their stage logs and replaces the signals by noise.
    sweep = _wall(rng)
    return PerceptSweep("none", {}, sweep.runs)


_DRAW = {"none": _nothing, "wall": _wall, "cylinder": _cylinder, "corner": _corner}


def draw_sweep(kind: str, rng: np.random.Generator) -> PerceptSweep:
    """An object of ``kind`` (:data:`OBJECT_KINDS`) with its parameters drawn from ``rng``."""
    if kind not in _DRAW:
        raise ValueError(f"unknown object kind {kind!r} (known: {', '.join(OBJECT_KINDS)})")
    return _DRAW[kind](rng)
