"""The rigid whisker of the paper's accuracy tests: its pose from the stage geometry alone.

Test 1 (Sec. III-A): a rigid whisker on the spring suspension, its base stepped
along x against a rigid surface at a known radial contact distance r, turns by
a rotation that the geometry fixes. Test 2: a manual linear stage pushes the
rigid whisker along its axis, so the applied dz is the stage's travel.

Same planar frame as :mod:`camwhisker.sim.mechanics.whisker`: the base travels
along +x on y = 0, the whisker points along +y at rest, and r is the
contact's distance from the point of rotation along the rest axis (the
paper's definition, Fig. 1).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from camwhisker.calibration.validate import rigid_phi_deg
from camwhisker.sim.mechanics.scenes import PegScene, Sweep
from camwhisker.sim.mechanics.whisker import WhiskerMechanics

__all__ = ["AxialPush", "rigid_phi_deg", "rigid_peg_sweep", "axial_push_sweep"]


@dataclass(frozen=True)
class AxialPush:
    """Test 2's manual stage on the whisker's tip: it touches at ``x_mm`` and pushes along the axis.

    ``x_mm`` is the stage's own reading at touch, so the log's position and the
    applied dz differ by it.
    """

    x_mm: float = 0.0
    kind: str = field(default="axial-push", init=False)

    def first_contact_x(self, mech: WhiskerMechanics) -> float:
        return self.x_mm


def _contact_sweep(xs, contact, phi, dz, r, cx, cy, force) -> Sweep:
    """A Sweep whose contact fields are NaN outside contact; no slip, no elastica."""
    nan = np.where(contact, 0.0, np.nan)
    return Sweep(
        base_x_mm=xs, in_contact=contact, phi_deg=phi, dz_mm=dz, r_mm=r + nan,
        s_contact_mm=r + nan, contact_x_mm=cx + nan, contact_y_mm=cy + nan,
        force_n=force + nan, slipping=np.zeros(xs.size, bool), elastica=np.zeros(xs.size, bool),
    )  # fmt: skip


def rigid_peg_sweep(scene: PegScene, mech: WhiskerMechanics, positions) -> Sweep:
    """Test 1: a rigid whisker stepped past a rigid, frictionless contact at ``scene.r_mm``.

    phi from :func:`rigid_phi_deg`; the load is normal to the whisker, so it has
    no axial share and dz = 0. The base spring holds the moment k_phi phi =
    F s, with s the straight distance base -> contact (also ``r_mm`` of the
    Sweep, as for the flexible whisker).
    """
    xs = np.asarray(positions, float)
    dx = np.clip(xs - scene.x_mm, 0.0, None)
    phi = rigid_phi_deg(scene.r_mm, dx)
    s = np.hypot(dx, scene.r_mm)
    force = mech.k_phi_nmm_per_rad * np.radians(phi) / s
    return _contact_sweep(xs, dx > 0, phi, np.zeros(xs.size), s, scene.x_mm, scene.r_mm, force)


def axial_push_sweep(scene: AxialPush, mech: WhiskerMechanics, positions) -> Sweep:
    """Test 2: the stage pushes the rigid whisker's tip along its axis; dz is its travel, phi 0."""
    xs = np.asarray(positions, float)
    dz = np.clip(xs - scene.x_mm, 0.0, None)
    force = mech.k_z_n_per_mm * dz
    tip = np.full(xs.size, mech.length_mm)
    return _contact_sweep(xs, dz > 0, np.zeros(xs.size), dz, tip, 0.0, tip, force)
