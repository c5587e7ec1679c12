"""Texture resolution: the smallest gap and amplitude resolved to within 10 %, per frame rate
and sliding speed, on simulated runs (``camwhisker dev texture-bench``).

Each cell simulates (:func:`camwhisker.sim.mechanics.texture.simulate_texture`, the front end's
noise) and estimates (:func:`camwhisker.percept.texture.estimate_texture`) one texture per
seed. A gap counts as resolved at a frame rate and speed where every seed's estimate lies
within :data:`TOLERANCE` of it, and so does every larger gap of the grid (likewise the
amplitude). Ridges :data:`AMPLITUDE_REF_MM` high for the gaps; :data:`GAP_REF_MM` apart for
the amplitudes. A *wrong number* is an estimate given (not a limit) more than
:data:`TOLERANCE` off.

Seeds 0-9 were used to choose the estimator's constants; the default seeds 1000-1002 are
kept apart from them.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from camwhisker.bench.seeds import seed_list
from camwhisker.percept.texture import estimate_texture
from camwhisker.sim.mechanics.texture import (
    FRAME_RATES,
    TextureProtocol,
    TextureSurface,
    simulate_texture,
)
from camwhisker.sim.mechanics.whisker import WhiskerMechanics

__all__ = ["GAPS_MM", "AMPLITUDES_MM", "SPEEDS_MM_S", "run_cell", "resolution_table",
           "coverage", "main"]

TOLERANCE = 0.10
SPEEDS_MM_S = (1.0, 3.0, 10.0)
# The ranges: gaps 0.2-5 mm, amplitudes 0.02-0.5 mm.
GAPS_MM = (0.2, 0.3, 0.5, 0.7, 1.0, 1.5, 2.0, 3.0, 5.0)
AMPLITUDES_MM = (0.02, 0.03, 0.05, 0.07, 0.1, 0.15, 0.2, 0.3, 0.5)
AMPLITUDE_REF_MM = 0.1
GAP_REF_MM = 5.0
SEEDS = (1000, 1001, 1002)


def run_cell(gap_mm, amplitude_mm, speed_mm_s, fps, seed) -> dict:
    """One simulated run and its estimate, with the relative errors (None: a limit given)."""
    protocol = TextureProtocol(speed_mm_s=speed_mm_s, fps=fps)
    run = simulate_texture(TextureSurface(gap_mm, amplitude_mm), protocol, seed)
    signals = dict(run.signals, ok=run.signals["ok"].astype(bool), source=f"seed {seed}")
    est = estimate_texture(signals, speed_mm_s, WhiskerMechanics().length_mm)
    row = {"gap_mm": gap_mm, "amplitude_mm": amplitude_mm, "speed_mm_s": speed_mm_s,
           "fps": fps, "seed": seed, "texture_hz": speed_mm_s / gap_mm,
           "resolved": est.resolved, "gap_error": None, "amplitude_error": None,
           "gap_se": None, "amplitude_se": None,
           "gap_min_mm": est.limits["gap_min_mm"],
           "nyquist_gap_min_mm": est.limits["nyquist_gap_min_mm"],
           "amplitude_min_mm": est.limits["amplitude_min_mm"]}
    if est.resolved:
        row["gap_error"] = est.gap_mm / gap_mm - 1.0
        row["amplitude_error"] = est.amplitude_mm / amplitude_mm - 1.0
        row["gap_se"] = est.gap_se_mm / gap_mm  # relative, as the errors
        row["amplitude_se"] = est.amplitude_se_mm / amplitude_mm
    return row


def coverage(runs, key) -> dict:
    """Of the numbers given: the share within 2 and 3 standard errors of the truth and the
    RMS of error / SE (1 where the standard errors are right)."""
    z = np.array([r[f"{key}_error"] / r[f"{key}_se"] for r in runs if r["resolved"]])
    if z.size == 0:
        return {"n": 0, "within_2se": None, "within_3se": None, "z_rms": None}
    return {"n": int(z.size), "within_2se": float(np.mean(np.abs(z) <= 2.0)),
            "within_3se": float(np.mean(np.abs(z) <= 3.0)),
            "z_rms": float(np.sqrt(np.mean(z**2)))}


def format_coverage(runs) -> str:
    lines = []
    for key in ("gap", "amplitude"):
        c = coverage(runs, key)
        if c["n"]:
            lines.append(f"{key}s within 2 SE: {c['within_2se']:.0%}, within 3 SE: "
                         f"{c['within_3se']:.0%}, RMS error / SE {c['z_rms']:.2f} "
                         f"(of {c['n']} given)")
    return "\n".join(lines)


def _within(rows, key) -> bool:
    return all(r[key] is not None and abs(r[key]) <= TOLERANCE for r in rows)


def _smallest(grid, cells, key):
    """Smallest grid value from which every larger one is within tolerance (None: none is)."""
    best = None
    for value in sorted(grid, reverse=True):
        if not _within(cells[value], key):
            break
        best = value
    return best


def resolution_table(seeds=SEEDS, frame_rates=FRAME_RATES, speeds=SPEEDS_MM_S) -> tuple:
    """Rows of the resolution table and every run's row."""
    table, runs = [], []
    for fps in frame_rates:
        for v in speeds:
            by_gap = {g: [run_cell(g, AMPLITUDE_REF_MM, v, fps, s) for s in seeds]
                      for g in GAPS_MM}
            by_amp = {a: [run_cell(GAP_REF_MM, a, v, fps, s) for s in seeds]
                      for a in AMPLITUDES_MM}
            cell_runs = [r for rows in (*by_gap.values(), *by_amp.values()) for r in rows]
            runs += cell_runs
            first = cell_runs[0]
            given = [r for r in cell_runs if r["resolved"]]
            beyond = [r for r in cell_runs if r["texture_hz"] >= 0.5 * fps]
            table.append({
                "fps": fps, "speed_mm_s": v,
                "gap_min_mm": _smallest(GAPS_MM, by_gap, "gap_error"),
                "gap_min_with_amplitude_mm": _smallest(GAPS_MM, by_gap, "amplitude_error"),
                "amplitude_min_mm": _smallest(AMPLITUDES_MM, by_amp, "amplitude_error"),
                "limit_gap_mm": first["gap_min_mm"],
                "nyquist_gap_mm": first["nyquist_gap_min_mm"],
                "limit_amplitude_mm": first["amplitude_min_mm"],
                "runs": len(cell_runs), "beyond_nyquist": len(beyond),
                "beyond_nyquist_with_number": sum(r["resolved"] for r in beyond),
                "given": len(given),
                "wrong_gaps": sum(abs(r["gap_error"]) > TOLERANCE for r in given),
                "wrong_amplitudes": sum(abs(r["amplitude_error"]) > TOLERANCE for r in given),
            })
    return table, runs


