"""Calibration: fit GM (eq. 8 and a beam alternative), sigma_GM(phi), the MF table, sigma_MF(phi).

Input: calibration runs, each a signal table plus a stage log with ``r_mm``
(the known contact distance). Output: a human-readable TOML file, with the MF
table as CSV beside it (``<stem>.mf.csv``)::

    calib = calibrate(runs, l_w_mm=150.0)
    write_calibration("calib.toml", calib)
    calib = read_calibration("calib.toml")
"""

from __future__ import annotations

import datetime as _dt
import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from camwhisker import __version__
from camwhisker.contact.fusion import MF_BIAS_FLOOR_MM, mf_bias_floor_mm
from camwhisker.contact.gm import PHI_MIN_DEG, GMFit, fit_gm, r_gm
from camwhisker.contact.mf import (
    DZ_SCALE_MM,
    MF_CURVE_STEP_DEG,
    MF_DOMAIN_RADIUS,
    MF_K,
    PHI_SCALE_DEG,
    MFTable,
    pause_dz_noise_mm,
    r_mf,
)
from camwhisker.contact.pipeline import Calibration, RunAnalysis, analyse_run
from camwhisker.contact.shape import (
    SURFACE_PHI_POWERS,
    SURFACE_R_POWERS,
    BendCorrection,
    fit_bend_correction,
)
from camwhisker.contact.stage import StageLog
from camwhisker.contact.zscore import SpreadTable, spread_table
from camwhisker.files.atomic import atomic_write_text
from camwhisker.files.tables import write_csv
from camwhisker.files.tomlfile import read_toml, toml_comment, toml_value

__all__ = ["MF_MAX_SPREAD_MM", "CalibrationError", "CalibrationRun", "calibrate",
           "format_calibration", "mf_phi_floor", "write_calibration", "read_calibration",
           "mf_table_path"]

# MF gives no estimate below the phi from which its scatter from noise alone (the
# calibration's pauses against the curves of their own runs) stays within this in every
# phi bin: the paper's 15 mm GM failure, which an MF with a wider scatter cannot tell
# from its own noise. Below ~5 deg (2.5 deg at the front end's noise) the axial force is
# too small for dz to tell radii apart (Table II's sigma_MF: 20-30 mm there).
MF_MAX_SPREAD_MM = 15.0


class CalibrationError(ValueError):
    """Calibration input or file that cannot be used; the message names the file and key."""


@dataclass(frozen=True)
class CalibrationRun:
    """One calibration run: its signals, its stage log (with r_mm) and their names."""

    signals: dict
    log: StageLog
    signals_source: str = "<signals>"
    offset_s: float | None = None


