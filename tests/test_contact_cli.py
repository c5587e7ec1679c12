"""Commands of the contact back end, end to end, and the vectorised core's degenerate inputs."""

import csv
import functools
import tomllib

import numpy as np
import pytest

from camwhisker.cli import main
from camwhisker.contact.pipeline import CONTACT_COLUMNS, estimate


@functools.cache
def simulated(tmp_root):
    """Calibration (eq.-8 runs) and compliant runs written by simulate-stage."""
    assert main(["dev", "simulate-stage", "--kind", "eq8", "--out", f"{tmp_root}/cal", "--seed",
                 "21"]) == 0
    assert main(["dev", "simulate-stage", "--kind", "compliant", "--out", f"{tmp_root}/comp",
                 "--seed", "22"]) == 0
    return tmp_root


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    return simulated(str(tmp_path_factory.mktemp("contact_cli")))


def _calibrate(root, out):
    args = ["calibrate", "--out", out, "--plots", f"{root}/figs"]
    for r in ("r22.5", "r42.5", "r60", "r90"):
        args += ["--signals", f"{root}/cal/{r}_signals.csv", "--stage", f"{root}/cal/{r}_stage.csv"]
    return main(args)


def test_simulate_calibrate_contact(root, capsys):
    calib = f"{root}/calib.toml"
    assert _calibrate(root, calib) == 0
    doc = tomllib.loads(open(calib).read())
    # Four eq.-(8) runs: C back within 2 %, offsets estimated, provenance recorded.
    assert doc["gm"]["eq8"]["c"] == pytest.approx(132.0, rel=0.02)
    assert len(doc["provenance"]["runs"]) == 4
    assert doc["provenance"]["command"].startswith("camwhisker calibrate")
    out = f"{root}/c35.csv"
    assert main(["contact", "--signals", f"{root}/comp/c35_signals.csv", "--stage",
                 f"{root}/comp/c35_stage.csv", "--calib", calib, "--out", out]) == 0
    with open(out) as fh:
        rows = list(csv.DictReader(fh))
    with open(f"{root}/comp/c35_signals.csv") as fh:
        n_signals = sum(1 for _ in fh) - 1
    assert len(rows) == n_signals
    assert list(rows[0])[: len(CONTACT_COLUMNS)] == list(CONTACT_COLUMNS)
    assert rows[0]["r_gm_mm"] == ""  # at rest: no contact, empty cell
    r_gm = np.array([float(r["r_gm_mm"]) for r in rows if r["r_gm_mm"]])
    assert r_gm.size > 500 and np.all((r_gm > 0) & (r_gm < 150))
    assert (tmp_path_png := __import__("pathlib").Path(f"{root}/figs/gm_model.png")).exists()
    assert tmp_path_png.read_bytes()[:4] == b"\x89PNG"
    printed = capsys.readouterr().out
    assert "wrote" in printed
    # Where MF starts, from the calibration's own noise (2.5-10 deg for 4 runs at the
    # paper's noise).
    floor = doc["mf"]["phi_min_deg"]
    assert 2.5 <= floor <= 10.0 and f"estimates from phi >= {floor:g} deg" in printed


def test_bad_stage_log_is_a_clean_error(root, tmp_path, capsys):
    bad = tmp_path / "bad_stage.csv"
    bad.write_text("t_s,x_mm\n0,0\n0.1,0\n0.1,1\n")
    code = main(["contact", "--signals", f"{root}/comp/c35_signals.csv", "--stage", str(bad),
                 "--calib", f"{root}/missing.toml", "--out", str(tmp_path / "c.csv")])
    err = capsys.readouterr().err
    assert code == 2
    assert "cannot read calibration" in err and "Traceback" not in err


def test_mismatched_pairs(root, tmp_path, capsys):
    code = main(["calibrate", "--signals", "a.csv", "--signals", "b.csv", "--stage", "a.csv",
                 "--out", str(tmp_path / "c.toml")])
    assert code == 2
    assert "one --stage per --signals" in capsys.readouterr().err


def test_estimate_degenerate_inputs_defined(root):
    """phi = 0, dx = 0, negative dx/phi, NaN: NaN cells, no warnings (RuntimeWarning is an
    error under pytest's configuration), and finite estimates where inputs are good."""
    from camwhisker.contact.calibrate import read_calibration

    calib_path = f"{root}/calib_degenerate.toml"
    assert _calibrate(root, calib_path) == 0
    calib = read_calibration(calib_path)
    dx = np.array([5.0, 0.0, -2.0, 5.0, np.nan, 5.0, 5.0])
    phi = np.array([0.0, 5.0, 5.0, -5.0, 5.0, np.nan, 5.0])
    dz = np.array([0.0, 0.05, 0.05, 0.05, 0.05, 0.05, np.nan])
    with np.errstate(all="raise"):
        out = estimate(calib, dx, dx, phi, dz, 1.0)
    for key in ("r_gm_mm", "z_score", "z_combined"):
        assert np.isnan(out[key][:6]).all(), key
    # Without GM (no travel, bad travel) the fused estimate is MF's, where phi is usable.
    assert np.isnan(out["r_hat_mm"][[0, 3, 5]]).all()
    assert np.array_equal(out["r_hat_mm"][[1, 2, 4]], out["r_mf_mm"][[1, 2, 4]])
    assert np.isfinite(out["r_gm_mm"][6]) and np.isnan(out["r_mf_mm"][6])
    assert out["r_hat_mm"][6] == out["r_gm_mm"][6]  # MF undefined: GM alone


