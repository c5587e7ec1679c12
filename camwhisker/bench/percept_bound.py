"""What a simulated wall's pauses allow: the Cramer-Rao bound on its fitted angle.

Each stage pause puts the contact somewhere along the curve that eq. 12 traces as r
varies at the pause's phi; the estimate of r decides where. Until the contact first
slips, r is GM's, with the calibration's sigma_GM at that phi; from then on (GM's r
holds only from the onset) it is MF's, whose scatter from noise is dr/d(dz) there
times the noise of a pause median of dz (the calibration's). A point off the wall
along that curve by e is off the wall by (n . u) e, u the curve's unit tangent and n
the wall's normal. The inverse Fisher information of the pauses' distances then bounds
the spread of any unbiased fit of the wall's angle from them. It leaves out MF's error
between calibrated radii, the noise of phi and GM's error shared by the pauses of one
stuck contact, so real fits do worse: the bound says where a miss is the pauses' noise
and not the fit.
"""

from __future__ import annotations

import math

import numpy as np

from camwhisker.contact.mf import r_mf
from camwhisker.contact.shape import reconstruct
from camwhisker.percept.surfels import Pose

__all__ = ["line_angle_bound_deg", "wall_angle_bound_deg"]

# Smallest distance scale (mm) of a point: one whose r error runs along the wall still
# carries eq. 12's own error across it.
FLOOR_MM = 0.01
# Step in r (mm) of the curve's tangent.
_STEP_MM = 0.5


def line_angle_bound_deg(points, along, sigma, normal_deg: float) -> float:
    """The Cramer-Rao bound (deg, one sd) on a line's angle fitted with its offset to points
    on it, each off along the unit vector ``along`` by N(0, ``sigma``) (mm); inf where the
    points cannot fix a line. ``normal_deg``: the line's normal."""
    p, u = np.asarray(points, float).reshape(-1, 2), np.asarray(along, float).reshape(-1, 2)
    t = math.radians(normal_deg)
    n, dn = np.array([math.cos(t), math.sin(t)]), np.array([-math.sin(t), math.cos(t)])
    sd = np.maximum(np.abs(u @ n) * np.asarray(sigma, float), FLOOR_MM)
    ok = np.isfinite(sd) & np.all(np.isfinite(p), axis=1)
    # Derivatives of a point's distance n . p - d by the normal's angle and by the offset.
    jac = np.c_[p[ok] @ dn, -np.ones(int(ok.sum()))] / sd[ok, None]
    info = jac.T @ jac
    if np.linalg.matrix_rank(info) < 2:
        return math.inf
    return math.degrees(math.sqrt(np.linalg.inv(info)[0, 0]))


def _pause_frames(cols: dict) -> np.ndarray:
    """The middle row of each stage pause of a contact table."""
    pause = np.asarray(cols["pause"], float)
    rows = []
    for p in np.unique(pause[np.isfinite(pause)]):
        idx = np.flatnonzero(pause == p)
        rows.append(idx[idx.size // 2])
    return np.asarray(rows, int)


def _pause_truth(run, cols, calib, travel_sign: float):
    """Per pause in contact: the true contact point (stage frame), the unit tangent of eq.
    12's curve in r there and the scatter (mm) of the estimate of r that holds there (NaN
    where MF has none)."""
    tr = run.truth
    k = np.clip(np.searchsorted(tr["t_s"], np.asarray(cols["t_s"], float)[_pause_frames(cols)]),
                0, tr["t_s"].size - 1)
    r, phi, dz, x = (np.asarray(tr[key], float)[k] for key in ("r_mm", "phi_deg", "dz_mm", "x_mm"))
    touch = (np.asarray(tr["in_contact"])[k] == 1) & np.isfinite(r)
    r, phi, dz, x, k = r[touch], phi[touch], dz[touch], x[touch], k[touch]
    ends = [reconstruct(x, r + h, phi, dz, travel_sign, calib.gm, calib.bend)
            for h in (-_STEP_MM, _STEP_MM)]
    u = np.c_[ends[1][0] - ends[0][0], ends[1][1] - ends[0][1]]
    u /= np.hypot(*u.T)[:, None]
    # GM (eq. 8, from the travel since the onset) holds until the contact first slips.
    slid = np.cumsum(np.asarray(tr["slipping"], bool)[k]) > 0
    noise = calib.dz_noise_mm if calib.dz_noise_mm is not None else math.nan
    sigma = np.where(slid, r_mf(calib.mf_table, phi, dz).dr_ddz * noise,
                     calib.gm_spread.sigma_at(phi))
    point = np.c_[np.asarray(tr["contact_x_mm"], float), np.asarray(tr["contact_y_mm"], float)][k]
    return point, u, sigma


def wall_angle_bound_deg(sweep, runs, calib) -> float:
    """:func:`line_angle_bound_deg` for a simulated wall from its runs' pauses.

    ``runs``: (run spec, simulated run, contact table) per run of ``sweep``
    (:mod:`camwhisker.bench.percepts`); the points go to the common frame by each run's pose.
    """
    parts = []
    for spec, run, cols in runs:
        point, u, sigma = _pause_truth(run, cols, calib, spec.travel_sign)
        pose = Pose(*spec.pose)
        parts.append((pose.apply(point), pose.rotate(u), sigma))
    points, along, sigma = (np.concatenate([p[i] for p in parts]) for i in range(3))
    return line_angle_bound_deg(points, along, sigma, sweep.truth["angle_deg"] + 90.0)