def calibrate(runs: list[CalibrationRun], l_w_mm: float, sensor_source: str = "<defaults>",
              command: str = "") -> tuple[Calibration, list[RunAnalysis], dict]:
    """Fit the calibration from runs with known r.

    Returns
    -------
    calib : Calibration
    analyses : list of RunAnalysis
        Per run: estimated offset, pause medians, contact onset.
    data : dict of ndarray
        The pooled pause samples used (phi_deg, dz_mm, dx_mm, r_mm, run) and
        their GM estimates (r_gm_mm).
    """
    if not runs:
        raise CalibrationError("calibration needs at least one run")
    analyses, cols = [], {k: [] for k in ("phi_deg", "dz_mm", "dx_mm", "r_mm", "run")}
    for i, run in enumerate(runs):
        if run.log.r_mm is None:
            raise CalibrationError(f"{run.log.source}: calibration stage log needs column r_mm")
        a = analyse_run(run.signals, run.log, run.offset_s)
        analyses.append(a)
        p = a.pauses
        contact = np.isfinite(a.dx_mm) & np.isfinite(p.phi_deg)
        cols["phi_deg"].append(p.phi_deg[contact])
        cols["dz_mm"].append(p.dz_mm[contact])
        cols["dx_mm"].append(a.dx_mm[contact])
        cols["r_mm"].append(p.r_mm[contact])
        cols["run"].append(np.full(int(contact.sum()), i))
    data = {k: np.concatenate(v) for k, v in cols.items()}
    try:
        gm = fit_gm(data["dx_mm"], data["phi_deg"], data["r_mm"], l_w_mm, groups=data["run"])
        data["r_gm_mm"] = r_gm(gm, data["dx_mm"], data["phi_deg"])
        gm_spread = spread_table(data["phi_deg"], data["r_mm"] - data["r_gm_mm"])
        if np.unique(data["run"]).size < 2:
            raise ValueError("MF needs runs at two or more radii (its spread is measured by "
                             "leaving one run out)")
        mf_spread = spread_table(data["phi_deg"], _mf_leave_one_run_out(data))
        table = MFTable.from_runs(data["phi_deg"], data["dz_mm"], data["r_mm"], data["run"])
        # The pauses against the curves fitted through them: the scatter the pause
        # medians' noise gives MF, without the error between calibrated radii.
        own = r_mf(table, data["phi_deg"], data["dz_mm"], domain_radius=np.inf)
        mf_noise = spread_table(data["phi_deg"], data["r_mm"] - own.r_mm)
        dz_noise = pause_dz_noise_mm(data["phi_deg"], data["dz_mm"], data["r_mm"], data["run"])
        table = replace(table, phi_min_deg=mf_phi_floor(mf_noise))
        # Each run's radius: r at its first contact, before it rolls out along the whisker.
        floor = mf_bias_floor_mm([np.min(data["r_mm"][data["run"] == i])
                                  for i in np.unique(data["run"])])
        bend = fit_bend_correction(gm, data["dx_mm"], data["phi_deg"], data["r_mm"],
                                   data["dz_mm"], data["run"])
    except ValueError as exc:
        raise CalibrationError(f"calibration from {len(runs)} run(s) failed: {exc}") from exc

    provenance = {
        "package": "camwhisker",
        "version": __version__,
        "created_utc": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "command": command,
        "sensor": sensor_source,
        "runs": [
            {"signals": r.signals_source, "stage": r.log.source, "offset_s": a.offset_s,
             "offset_estimated": a.offset_estimated, "offset_score": a.offset_score,
             "x_contact_mm": a.x_contact_mm, "pauses_used": int(np.isfinite(a.dx_mm).sum())}
            for r, a in zip(runs, analyses, strict=True)
        ],
    }
    calib = Calibration(gm=gm, gm_spread=gm_spread, mf_table=table, mf_spread=mf_spread,
                        mf_noise=mf_noise, l_w_mm=float(l_w_mm), provenance=provenance,
                        dz_noise_mm=dz_noise,
                        mf_bias_floor_mm=floor, bend=bend)
    return calib, analyses, data


