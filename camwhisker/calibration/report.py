"""The outputs of calibrate-sensor: the fitted sensor file and its report beside it.

For ``BUILD.toml``::

    BUILD.toml          the fitted sensor file (only keys the sensor file knows)
    BUILD.report.json   every parameter's nominal and fitted value, SE (and the
                        SE from the data alone, ``se_data``), held or fitted;
                        residual RMS per point and per frame; each video's
                        corners' offsets at rest; frames used; phi's SE
                        at 20 deg of tilt read with the fitted file (from the
                        fitted parameters' covariance; held ones count as exact);
                        dz's scale: its gain's relative SE from the sweep, and
                        with known dz steps, the gain they measured;
                        warnings; version, inputs, command
    BUILD.report.png    residuals per point and per frame, parameter shifts in SE

All three are written atomically.
"""

from __future__ import annotations

import datetime as _dt
import math
from pathlib import Path

import numpy as np

from camwhisker import __version__
from camwhisker.calibration.adjust import tolerances
from camwhisker.calibration.sweep import SensorFit
from camwhisker.files import jsonfile
from camwhisker.files.atomic import atomic_write_text
from camwhisker.files.jsonfile import number
from camwhisker.sensor.file import Sensor, dump_sensor, sensor_to_dict
from camwhisker.sensor.model import GEOMETRY_NAMES, POINT_NAMES, geometry_vector

__all__ = ["report_paths", "calibration_record", "write_sensor_fit", "plot_calibration"]


def report_paths(out_toml: str | Path) -> dict[str, Path]:
    out = Path(out_toml)
    stem = out.with_suffix("")
    return {
        "sensor": out,
        "json": stem.with_name(stem.name + ".report.json"),
        "png": stem.with_name(stem.name + ".report.png"),
    }



def _why_held(cal: SensorFit, name: str) -> str:
    if name == "plate.rod_diameter_mm":
        if cal.rim_frames:
            blur = (f"the edge's blur of {cal.rim_blur_px:.2f} px taken out"
                    if math.isfinite(cal.rim_blur_px) else "the edge's blur not measured")
            return (f"measured from the tip's edge in {cal.rim_frames} tilted frames (the rim "
                    f"scaled by {1 + cal.rim_scale:.4f} from the round before, {blur})")
        if math.isfinite(cal.tip_radius_px):
            return f"measured from the tip's radius at rest ({cal.tip_radius_px:.2f} px)"
    return cal.adjustment.held.get(name, "")


def calibration_record(cal: SensorFit, nominal: Sensor, inputs: dict, command: str) -> dict:
    """The report's content (see the module notes)."""
    adj = cal.adjustment
    nominal_g, tol = geometry_vector(nominal), tolerances(nominal)
    params = [
        {"name": name, "nominal": number(nominal_g[i]), "fitted": number(adj.value[i]),
         "se": number(adj.se[i]), "se_data": number(adj.se_data[i]), "tolerance": number(tol[i]),
         "held": name in adj.held,
         "why_held": _why_held(cal, name)}
        for i, name in enumerate(GEOMETRY_NAMES)
    ]  # fmt: skip
    tracked = cal.tracked
    return {
        "camwhisker_version": __version__,
        "made_by": "camwhisker.calibration.report.write_sensor_fit",
        "created_utc": _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "command": command,
        "inputs": {**inputs, "nominal_sensor": nominal.source},
        "parameters": params,
        "residual_rms_px": {
            "sigma_per_coordinate": number(adj.sigma_px),
            "noise_per_coordinate": {
                n: number(v) for n, v in zip(POINT_NAMES, adj.noise_px, strict=True)
            },  # fmt: skip
            "per_point": {
                n: number(v) for n, v in zip(POINT_NAMES, adj.rms_per_point_px(), strict=True)
            },  # fmt: skip
            "per_frame": [number(v) for v in adj.rms_per_frame_px()],
        },
        "corner_offsets_at_rest_px": np.where(
            np.isfinite(tracked.corner_offsets_uv), tracked.corner_offsets_uv.round(3), None
        ).tolist(),
        "frames": {
            "total": len(tracked.ok),
            "used": int(adj.used.sum()),
            "rest": int(tracked.rest.sum()),
            "per_video": np.bincount(tracked.video).tolist(),
            "ok_fraction_per_round": cal.ok_fraction,
        },
        "phi_max_deg": number(adj.phi_max_deg),
        "phi_se_deg_at_20_deg": number(adj.phi_se_deg()),
        "dz_scale": {
            "se_relative_from_sweep": number(adj.dz_scale.se_sweep),
            "se_relative": number(adj.dz_scale.se),
            "steps_gain_of_sweep_fit": number(adj.dz_scale.steps_gain),
            "steps_gain_se_relative": number(adj.dz_scale.steps_gain_se),
            "summary": adj.dz_scale.text(),
        },
        "tip_radius_at_rest_px": number(cal.tip_radius_px),
        "tip_rim_scale_in_tilted_frames": number(cal.rim_scale),
        "tip_tilted_frames": cal.rim_frames,
        "tip_edge_blur_px": number(cal.rim_blur_px),
        "warnings": list(adj.warnings),
        "fitted_sensor": sensor_to_dict(adj.sensor),
    }