def test_bench_command(capsys):
    assert main(["dev", "contact-bench", "--seed", "3", "--samples", "5000", "--speeds", ""]) == 0
    out = capsys.readouterr().out
    assert "samples/s" in out
    # Every scene at both noise levels (issue #4: the paper's and the front end's).
    assert "noise level 'paper': phi 0.22 deg, dz 0.04 mm" in out
    assert "noise level 'front-end': phi 0.05 deg, dz 0.02 mm" in out
    for kind in ("rigid", "compliant", "slide-box", "slide-circle"):
        assert out.count(f"\n{kind} ") == 2
    speed = float(out.split(" samples/s")[0].split()[-1].replace(",", ""))
    assert speed > 0


def test_command_line_parser_leaves_scipy_optimize_and_stats_unimported():
    # Every command builds the whole parser first; the contact commands' choices
    # come from the simulator, which imports GM. Importing scipy.optimize and
    # scipy.stats there cost every command ~1 s before it started (`--help` took
    # 1.7 s, now ~0.7 s). A fresh interpreter, since this one has them already.
    import subprocess
    import sys

    # Nor numba (the front end's kernels, ~0.3 s) nor scipy.spatial (~0.25 s).
    code = ("import sys, camwhisker.cli as c; c.build_parser(); "
            "print([m for m in ('scipy.optimize', 'scipy.stats', 'numba', 'scipy.spatial') "
            "if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert out.strip() == "[]"


def test_the_tracker_options_help_names_the_front_ends_defaults(capsys):
    # The help writes them out (reading them would import the kernels at start-up).
    from camwhisker.vision import FrontEndOptions

    with pytest.raises(SystemExit):
        main(["batch", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    d = FrontEndOptions()
    assert f"template (default: the front end's, {d.lk_half_px})" in text
    assert f"LK window (default: the front end's, {d.roi_margin_px})" in text
    from camwhisker.run.overlay import ARROW_SCALE

    with pytest.raises(SystemExit):
        main(["overlay", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert f"motion from rest at {ARROW_SCALE:g}x" in text
    assert f"arrows' scale (default {ARROW_SCALE:g})" in text


def _no_row_ok(src, dst):
    """A copy of a signal table with every row untrusted (ok = 0, empty pose cells),
    as batch writes it when the front end never tracked the plate."""
    with open(src) as fh:
        rows = list(csv.DictReader(fh))
    with open(dst, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        for r in rows:
            w.writerow({**r, "ok": "0", "dz_mm": "", "phi_deg": "", "theta_deg": ""})
    return len(rows)


def test_no_row_ok_is_an_error_naming_the_file(root, tmp_path, capsys):
    """Issue #21 item 4: a table with no trusted row is bad input (exit 2, the file named,
    nothing written), not an all-empty contact table with exit 0, nor a misleading
    'MF needs two radii' from calibrate."""
    bad_cal = tmp_path / "r22.5_none_ok.csv"
    n_cal = _no_row_ok(f"{root}/cal/r22.5_signals.csv", bad_cal)
    code = main(["calibrate", "--signals", str(bad_cal), "--stage", f"{root}/cal/r22.5_stage.csv",
                 "--signals", f"{root}/cal/r42.5_signals.csv", "--stage",
                 f"{root}/cal/r42.5_stage.csv", "--out", str(tmp_path / "cal.toml")])
    err = capsys.readouterr().err
    assert code == 2
    assert f"{bad_cal}: no row is ok (ok = 0 in all {n_cal} rows)" in err
    assert not (tmp_path / "cal.toml").exists()
    calib = tmp_path / "good.toml"
    assert _calibrate(root, str(calib)) == 0
    bad = tmp_path / "c35_none_ok.csv"
    n = _no_row_ok(f"{root}/comp/c35_signals.csv", bad)
    out = tmp_path / "c35_contact.csv"
    code = main(["contact", "--signals", str(bad), "--stage", f"{root}/comp/c35_stage.csv",
                 "--calib", str(calib), "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2
    assert f"{bad}: no row is ok (ok = 0 in all {n} rows)" in err and "Traceback" not in err
    assert not out.exists()


def test_fig7a_draws_the_measured_pauses_with_a_legend_entry(root, monkeypatch):
    """Issue #21 item 10: Fig. 7A's measured data are one point per calibration pause,
    named in the legend (they were dozens of boxes a few px wide, with no entry)."""
    from camwhisker.contact import plots
    from camwhisker.contact.calibrate import CalibrationRun, calibrate
    from camwhisker.contact.stage import read_stage_log
    from camwhisker.io.signals import read_signal_table

    runs = [CalibrationRun(read_signal_table(f"{root}/cal/{r}_signals.csv"),
                           read_stage_log(f"{root}/cal/{r}_stage.csv"))
            for r in ("r22.5", "r42.5", "r60", "r90")]
    calib, _, data = calibrate(runs, 150.0)
    shown = {}
    monkeypatch.setattr(plots, "save_figure", lambda fig, path, how: shown.update(fig=fig))
    plots.plot_gm_model(calib, data, "unused.png")
    ax = shown["fig"].axes[0]
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    measured = [line for line in ax.lines if line.get_label().startswith("measured")]
    n_pauses = int((np.isfinite(data["dx_mm"]) & (data["phi_deg"] >= 1.0)).sum())
    assert labels[0] == f"measured: {n_pauses} calibration pauses (known r)"
    assert len(measured) == 1 and measured[0].get_xdata().size == n_pauses
    assert not ax.patches and not any(line.get_label().startswith("_") for line in ax.lines)