def format_calibration(runs: list[CalibrationRun], analyses: list[RunAnalysis],
                       calib: Calibration) -> tuple[list[str], str | None]:
    """What a person reads after a calibration: offsets, C of eq. (8), the MF table.

    Returns the lines, and a warning when MF is left with no phi to estimate from.
    """
    lines = []
    for run, a in zip(runs, analyses, strict=True):
        how = "estimated" if a.offset_estimated else "given"
        lines.append(f"{run.log.source}: offset {a.offset_s:+.3f} s ({how}), "
                     f"{int((a.dx_mm == a.dx_mm).sum())} contact pauses")
    eq8 = calib.gm.alternatives["eq8"]
    lo, hi = eq8.ci["c"]
    lines.append(f"eq. (8): C = {eq8.params['c']:.2f} (95 % CI {lo:.2f}-{hi:.2f}), "
                 f"RMSE {eq8.rmse_mm:.2f} mm; GM model used: {calib.gm.kind} "
                 f"(RMSE {calib.gm.rmse_mm:.2f} mm)")
    bend = calib.bend
    if bend is not None:
        lines.append("eq. (12) on the bent whisker: the calibrated offset takes the GM model's "
                     "error across from {:.3f} to {:.3f} mm (sd), the shortening along from "
                     "{:.3f} to {:.3f} mm".format(*bend.offset_sd_mm, *bend.shortening_sd_mm))
    floor = calib.mf_table.phi_min_deg
    if math.isinf(floor):
        return lines, (f"MF's scatter from noise exceeds {MF_MAX_SPREAD_MM:g} mm at every phi: "
                       "MF, z_score and the fusion will be empty (calibrate with more runs, or "
                       "with less noise)")
    lines.append(f"MF: {len(calib.mf_table)} table points from {len(runs)} run(s), estimates "
                 f"from phi >= {floor:g} deg; the fusion allows MF {calib.mf_bias_floor_mm:.2f} mm "
                 "of error over a contact (2 mm for the paper's pegs, less on denser pegs)")
    if calib.dz_noise_mm is not None:
        lines.append(f"MF's noise: a pause median of dz scatters {1000 * calib.dz_noise_mm:.1f} um;"
                     " sigma_MF at a pause is MF's dr/d(dz) there times that")
    return lines, None


def _mf_leave_one_run_out(data: dict) -> np.ndarray:
    """r - r_MF per pause, each run's pauses looked up in the table of the other runs.

    A run's own curve would pass through its pauses; leaving the whole run out
    gives MF's error at a radius it was not calibrated at, as in use.
    """
    err = np.full(data["r_mm"].size, np.nan)
    cols = ("phi_deg", "dz_mm", "r_mm", "run")
    for i in np.unique(data["run"]):
        own = data["run"] == i
        others = MFTable.from_runs(*(data[k][~own] for k in cols))
        err[own] = data["r_mm"][own] - r_mf(others, data["phi_deg"][own], data["dz_mm"][own]).r_mm
    return err


def mf_phi_floor(spread: SpreadTable, max_spread_mm: float = MF_MAX_SPREAD_MM) -> float:
    """The lower edge of the lowest phi bin from which every bin's spread <= max_spread_mm,
    and never under PHI_MIN_DEG (the table's own floor: a quiet front end's spread is narrow
    down to phi 0, where an untouched whisker's noise would get an MF estimate).

    inf if the highest bin's spread is wider (MF then gives no estimate at all).
    """
    wide = np.flatnonzero(~(spread.std_mm <= max_spread_mm))
    if not wide.size:
        return max(PHI_MIN_DEG, float(spread.edges_deg[0]))
    return float(spread.edges_deg[wide[-1] + 1]) if wide[-1] + 1 < spread.std_mm.size else math.inf


def mf_table_path(calib_path: str | Path) -> Path:
    """The MF table CSV beside a calibration file: ``calib.toml`` -> ``calib.mf.csv``."""
    p = Path(calib_path)
    return p.with_name(p.stem + ".mf.csv")


def _spread_lines(name: str, s: SpreadTable, what: str) -> list[str]:
    lines = [f"[{name}]", f"# {what}: error r - r_hat per phi bin lo <= phi < hi (deg)."]
    for lo, hi, n, m, sd in s.rows():
        lines.append(f"#   {lo:5.1f} - {hi:5.1f}: n = {n:4d}  mean = {m:7.2f} mm  "
                     f"std = {sd:6.2f} mm")
    lines += [f"edges_deg = {toml_value(s.edges_deg)}", f"n = {toml_value(s.n)}",
              f"mean_mm = {toml_value(s.mean_mm)}", f"std_mm = {toml_value(s.std_mm)}", ""]
    return lines


def _gm_lines(fit: GMFit) -> list[str]:
    lines = []
    for kind, f in sorted(fit.alternatives.items()):
        lines.append(f"[gm.{kind}]")
        for key, value in f.params.items():
            lines.append(f"{key} = {toml_value(value)}")
            lo, hi = f.ci[key]
            lines.append(f"{key}_ci95 = {toml_value([lo, hi])}")
        lines += [f"rmse_mm = {toml_value(f.rmse_mm)}", f"aic = {toml_value(f.aic)}",
                  f"n = {f.n}", ""]
    return lines