def plot_calibration(cal: SensorFit, nominal: Sensor, path: str | Path, how: str) -> None:
    """Residual RMS per point and per frame; each fitted parameter's shift in SE."""
    from camwhisker.files.figures import new_figure, save_figure

    adj = cal.adjustment
    fig, axes = new_figure((7.5, 11.0), nrows=3, ncols=1,
                           gridspec_kw={"height_ratios": (1.0, 1.0, 2.2)})
    ax = axes[0]
    ax.bar(range(len(POINT_NAMES)), adj.rms_per_point_px(), color="C0")
    ax.set_xticks(range(len(POINT_NAMES)), POINT_NAMES, rotation=45, ha="right", fontsize=7)
    ax.set_ylabel("residual RMS (px)")
    ax.set_title(f"per point (sigma {adj.sigma_px:.3f} px per coordinate)", fontsize=9)
    ax = axes[1]
    ax.plot(adj.rms_per_frame_px(), ".", ms=3, color="C0")
    ax.set_xlabel("frame (videos concatenated)")
    ax.set_ylabel("residual RMS (px)")
    ax.set_title(f"per frame ({int(adj.used.sum())} of {len(adj.used)} used)", fontsize=9)
    ax = axes[2]
    free = np.flatnonzero(np.isfinite(adj.se))
    shift = (adj.value - geometry_vector(nominal))[free] / adj.se[free]
    far = np.abs(shift) > 3
    for mask, colour, label in ((~far, "C0", "within 3 SE of nominal"),
                                (far, "C3", "more than 3 SE from nominal")):  # fmt: skip
        ax.barh(np.flatnonzero(mask), shift[mask], color=colour, label=label)
    ax.set_yticks(range(len(free)), [GEOMETRY_NAMES[i] for i in free], fontsize=7)
    ax.set_ylim(-0.7, len(free) - 0.3)
    fig.legend(fontsize=7, loc="outside lower center", ncol=2)
    ax.axvline(0, color="0.5", lw=0.8)
    ax.set_xscale("symlog", linthresh=3)
    ax.set_xlabel("fitted - nominal (SE)")
    held = ", ".join(n.split(".")[1] for n in adj.held) or "none"
    ax.set_title(f"parameter shifts (phi at 20 deg read with the fit: SE "
                 f"{adj.phi_se_deg():.3f} deg)\nheld at nominal: {held}", fontsize=9)
    save_figure(fig, path, how)


def write_sensor_fit(
    cal: SensorFit, nominal: Sensor, out_toml: str | Path, inputs: dict, command: str = ""
) -> dict[str, Path]:
    """Write the fitted sensor file and its report (JSON, PNG); returns the paths by role."""
    paths = report_paths(out_toml)
    atomic_write_text(paths["sensor"], dump_sensor(cal.sensor))
    record = calibration_record(cal, nominal, inputs, command)
    atomic_write_text(paths["json"], jsonfile.dumps(record, indent=2) + "\n")
    plot_calibration(cal, nominal, paths["png"], command or "camwhisker calibrate-sensor")
    return paths
