"""Contact in 3-D (docs/sensor.md section 9): a base that moves in space, contacts placed in W.

The whisker bends in the plane of its shaft and the contact force; theta (signals) says
which way the base pressed into the object. So the contact side of a one-axis stage
applies along that direction: the base's travel across the shaft toward theta, read
from the pose log, is the stage position (:func:`travel_log`); GM, MF, Z, the fusion and
eq. 12 run as for a stage (:func:`~camwhisker.contact.pipeline.contact_rows`), and eq.
12's point, in the plane of the shaft and theta, is placed in W by the base's pose at
the frame (:func:`contact_rows_in_space`). Where the whole contact's travel follows a
contact sliding toward the base along a smooth object (:mod:`camwhisker.contact.slide`),
or one stuck at an edge and then dragged along a flat face (:mod:`camwhisker.contact.face`),
r_hat and eq. 12's point come from that (:func:`with_whole_contact`); a stage's own tables
never do.

In S (section 9): the whisker at rest lies along z_S; a tilt toward psi = theta + 180 deg
is the object's push, so (cos psi, sin psi, 0) is the estimate of the surface normal.

A base that turns (a robot's wrist, a whisking actuator) moves each point of the shaft
differently: with the contact stuck at c in W, the object displaces the shaft's point at
r across the shaft, in S, by x(t; r) = d_w(t) . (p(t) - c), c = p(t0) + r R(t0) e_z at
first contact t0 and d_w(t) = R(t) d_s the pressing direction in W at t. That travel is
the stage position, and r is solved for: the run's stuck r_hat from the travel at r must
be r (:func:`_turning_rows`). A base that keeps its orientation gives the base's own
travel (r drops out). The clock offset is found from the base's 3-D motion (translation
and turn, :meth:`~camwhisker.io.poses.PoseLog.motion_mm`): its pauses and changes of speed
wherever it moves, not only across the shaft.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from camwhisker.contact.face import face_r, fit_face, fit_stuck, mf_cost, stuck_r, stuck_y0
from camwhisker.contact.pipeline import (
    CONTACT_COLUMNS,
    ONSET_DX_MM,
    Calibration,
    RunAnalysis,
    contact_rows,
    smooth_half_frames,
)
from camwhisker.contact.shape import reconstruct
from camwhisker.contact.slide import MAX_RMS_MM, fit_slide
from camwhisker.contact.smooth import local_line
from camwhisker.contact.stage import (
    CONTACT_PHI_DEG,
    STATIONARY_TOL_MM,
    StageLog,
    stage_log_from_arrays,
)
from camwhisker.io.poses import MAX_GAP_S, PoseLog

__all__ = ["WORLD_COLUMNS", "BASE_COLUMNS", "STILL_TURN_DEG", "MIN_TRAVEL_MM", "MIN_CLOCK_SCORE",
           "SpaceError", "pressing_theta_deg", "travel_log", "contact_rows_in_space",
           "with_whole_contact", "placed_in_world"]  # fmt: skip

#: The contact point and the surface normal's estimate in W, after the section 7 columns.
WORLD_COLUMNS = ("px_mm", "py_mm", "pz_mm", "nx", "ny", "nz")
#: Written after them: the base (S's origin) in W and the shaft's rest direction (z_S), for
#: the free space the base moved through and the normal's component along the shaft.
BASE_COLUMNS = ("bx_mm", "by_mm", "bz_mm", "ax", "ay", "az")
#: A base that turns less than this over a run (deg) keeps its orientation: at the
#: whisker's 150 mm it moves the shaft's point by 3 um, the pause tolerance's order.
STILL_TURN_DEG = 1e-3
#: Least range of the base's travel across the shaft (mm): one of the calibration's steps.
MIN_TRAVEL_MM = 1.0
#: Least share of the signals that the pauses' model explains at the estimated offset: the
#: motion estimator's own floor (contact.clock); under it no clock is aligned.
MIN_CLOCK_SCORE = 0.5
#: r (mm) is solved for to this (far under GM's spread), in at most R_STEPS passes ...
R_TOL_MM = 0.1
R_STEPS = 8
#: ... and a run whose r_hat still misses r by more than this (mm) is refused.
R_SETTLE_MM = 2.0


class SpaceError(ValueError):
    """A run that cannot be placed in space; the message names the file and why."""


def pressing_theta_deg(signals: dict) -> float:
    """The direction theta (deg, in S) in which the base pressed: the circular mean of the
    trusted rows' theta in contact (phi >= CONTACT_PHI_DEG), each weighted by its phi; NaN
    without such a row."""
    theta = np.asarray(signals["theta_deg"], float)
    phi = np.asarray(signals["phi_deg"], float)
    use = np.asarray(signals["ok"], bool) & (phi >= CONTACT_PHI_DEG) & np.isfinite(theta)
    if not use.any():
        return math.nan
    t = np.radians(theta[use])
    return float(np.degrees(np.arctan2(np.sum(phi[use] * np.sin(t)),
                                       np.sum(phi[use] * np.cos(t)))))  # fmt: skip


def _direction_s(theta_deg: float) -> np.ndarray:
    th = math.radians(theta_deg)
    return np.array([math.cos(th), math.sin(th), 0.0])


def _motion(poses: PoseLog, x: np.ndarray, d_w: np.ndarray, turning: bool, reach_mm: float):
    """The base's 3-D motion for the pauses (:meth:`PoseLog.motion_mm`), or None where it
    moves along d_w alone and its travel says all (the one-axis stage's path, digit for
    digit)."""
    off = (poses.p_mm - poses.p_mm[0]) - np.outer(x, d_w)
    if not turning and np.max(np.linalg.norm(off, axis=1)) <= STATIONARY_TOL_MM:
        return None
    return poses.motion_mm(reach_mm)


def travel_log(poses: PoseLog, theta_deg: float, r_mm: float = 0.0,
               t_ref_s: float | None = None, reach_mm: float = 150.0) -> StageLog:  # fmt: skip
    """The travel across the shaft toward theta as a one-axis stage log.

    For a base that keeps its orientation (within :data:`STILL_TURN_DEG`), the base's
    position along theta from its first pose. For one that turns, that of the shaft's point
    at ``r_mm`` against a contact stuck where it was at ``t_ref_s`` (pose clock; default:
    the first pose): x(t) = d_w(t) . (p(t) - c) (module docstring), 0 at ``t_ref_s``. The
    log carries the base's 3-D motion (``reach_mm``: the whisker's length, at which a turn
    counts) wherever the base moves other than along theta.

    Raises
    ------
    SpaceError
        The base (or the shaft's point at ``r_mm``) never moves across the shaft toward
        theta by :data:`MIN_TRAVEL_MM`.
    """
    d_s = _direction_s(theta_deg)
    turning = poses.turn_deg() > STILL_TURN_DEG
    if not turning:
        d_w = poses.rotations[0].apply(d_s)
        x = (poses.p_mm - poses.p_mm[0]) @ d_w
        what, d_ref = "the base", d_w
    else:
        p_ref, m_ref = poses.at(poses.t_s[0] if t_ref_s is None else t_ref_s)
        c = p_ref[0] + r_mm * m_ref[0][:, 2]
        x = np.einsum("ni,ni->n", poses.rotations.apply(d_s), poses.p_mm - c)
        what, d_ref = f"the shaft's point at r = {r_mm:.1f} mm", poses.rotations[0].apply(d_s)
    if np.ptp(x) < MIN_TRAVEL_MM:
        raise SpaceError(f"{poses.source}: {what} never moves across the shaft toward "
                         f"theta {theta_deg:.1f} deg (it travels {np.ptp(x):.2f} mm that way, "
                         f"less than {MIN_TRAVEL_MM:g} mm): GM has no travel to work from")
    return stage_log_from_arrays(poses.t_s, x, source=f"{poses.source} (travel toward theta)",
                                 max_gap_s=MAX_GAP_S, first_row=2,
                                 motion_mm=_motion(poses, x, d_ref, turning, reach_mm))


def _check_clock(run: RunAnalysis, poses: PoseLog) -> None:
    """Refuse an offset estimated from pauses that explain too little of the signals."""
    if run.offset_estimated and run.paused and not run.offset_score >= MIN_CLOCK_SCORE:
        raise SpaceError(f"{poses.source}: a clock that cannot be aligned: at the best offset "
                         f"({run.offset_s:+.3f} s) the base's pauses explain "
                         f"{run.offset_score:.2f} of the signals (less than "
                         f"{MIN_CLOCK_SCORE:g}); give it with --offset-s")


def _run_medians(cols: dict) -> tuple[float, float]:
    """The run's r_GM and r_MF, less dz (the calibration's r is from the base pushed back
    by dz, the travel's from S's origin): medians where phi >= 2 CONTACT_PHI_DEG (GM's
    travel is short against its onset's error below), else wherever there is one."""
    phi = np.asarray(cols["phi_deg"], float)
    dz = np.asarray(cols["dz_mm"], float)
    out = []
    for name in ("r_gm_mm", "r_mf_mm"):
        v = np.asarray(cols[name], float) - dz
        use = np.isfinite(v) & (phi >= 2.0 * CONTACT_PHI_DEG)
        use = use if use.any() else np.isfinite(v)
        out.append(float(np.median(v[use])) if use.any() else math.nan)
    return tuple(out)


def _solve_r(seen: list, r_mf: float) -> float:
    """The next r: MF's (less dz) where the run has one, else GM's self-consistent root
    (r_GM(r) = r, r_GM a line through the last two passes; a fixed-point step first).

    A base turning about itself tilts the plate by about its own turn whatever r is: r_GM
    follows the r of the travel (slope 0.65-0.95 on the simulator's whisks, pivots 0-30
    mm behind the base), and its model's bias of +0.1-0.9 mm at the true r puts its root
    1-6 mm out; MF's run median, from dz, is within 2.4 mm there (tuning seeds 0-9 of
    tests/test_space_turning.py's whisks). GM's own r_hat per frame still goes through
    the fusion at that r.
    """
    if math.isfinite(r_mf):
        return r_mf
    (r1, g1), (r2, g2) = seen[-2] if len(seen) > 1 else (math.nan, math.nan), seen[-1]
    slope = (g2 - g1) / (r2 - r1) if len(seen) > 1 and r2 != r1 else math.nan
    if not (math.isfinite(slope) and slope < 1.0):
        return g2
    return r2 + (g2 - r2) / (1.0 - slope)


def _onset_pose_time(log: StageLog, run: RunAnalysis, t_ref_s: float) -> float:
    """The pose-clock time at which the travel first passes the run's contact onset."""
    if not math.isfinite(run.x_contact_mm):
        return t_ref_s
    past = np.flatnonzero(run.travel_sign * (log.x_mm - run.x_contact_mm) > 0)
    if past.size == 0 or past[0] == 0:
        return t_ref_s
    k = past[0]
    x0, x1 = log.x_mm[k - 1], log.x_mm[k]
    share = (run.x_contact_mm - x0) / (x1 - x0) if x1 != x0 else 1.0
    return float(log.t_s[k - 1] + share * (log.t_s[k] - log.t_s[k - 1]))


def _turning_rows(signals: dict, poses: PoseLog, calib: Calibration, offset_s, mode: str,
                  theta: float) -> tuple[dict, RunAnalysis]:  # fmt: skip
    """contact_rows on the travel at r, r solved for (:func:`_solve_r`) from r = l_w / 2,
    the onset's pose re-read each pass; the clock is estimated on the first pass and kept."""
    r, t_ref, first, seen = 0.5 * calib.l_w_mm, float(poses.t_s[0]), None, []
    for _ in range(R_STEPS):
        log = travel_log(poses, theta, r, t_ref, calib.l_w_mm)
        cols, run = contact_rows(signals, log, calib, offset_s, mode)
        if first is None:
            _check_clock(run, poses)
            first, offset_s = run, run.offset_s
        t_ref = _onset_pose_time(log, run, t_ref)
        r_gm, r_mf = _run_medians(cols)
        if not (math.isfinite(r_gm) or math.isfinite(r_mf)):
            raise SpaceError(f"{poses.source}: no row has a contact estimate on the turning "
                             f"base's travel at r = {r:.1f} mm: its contact distance is unknown")
        seen.append((r, r_gm))
        new = float(np.clip(_solve_r(seen, r_mf), 0.1 * calib.l_w_mm, calib.l_w_mm))
        if abs(new - r) < R_TOL_MM:
            break
        r = new
    if abs(new - r) > R_SETTLE_MM:
        raise SpaceError(f"{poses.source}: the turning base's contact distance does not settle "
                         f"(r = {r:.1f} mm, then {new:.1f} mm after {R_STEPS} passes): a "
                         "contact that slides or is lost cannot be placed")
    return cols, replace(run, offset_estimated=first.offset_estimated,
                         offset_score=first.offset_score, offset_se_s=first.offset_se_s)


def contact_rows_in_space(signals: dict, poses: PoseLog, calib: Calibration,
                          offset_s: float | None = None, mode: str = "frame"
                          ) -> tuple[dict, RunAnalysis, float]:  # fmt: skip
    """The contact table of a run whose base moves in space, with :data:`WORLD_COLUMNS`.

    ``x_mm`` is the travel along theta (the base's from its first pose; for a base that
    turns, the shaft's point's at the solved r from first contact) and ``dx_mm`` the travel
    since first contact; ``offset_s`` is the pose clock's (t_camera = t_pose + offset),
    estimated from the base's 3-D pauses (or motion) unless given. Returns the columns, the
    run's analysis and the pressing direction theta (deg).

    Raises
    ------
    SpaceError
        No trusted row in contact (theta unknown), a clock that cannot be aligned, a turning
        base whose r does not settle, or see :func:`travel_log`.
    """
    theta = pressing_theta_deg(signals)
    if not math.isfinite(theta):
        raise SpaceError(f"{signals.get('source', '<signals>')}: no trusted row with phi >= "
                         f"{CONTACT_PHI_DEG:g} deg: the direction the base pressed in is "
                         "unknown")  # fmt: skip
    if poses.turn_deg() > STILL_TURN_DEG:
        cols, run = _turning_rows(signals, poses, calib, offset_s, mode, theta)
    else:
        cols, run = contact_rows(signals, travel_log(poses, theta, reach_mm=calib.l_w_mm),
                                 calib, offset_s, mode)  # fmt: skip
        _check_clock(run, poses)
        cols = with_whole_contact(cols, run, calib, mode)
    return placed_in_world(cols, run, poses, theta), run, theta


def with_whole_contact(cols: dict, run: RunAnalysis, calib: Calibration, mode: str) -> dict:
    """The contact table with r_hat_mm (and r_hat_pause_mm, eq. 12's point) from the whole
    contact's travel: its slide along a smooth object where
    :func:`~camwhisker.contact.slide.fit_slide` takes it, else its stuck start
    (:func:`~camwhisker.contact.face.fit_stuck`) and the face it is then dragged along
    where :func:`~camwhisker.contact.face.fit_face` takes it; the table as it was
    elsewhere. GM, MF and the fusion's columns stay theirs."""
    contact = np.isfinite(np.asarray(cols["dx_mm"], float))
    x = run.travel_sign * np.asarray(cols["x_mm"], float)
    phi = np.asarray(cols["phi_deg"], float)
    if mode == "pause":
        phi_at, dz_at = cols["phi_pause_deg"], cols["dz_pause_mm"]
    else:
        t = np.asarray(cols["t_s"], float)
        h = smooth_half_frames(float(np.median(np.diff(t))) if t.size > 1 else 0.0)
        phi_at, dz_at = local_line(phi, h), local_line(np.asarray(cols["dz_mm"], float), h)
    phi_at = np.asarray(phi_at, float)
    slide = fit_slide(calib.gm, x[contact], phi[contact])
    got = None
    if slide is None or not slide.taken:
        got = _stuck_then_face(cols, run, calib, x, phi_at, contact)
        if got is None:
            return cols
        if _slide_nearer_mf(cols, slide, phi_at, got):  # a shallow slide: MF says which
            got = None
    rows, r, r_pause = got or (contact, slide.r_mm(phi_at), slide.r_mm(cols["phi_pause_deg"]))
    out = dict(cols)
    out["r_hat_mm"] = np.where(np.isfinite(cols["r_hat_mm"]) & rows, r, cols["r_hat_mm"])
    out["x_hat_mm"], out["y_hat_mm"] = reconstruct(cols["x_mm"], out["r_hat_mm"], phi_at, dz_at,
                                                   run.travel_sign, calib.gm, calib.bend)
    pause = np.asarray(cols["r_hat_pause_mm"], float)
    out["r_hat_pause_mm"] = np.where(np.isfinite(pause) & rows, r_pause, pause)
    return out


def _slide_nearer_mf(cols: dict, slide, phi_at, got) -> bool:
    """Whether a slide toward the base that fits the travel to the noise, though not 1.5x
    better than one r, lies nearer MF's r than the stuck start and face do, over their rows."""
    if slide is None or slide.a_mm_per_deg >= 0.0 or slide.rms_mm > MAX_RMS_MM:
        return False
    rows, r, _ = got
    r_mf = np.asarray(cols["r_mf_mm"], float)[rows]
    s_mf = np.asarray(cols["sigma_mf_mm"], float)[rows]
    return mf_cost(slide.r_mm(phi_at[rows]), r_mf, s_mf) < mf_cost(r[rows], r_mf, s_mf)


def _stuck_then_face(cols: dict, run: RunAnalysis, calib: Calibration, x, phi_at, contact):
    """The rows a stuck start and the face after it place, and their r (frame, pause); None
    where the contact has no stuck start."""
    phi = np.asarray(cols["phi_deg"], float)
    stuck = fit_stuck(calib.gm, x[contact], phi[contact])
    if stuck is None:
        return None
    dx = np.asarray(cols["dx_mm"], float)
    after = np.arange(contact.size) > np.flatnonzero(contact)[stuck.last]
    rows = contact & ~after
    settled = rows & (dx >= ONSET_DX_MM) & np.isfinite(cols["r_gm_mm"])
    if not settled.any():  # the stretch never left the onset: GM places none of it
        return None
    y0 = stuck_y0(np.asarray(cols["r_gm_mm"], float)[settled], dx[settled])
    r = r_pause = stuck_r(y0, dx)
    dragged = contact & after
    x_e = run.travel_sign * run.x_contact_mm
    face = fit_face(calib.gm, x_e, y0, x[dragged], phi_at[dragged],
                    np.asarray(cols["r_mf_mm"], float)[dragged],
                    np.asarray(cols["sigma_mf_mm"], float)[dragged])
    if face is not None and face.taken:
        rows = contact
        on_face = face_r(calib.gm, x_e, y0, face.beta_deg, x, phi_at)
        on_face_pause = face_r(calib.gm, x_e, y0, face.beta_deg, x, cols["phi_pause_deg"])
        r, r_pause = np.where(after, on_face, r), np.where(after, on_face_pause, r_pause)
    return rows, r, r_pause


def placed_in_world(cols: dict, run: RunAnalysis, poses: PoseLog, theta: float) -> dict:
    """The contact table with eq. 12's point and the normal placed in W by each frame's pose."""
    p, m = poses.at(np.asarray(cols["t_s"], float) - run.offset_s)
    d_s = _direction_s(theta)
    lateral = np.asarray(cols["x_hat_mm"], float) - np.asarray(cols["x_mm"], float)
    # Eq. 12's point: across the shaft along theta (behind the base), along it on z_S.
    local = lateral[:, None] * d_s + np.asarray(cols["y_hat_mm"], float)[:, None] * [0, 0, 1]
    point = p + np.einsum("nij,nj->ni", m, local)
    normal = np.einsum("nij,j->ni", m, -d_s)
    normal[~np.isfinite(point).all(axis=1)] = np.nan
    shaft = m[:, :, 2]
    world = dict(zip(WORLD_COLUMNS + BASE_COLUMNS, [*point.T, *normal.T, *p.T, *shaft.T],
                     strict=True))  # fmt: skip
    n = len(CONTACT_COLUMNS)
    names = list(cols)
    return {**{k: cols[k] for k in names[:n]}, **world, **{k: cols[k] for k in names[n:]}}