def _shape_lines(bend: BendCorrection | None) -> list[str]:
    if bend is None:
        return ["[shape]", "# No bend correction: too few calibration pauses or radii.", ""]
    n_r = bend.offset_coef.shape[1]
    return [
        "[shape]",
        "# Eq. (12) on the bent whisker: what the GM model read backwards misses, as",
        "# sum coef[i][j] (phi / phi_max_deg)^phi_powers[i] (r / r_max_mm)^r_powers[j],",
        "# phi and r clipped to the calibrated box: offset_coef adds to the contact's offset",
        "# d across the base's line, shortening_coef comes off sqrt(r^2 - d^2) along it.",
        f"phi_powers = {toml_value(list(SURFACE_PHI_POWERS))}",
        f"r_powers = {toml_value(list(SURFACE_R_POWERS[:n_r]))}",
        f"offset_coef = {toml_value([list(row) for row in bend.offset_coef])}",
        f"shortening_coef = {toml_value([list(row) for row in bend.shortening_coef])}",
        f"phi_max_deg = {toml_value(bend.phi_max_deg)}",
        f"r_min_mm = {toml_value(bend.r_min_mm)}",
        f"r_max_mm = {toml_value(bend.r_max_mm)}",
        "# Residual sd (mm) of the calibration's pauses without and with each surface.",
        f"offset_sd_mm = {toml_value(list(bend.offset_sd_mm))}",
        f"shortening_sd_mm = {toml_value(list(bend.shortening_sd_mm))}",
        "",
    ]


def write_calibration(path: str | Path, calib: Calibration) -> None:
    """Write the TOML file and the MF table CSV beside it (both atomically)."""
    path = Path(path)
    mf_path = mf_table_path(path)
    prov = calib.provenance
    eq8 = calib.gm.alternatives.get("eq8")
    lines = [
        "# camwhisker calibration: GM (eq. 8 and a beam alternative), sigma_GM(phi), MF table.",
        toml_comment(f"Made by camwhisker {prov['version']} at {prov['created_utc']}."),
        toml_comment(f"Command: {prov.get('command', '')}"),
        toml_comment(f"MF table (phi_deg, dz_mm, r_mm): {mf_path.name}"),
    ]
    if eq8 is not None:
        lo, hi = eq8.ci["c"]
        lines.append(f"# Eq. (8) constant C = {eq8.params['c']:.2f} (95 % CI {lo:.2f} - {hi:.2f}),"
                     f" RMSE {eq8.rmse_mm:.2f} mm")
    lines += [
        "",
        "[provenance]",
        f"package = {toml_value(prov['package'])}",
        f"version = {toml_value(prov['version'])}",
        f"created_utc = {toml_value(prov['created_utc'])}",
        f"command = {toml_value(prov.get('command', ''))}",
        f"sensor = {toml_value(prov.get('sensor', ''))}",
        "",
        "[whisker]",
        f"length_mm = {toml_value(calib.l_w_mm)}",
        "",
        "[gm]",
        "# The model used for r_gm_mm: the lower AIC of eq. (8) and the beam model.",
        f"model = {toml_value(calib.gm.kind)}",
        f"phi_min_deg = {toml_value(PHI_MIN_DEG)}",
        "",
        *_gm_lines(calib.gm),
        *_spread_lines("gm_spread", calib.gm_spread, "sigma_GM"),
        *_shape_lines(calib.bend),
        "[mf]",
        f"table = {toml_value(mf_path.name)}",
        f"k = {MF_K}",
        f"phi_scale_deg = {toml_value(PHI_SCALE_DEG)}",
        f"dz_scale_mm = {toml_value(DZ_SCALE_MM)}",
        f"domain_radius = {toml_value(MF_DOMAIN_RADIUS)}",
        "# Points every curve_step_deg along each run's fitted r(phi), dz from one surface.",
        f"curve_step_deg = {toml_value(MF_CURVE_STEP_DEG)}",
        f"rows = {len(calib.mf_table)}",
        f"# No MF estimate below phi_min_deg: MF's noise scatter > {MF_MAX_SPREAD_MM:g} mm.",
        f"phi_min_deg = {toml_value(calib.mf_table.phi_min_deg)}",
        "# MF's error over a contact between calibrated radii that the fusion allows a good",
        "# GM: 2 mm for the paper's pegs, scaled by the widest relative gap between radii.",
        f"bias_floor_mm = {toml_value(calib.mf_bias_floor_mm)}",
        *([] if calib.dz_noise_mm is None else [
            "# Noise of a pause median of dz: sigma_MF at a pause is MF's dr/d(dz) there times",
            "# this, with MF's error between radii (mf_spread beyond mf_noise).",
            f"dz_noise_mm = {toml_value(calib.dz_noise_mm)}"]),
        "",
        *_spread_lines("mf_spread", calib.mf_spread, "sigma_MF (leave one run out)"),
        *_spread_lines("mf_noise", calib.mf_noise,
                       "MF's scatter from noise alone (pauses against their own runs' curves),"
                       " for the fusion"),
    ]
    for run in prov.get("runs", []):
        lines.append("[[provenance.runs]]")
        lines += [f"{k} = {toml_value(v)}" for k, v in run.items()]
        lines.append("")
    write_csv(mf_path, {"phi_deg": calib.mf_table.phi_deg, "dz_mm": calib.mf_table.dz_mm,
                        "r_mm": calib.mf_table.r_mm}, digits=9)
    atomic_write_text(path, "\n".join(lines) + "\n")