def _fmt(v, digits=3):
    return "none" if v is None else f"{v:.{digits}g}"


def format_table(table, seeds) -> str:
    lines = [
        f"Texture resolution, seeds {seeds[0]}-{seeds[-1]} ({len(seeds)} per cell), "
        f"within {TOLERANCE:.0%} on every seed; gaps at amplitude {AMPLITUDE_REF_MM:g} mm, "
        f"amplitudes at gap {GAP_REF_MM:g} mm",
        "",
        "| frames/s | speed mm/s | smallest gap mm | ... with amplitude too mm | "
        "smallest amplitude mm | limit: gap (mode) mm | Nyquist gap mm | "
        "limit: amplitude mm | runs beyond Nyquist (with a number) | numbers given | "
        "wrong gaps | wrong amplitudes |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in table:
        lines.append(
            f"| {r['fps']:g} | {r['speed_mm_s']:g} | {_fmt(r['gap_min_mm'])} | "
            f"{_fmt(r['gap_min_with_amplitude_mm'])} | {_fmt(r['amplitude_min_mm'])} | "
            f"{_fmt(r['limit_gap_mm'])} | {_fmt(r['nyquist_gap_mm'])} | "
            f"{_fmt(r['limit_amplitude_mm'])} | {r['beyond_nyquist']} "
            f"({r['beyond_nyquist_with_number']}) | {r['given']} of {r['runs']} | "
            f"{r['wrong_gaps']} | {r['wrong_amplitudes']} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="camwhisker dev texture-bench", description=__doc__)
    p.add_argument("--seeds", default=f"{SEEDS[0]}-{SEEDS[-1]}", metavar="A-B",
                   help="seeds per cell, inclusive (0-9 were used for tuning)")
    p.add_argument("--out", metavar="R.json", help="also write the table and every run here")
    args = p.parse_args(argv)
    seeds = tuple(seed_list(args.seeds))
    start = time.perf_counter()
    table, runs = resolution_table(seeds)
    print(format_table(table, seeds))
    print()
    print(format_coverage(runs))
    print(f"\n{len(runs)} runs in {time.perf_counter() - start:.0f} s")
    if args.out:
        from camwhisker.files.atomic import atomic_write_text
        from camwhisker.files.jsonfile import dumps

        atomic_write_text(args.out, dumps({"table": table, "runs": runs}, indent=1) + "\n")
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