def _get(table: dict, key: str, where: str):
    if key not in table:
        raise CalibrationError(f"{where}: missing key {key!r}")
    return table[key]


def _spread_from(doc: dict, name: str, path: Path) -> SpreadTable:
    t = _get(doc, name, str(path))
    where = f"{path}: [{name}]"
    return SpreadTable(np.asarray(_get(t, "edges_deg", where), float),
                       np.asarray(_get(t, "n", where), int),
                       np.asarray(_get(t, "mean_mm", where), float),
                       np.asarray(_get(t, "std_mm", where), float))


def _bend_from(doc: dict, path: Path) -> BendCorrection | None:
    """The [shape] section's correction; None without one (files from before it: eq. 12 then
    takes the GM model's bend alone)."""
    t = doc.get("shape", {})
    if "offset_coef" not in t:
        return None
    where = f"{path}: [shape]"
    keys = ("phi_powers", "r_powers", "offset_coef", "shortening_coef", "phi_max_deg",
            "r_min_mm", "r_max_mm")
    phi_powers, r_powers, *values = (_get(t, k, where) for k in keys)
    try:
        offset, shortening = (np.asarray(v, float) for v in values[:2])
        box = [float(v) for v in values[2:]]
    except (TypeError, ValueError) as exc:
        raise CalibrationError(f"{where}: bend correction is not numbers ({exc})") from exc
    n_r = offset.shape[1] if offset.ndim == 2 else 0
    shape_ok = (offset.ndim == 2 and offset.shape == shortening.shape
                and offset.shape[0] == len(SURFACE_PHI_POWERS) and n_r >= 1
                and phi_powers == list(SURFACE_PHI_POWERS)
                and r_powers == list(SURFACE_R_POWERS[:n_r]))
    if not (shape_ok and np.all(np.isfinite(offset)) and np.all(np.isfinite(shortening))
            and np.all(np.isfinite(box)) and box[0] > 0 and 0 < box[1] <= box[2]):
        raise CalibrationError(
            f"{where}: offset_coef and shortening_coef must be {len(SURFACE_PHI_POWERS)} x n "
            f"tables of numbers for phi_powers = {list(SURFACE_PHI_POWERS)} and the first n "
            f"of r_powers = {list(SURFACE_R_POWERS)}, with phi_max_deg > 0 and "
            "0 < r_min_mm <= r_max_mm")
    sds = [tuple(t.get(k, (math.nan, math.nan))) for k in ("offset_sd_mm", "shortening_sd_mm")]
    return BendCorrection(offset, shortening, *box, *sds)


def read_calibration(path: str | Path) -> Calibration:
    """Read a calibration file written by :func:`write_calibration`.

    Raises
    ------
    CalibrationError
        Unreadable file, bad TOML, a missing key (named), or a bad MF table.
    """
    path = Path(path)
    doc = read_toml(path, "calibration", CalibrationError)
    l_w = float(_get(_get(doc, "whisker", str(path)), "length_mm", f"{path}: [whisker]"))
    gm_doc = _get(doc, "gm", str(path))
    kind = _get(gm_doc, "model", f"{path}: [gm]")
    fits = {}
    for k in ("eq8", "beam"):
        if k not in gm_doc:
            continue
        t = gm_doc[k]
        names = ("c",) if k == "eq8" else ("beta_per_mm", "kappa_per_mm")
        where = f"{path}: [gm.{k}]"
        fits[k] = GMFit(kind=k, params={n: float(_get(t, n, where)) for n in names},
                        ci={n: tuple(_get(t, n + "_ci95", where)) for n in names},
                        rmse_mm=float(t.get("rmse_mm", math.nan)),
                        aic=float(t.get("aic", math.nan)), n=int(t.get("n", 0)), l_w_mm=l_w)
    if kind not in fits:
        raise CalibrationError(f"{path}: [gm] model = {kind!r} but there is no [gm.{kind}]")
    gm = GMFit(**{**fits[kind].__dict__, "alternatives": fits})
    mf_doc = _get(doc, "mf", str(path))
    mf_path = path.with_name(_get(mf_doc, "table", f"{path}: [mf]"))
    try:
        arr = np.genfromtxt(mf_path, delimiter=",", names=True)
    except (OSError, ValueError) as exc:
        raise CalibrationError(f"{mf_path}: cannot read MF table ({exc})") from exc
    phi_min = float(_get(mf_doc, "phi_min_deg", f"{path}: [mf]"))
    try:
        table = MFTable.build(np.atleast_1d(arr["phi_deg"]), np.atleast_1d(arr["dz_mm"]),
                              np.atleast_1d(arr["r_mm"]), phi_min)
    except (ValueError, KeyError) as exc:
        raise CalibrationError(f"{mf_path}: bad MF table ({exc})") from exc
    # Files from before the key: made on the paper's pegs, whose floor is the default.
    floor = float(mf_doc.get("bias_floor_mm", MF_BIAS_FLOOR_MM))
    if not (math.isfinite(floor) and floor > 0):
        raise CalibrationError(f"{path}: [mf] bias_floor_mm must be a positive number, "
                               f"got {floor}")
    # Files from before the key: sigma_MF per phi bin, as then.
    dz_noise = mf_doc.get("dz_noise_mm")
    number = isinstance(dz_noise, (int, float)) and not isinstance(dz_noise, bool)
    if dz_noise is not None and not (number and math.isfinite(dz_noise) and dz_noise > 0):
        raise CalibrationError(f"{path}: [mf] dz_noise_mm must be a positive number, "
                               f"got {dz_noise!r}")
    return Calibration(gm=gm, gm_spread=_spread_from(doc, "gm_spread", path), mf_table=table,
                       mf_spread=_spread_from(doc, "mf_spread", path),
                       mf_noise=_spread_from(doc, "mf_noise", path), l_w_mm=l_w,
                       provenance=doc.get("provenance", {}), mf_bias_floor_mm=floor,
                       bend=_bend_from(doc, path),
                       dz_noise_mm=None if dz_noise is None else float(dz_noise))
