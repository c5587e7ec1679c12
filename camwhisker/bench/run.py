"""Measure every configuration on the same frames; the Pareto table and plot.

For each scene (rendered once with a fixed seed, cached), the frames are
decoded into memory (the decode's CPU time measured once per frame), and each
configuration runs on them on one core (``cv2.setNumThreads(1)``,
``torch.set_num_threads(1)``). The rest frame's detection is excluded from
the timing; everything after it (tracking and the pose fit) is included.

Speed is frames per second of process CPU time (``time.process_time``): on a
shared machine it does not count time spent waiting for the CPU, as wall time
would. Wall-clock frames/s are reported beside it. "decode incl." adds the
measured decode CPU time per frame.

Peak memory: the process's peak resident set size above its size at the
start of the configuration (Linux ``VmHWM``, reset through
``/proc/self/clear_refs``); NaN where the system does not offer it.

The error of each scene is set against its Cramér-Rao bound
(:func:`camwhisker.sim.render.bound.pose_bound`, with the scene's camera and
artefacts at :func:`~camwhisker.sim.render.bound.nominal_bound_pose`, cached).
"""

from __future__ import annotations

import io
import json
import math
import os
import shlex
import sys
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from camwhisker.bench.configs import DEFAULT, PAPER, Config
from camwhisker.bench.pareto import pareto_front
from camwhisker.bench.peers import PEERS
from camwhisker.bench.vision import SCENES, render_scene, scene_errors
from camwhisker.files.atomic import atomic_write_bytes, atomic_write_text
from camwhisker.io.sources import VideoSource
from camwhisker.sensor.model import TIP
from camwhisker.sim.render.bound import nominal_bound_pose, pose_bound
from camwhisker.vision.colour import contrast_map
from camwhisker.vision.detect import detect_features
from camwhisker.vision.pose import fit_pose
from camwhisker.vision.tracker import (
    MAX_RMS_PX,
    MIN_CORNERS,
    PHI_MIN_FOR_THETA_DEG,
    TIP_WEIGHT,
    FrontEnd,
)

__all__ = ["Scene", "SceneResult", "load_scene", "run_config", "run_benchmark", "markdown",
           "plot", "machine", "default_cache", "timing_spread"]  # fmt: skip


#: A configuration that trusts fewer than this share of the error scene's rows is
#: not eligible for the Pareto front: its RMSE over the few rows it kept says
#: little (every frame of the nominal scene can be tracked).
MIN_OK_FOR_FRONT = 0.9
#: Errors closer than this (relative) count as equal on the Pareto front: two
#: configurations that track the same points to the same pixels differ by ~1e-6
#: deg, far inside what 50 frames resolve (a paired bootstrap of the default
#: against lock_gains=True, a real difference of 5%, spans 2-8%).
ERROR_TOL = 0.01
#: Runs are repeated for timing only while one run takes less than this (s of CPU):
#: the slow peers are timed once.
REPEAT_BELOW_S = 5.0


def default_cache() -> Path:
    """Where renders and bounds are kept between runs."""
    return Path(tempfile.gettempdir()) / "camwhisker-bench"


@dataclass
class Scene:
    name: str
    frames: list
    scenario: object
    sensor: object
    decode_cpu_s_per_frame: float
    bound: dict


@dataclass
class SceneResult:
    config: str
    scene: str
    frames: int  # frames timed (all but the rest frame)
    cpu_s: float
    wall_s: float
    decode_cpu_s: float
    peak_mib: float
    ok: float
    phi_rmse_deg: float
    dz_rmse_mm: float
    theta_mae_deg: float
    phi_bound_deg: float
    dz_bound_mm: float
    cpu_s_max: float = math.nan  # the slowest of the repeated runs (cpu_s: the fastest)


def _bound(scene_name, scenario, sensor, cache: Path) -> dict:
    path = cache / f"bound-{scene_name}.json"
    if path.exists():
        return json.loads(path.read_text())
    b = pose_bound(sensor, nominal_bound_pose(), scenario.artefacts)
    atomic_write_text(path, json.dumps(b))
    return b


def load_scene(name: str, n_frames: int, cache: Path, seed: int | None = None) -> Scene:
    """Render (or reuse) a scene, decode it into memory, and get its bound."""
    seed = SCENES[name] if seed is None else seed
    rendered = render_scene(name, seed, n_frames, cache)
    cv2.setNumThreads(1)
    c0 = time.process_time()
    frames = [f.image for f in VideoSource(rendered.video)]
    decode = (time.process_time() - c0) / max(len(frames), 1)
    bound = _bound(name, rendered.scenario, rendered.sensor, cache)
    return Scene(name, frames, rendered.scenario, rendered.sensor, decode, bound)


def _rss_reset() -> float:
    """Reset the peak RSS; return the current RSS (MiB), NaN if unavailable."""
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
        return _status("VmRSS")
    except OSError:
        return math.nan


def _status(key: str) -> float:
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith(key + ":"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return math.nan


def _run_frontend(config: Config, scene: Scene):
    fe = FrontEnd(scene.sensor, config.options)
    first = fe.start(scene.frames[0])
    rows = [(first.dz_mm, first.phi_deg, first.theta_deg, first.ok)]
    t0, c0 = time.perf_counter(), time.process_time()
    for frame in scene.frames[1:]:
        r = fe.update(frame)
        if config.full_frame_map:
            contrast_map(frame, fe.rest.gains)  # Eq. (1), the whole frame
        rows.append((r.dz_mm, r.phi_deg, r.theta_deg, r.ok))
    return rows, time.perf_counter() - t0, time.process_time() - c0


def _run_detect(config: Config, scene: Scene):
    """Every frame detected afresh (the paper's per-frame segmentation), no tracking."""
    fe = FrontEnd(scene.sensor, config.options)
    first = fe.start(scene.frames[0])
    rows = [(first.dz_mm, first.phi_deg, first.theta_deg, first.ok)]
    w = np.ones(TIP + 1)
    w[TIP] = TIP_WEIGHT
    t0, c0 = time.perf_counter(), time.process_time()
    for frame in scene.frames[1:]:
        gains = fe.gains(frame)
        uv = detect_features(frame, gains, fe.model, require=()).uv
        if config.options.mode == "paper":
            # Eqs. (2)-(7), as the front end applies them.
            dz, phi, theta = fe.paper.pose_from_points(fe.rest.paper, uv)
            ok = bool(np.isfinite(phi))
        else:  # pragma: no cover - only the paper variant is configured
            fit = fit_pose(fe.model, uv, fe.rest.offsets, np.zeros(5), w, config.options.fit_shift)
            ok = bool(fit.converged and fit.rms_px <= MAX_RMS_PX)
            dz, phi, theta = fit.pose.dz_mm, fit.pose.phi_deg, fit.pose.theta_deg
        if ok and phi < PHI_MIN_FOR_THETA_DEG:
            theta = math.nan
        rows.append((dz, phi, theta, ok) if ok else (math.nan, math.nan, math.nan, False))
    return rows, time.perf_counter() - t0, time.process_time() - c0


def _run_peer(config: Config, scene: Scene):
    fe = FrontEnd(scene.sensor)
    first = fe.start(scene.frames[0])
    rest_uv = first.points_uv.copy()
    rows = [(first.dz_mm, first.phi_deg, first.theta_deg, first.ok)]
    w = np.ones(TIP + 1)
    w[TIP] = TIP_WEIGHT
    q = np.zeros(5)
    t0, c0 = time.perf_counter(), time.process_time()
    for uv in PEERS[config.peer](scene.frames[1:], scene.frames[0], rest_uv):
        with np.errstate(all="ignore"):  # a degenerate fit to lost points is flagged below
            fit = fit_pose(fe.model, uv, fe.rest.offsets, q, w, config.options.fit_shift)
        n_corners = int(fit.used[:TIP].sum()) if fit.used is not None else 0
        ok = bool(fit.converged and np.isfinite(uv[TIP]).all() and n_corners >= MIN_CORNERS
                  and fit.rms_px <= MAX_RMS_PX)  # fmt: skip
        if fit.converged:
            q = fit.q.copy()
        if ok:
            p = fit.pose
            theta = p.theta_deg if p.phi_deg >= PHI_MIN_FOR_THETA_DEG else math.nan
            rows.append((p.dz_mm, p.phi_deg, theta, True))
        else:
            rows.append((math.nan, math.nan, math.nan, False))
    return rows, time.perf_counter() - t0, time.process_time() - c0


def _same_errors(a: SceneResult, b: SceneResult) -> bool:
    x = np.array([a.frames, a.ok, a.phi_rmse_deg, a.dz_rmse_mm, a.theta_mae_deg])
    y = np.array([b.frames, b.ok, b.phi_rmse_deg, b.dz_rmse_mm, b.theta_mae_deg])
    return bool(np.array_equal(x, y, equal_nan=True))


def run_config(config: Config, scene: Scene) -> SceneResult:
    """Run one configuration on one scene's frames; its speed, memory and errors."""
    cv2.setNumThreads(1)
    base = _rss_reset()
    runner = (
        _run_peer if config.peer else _run_detect if config.detect_each_frame else _run_frontend
    )
    rows, wall, cpu = runner(config, scene)
    peak = max(_status("VmHWM") - base, 0.0)
    vals = np.array(rows, dtype=float)
    if len(vals) != len(scene.frames):
        raise RuntimeError(f"{config.name} gave {len(vals)} rows for {len(scene.frames)} frames")
    ok = vals[:, 3] > 0
    dz, phi, theta = vals[:, 0], vals[:, 1], vals[:, 2]
    ok &= np.isfinite(phi)
    e_phi, e_dz, mae, _ = scene_errors(scene.scenario.track, dz, phi, theta, ok)
    n = len(scene.frames) - 1
    return SceneResult(config.name, scene.name, n, cpu, wall, n * scene.decode_cpu_s_per_frame,
                       peak, float(ok.mean()), e_phi, e_dz, mae,
                       scene.bound["phi_deg"], scene.bound["dz_mm"])  # fmt: skip


def machine() -> dict:
    """CPU model, core count and load average now."""
    model = "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        load = os.getloadavg()
    except OSError:
        load = (math.nan,) * 3
    return {"cpu": model, "cores": os.cpu_count(), "load": load}


def run_benchmark(configs: list[Config], scenes: list[str], n_frames: int, cache: Path,
                  log=None, repeats: int = 1) -> list[SceneResult]:  # fmt: skip
    """Every configuration on every scene (the same decoded frames for all).

    With ``repeats`` > 1, the configurations whose run took under REPEAT_BELOW_S
    of CPU time are timed again, in turn (so a burst of other work on the
    machine hits them alike), and the least CPU and wall times are kept. Their
    errors must repeat exactly."""
    try:
        import torch

        torch.set_num_threads(1)
    except ImportError:  # pragma: no cover - torch is a dependency of the peers only
        pass
    cv2.setNumThreads(1)
    results = []
    for name in scenes:
        scene = load_scene(name, n_frames, cache)
        first = [run_config(config, scene) for config in configs]
        best = [replace(r, cpu_s_max=r.cpu_s) for r in first]
        for _ in range(repeats - 1):
            for i, config in enumerate(configs):
                if first[i].cpu_s > REPEAT_BELOW_S:
                    continue
                r = run_config(config, scene)
                if not _same_errors(r, first[i]):
                    raise RuntimeError(f"{config.name} did not repeat on {name}")
                best[i] = replace(best[i], cpu_s=min(best[i].cpu_s, r.cpu_s),
                                  cpu_s_max=max(best[i].cpu_s_max, r.cpu_s),
                                  wall_s=min(best[i].wall_s, r.wall_s))  # fmt: skip
        for r in best:
            if log:
                log(f"{name:>10} {r.config:<28} {r.frames / r.cpu_s:8.1f} frames/s CPU "
                    f"(repeats up to {100 * (r.cpu_s_max / r.cpu_s - 1):.0f}% slower)  "
                    f"phi RMSE {r.phi_rmse_deg:.4f} deg  ok {100 * r.ok:.0f}%")  # fmt: skip
        results += best
        del scene
    return results


@dataclass
class Summary:
    config: str
    fps_cpu: float
    fps_cpu_decode: float
    fps_wall: float
    peak_mib: float
    by_scene: dict
    on_front: bool = False


def summarise(results: list[SceneResult], configs: list[Config]) -> list[Summary]:
    """One summary per configuration: speed over all scenes, errors per scene, and
    whether it is on the Pareto front of CPU frames/s against nominal phi and dz
    RMSE (the first scene's when nominal is not run)."""
    out = []
    for c in configs:
        rs = [r for r in results if r.config == c.name]
        n = sum(r.frames for r in rs)
        cpu = sum(r.cpu_s for r in rs)
        out.append(Summary(c.name, n / cpu, n / (cpu + sum(r.decode_cpu_s for r in rs)),
                           n / sum(r.wall_s for r in rs), max(r.peak_mib for r in rs),
                           {r.scene: r for r in rs}))  # fmt: skip
    axis = error_scene(results)
    err = np.array([[s.by_scene[axis].phi_rmse_deg, s.by_scene[axis].dz_rmse_mm]
                    if _eligible(s) else [np.nan, np.nan] for s in out])  # fmt: skip
    front = pareto_front(np.array([s.fps_cpu for s in out]), err, timing_spread(results),
                         ERROR_TOL)  # fmt: skip
    for s, f in zip(out, front, strict=True):
        s.on_front = bool(f)
    return out


def timing_spread(results: list[SceneResult]) -> float:
    """The typical relative spread of CPU time between repeats of one configuration:
    the median over the repeated configurations of (slowest / fastest - 1), CPU time
    summed over the scenes; 0 without repeats. Speeds closer than this are not told
    apart."""
    spreads = []
    for name in dict.fromkeys(r.config for r in results):
        rs = [r for r in results if r.config == name]
        lo, hi = sum(r.cpu_s for r in rs), sum(r.cpu_s_max for r in rs)
        if np.isfinite(hi) and hi > lo > 0:  # equal: timed once
            spreads.append(hi / lo - 1.0)
    return float(np.median(spreads)) if spreads else 0.0


def _eligible(s: Summary) -> bool:
    return min(r.ok for r in s.by_scene.values()) >= MIN_OK_FOR_FRONT


def error_scene(results: list[SceneResult]) -> str:
    names = [r.scene for r in results]
    return "nominal" if "nominal" in names else names[0]


def _f(x, fmt):
    return "—" if not np.isfinite(x) else format(x, fmt)


def markdown(results: list[SceneResult], configs: list[Config], command: str, info: dict,
             elapsed_s: float, n_frames: int, repeats: int = 1) -> str:  # fmt: skip
    """The Pareto table, the per-scene table and how they were made."""
    summ = summarise(results, configs)
    axis = error_scene(results)
    scenes = list(dict.fromkeys(r.scene for r in results))
    by = {s.config: s for s in summ}
    lines = _how_made(results, command, info, elapsed_s, n_frames, repeats, scenes, axis)
    lines += _pareto_table(summ, axis, [s for s in scenes if s != axis])
    if DEFAULT in by:
        lines += ["", _verdict(by, axis)]
    lines += [
        "",
        "Cramér-Rao bound (sd) at dz 0.5 mm, phi 15 deg, theta 30 deg, per scene: "
        + "; ".join(
            f"{s}: phi {by[configs[0].name].by_scene[s].phi_bound_deg:.4f} deg, "
            f"dz {by[configs[0].name].by_scene[s].dz_bound_mm:.4f} mm"
            for s in scenes
        ),
    ]
    lines += _scene_table(results)
    lines += ["", "Configurations:", ""]
    lines += [f"- {c.name}: {c.note or c.options}" for c in configs]
    return "\n".join(lines) + "\n"


def _how_made(results, command, info, elapsed_s, n_frames, repeats, scenes, axis) -> list[str]:
    """The table's preamble: command, machine, frames and how the front is decided."""
    return [
        f"Command: `{command}`",
        "",
        f"Machine: {info['cpu']}, {info['cores']} cores, load average at start "
        f"{info['load'][0]:.2f} {info['load'][1]:.2f} {info['load'][2]:.2f}; "
        f"benchmark took {elapsed_s:.0f} s.",
        "",
        f"{n_frames} frames per scene (seeds {', '.join(f'{s} {SCENES.get(s)}' for s in scenes)}), "
        "MJPG; one core; the rest frame's detection excluded. frames/s are over all scenes, "
        "by process CPU time (the reported speed; wall clock beside it). "
        f"Error axes: phi RMSE and dz RMSE on {axis} (ok rows), the sensor's two "
        "outputs (the contact back end uses both). Pareto front: no other row is at "
        "least as fast (CPU, decode excluded) and at least as accurate in phi and in dz, "
        f"and better in one of the three, errors within {100 * ERROR_TOL:.0f}% and speeds within "
        f"{100 * timing_spread(results):.0f}% counting as equal (the median spread between "
        "repeats of one configuration in this run); rows with fewer than "
        f"{100 * MIN_OK_FOR_FRONT:.0f}% ok on any scene are not eligible (their RMSE covers "
        "only the rows they kept). Timing: the least CPU time of up to "
        f"{repeats} runs, the configurations in turn (those under {REPEAT_BELOW_S:.0f} s of "
        "CPU a run are repeated); the errors repeat exactly. Peak extra RSS: above the RSS "
        "at the configuration's start (the first configuration of a scene carries the "
        "allocations the later ones reuse).",
        "",
    ]


def _pareto_table(summ: list[Summary], axis: str, others: list[str]) -> list[str]:
    """One row per configuration: speed, errors on ``axis`` and on the ``others`` scenes."""
    head = (
        f"| configuration | Pareto front | frames/s CPU | frames/s CPU, decode incl. "
        f"| frames/s wall | peak extra RSS (MiB) | {axis} phi RMSE (deg) | phi / CRB "
        f"| dz RMSE (mm) | dz / CRB | theta MAE (deg) | ok |"
        + "".join(f" {s} phi RMSE (deg) | {s} phi / CRB | {s} ok |" for s in others)
    )
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for s in summ:
        a = s.by_scene[axis]
        mark = "**yes**" if s.on_front else ("no" if _eligible(s) else "no (ok < 90%)")
        row = (
            f"| {s.config} | {mark} | {s.fps_cpu:.1f} "
            f"| {s.fps_cpu_decode:.1f} | {s.fps_wall:.1f} | {_f(s.peak_mib, '.1f')} "
            f"| {_f(a.phi_rmse_deg, '.4f')} | {_f(a.phi_rmse_deg / a.phi_bound_deg, '.1f')} "
            f"| {_f(a.dz_rmse_mm, '.4f')} | {_f(a.dz_rmse_mm / a.dz_bound_mm, '.1f')} "
            f"| {_f(a.theta_mae_deg, '.3f')} | {100 * a.ok:.0f}% |"
        )
        for o in others:
            r = s.by_scene[o]
            row += (
                f" {_f(r.phi_rmse_deg, '.4f')} | {_f(r.phi_rmse_deg / r.phi_bound_deg, '.1f')}"
                f" | {100 * r.ok:.0f}% |"
            )
        lines.append(row)
    return lines


def _verdict(by: dict, axis: str) -> str:
    """Whether the default is on the front, and how it compares with the paper's pipeline."""
    d = by[DEFAULT]
    verdict = f"The default {'is' if d.on_front else 'is NOT'} on the Pareto front."
    if PAPER in by:
        p = by[PAPER]
        ratio = d.fps_cpu / p.fps_cpu
        better = d.by_scene[axis].phi_rmse_deg < p.by_scene[axis].phi_rmse_deg
        verdict += (
            f" It runs {ratio:.1f}x the CPU frames/s of the paper-literal pipeline, "
            f"with {'lower' if better else 'NOT lower'} {axis} phi RMSE."
        )
    return verdict


def _scene_table(results: list[SceneResult]) -> list[str]:
    """One row per scene and configuration."""
    lines = [
        "",
        "Per scene:",
        "",
        "| scene | configuration | frames | frames/s CPU | frames/s wall | ok "
        "| phi RMSE (deg) | dz RMSE (mm) | theta MAE (deg) |",
        "|" + "---|" * 9,
    ]
    for r in results:
        lines.append(
            f"| {r.scene} | {r.config} | {r.frames} | {r.frames / r.cpu_s:.1f} "
            f"| {r.frames / r.wall_s:.1f} | {100 * r.ok:.0f}% "
            f"| {_f(r.phi_rmse_deg, '.4f')} | {_f(r.dz_rmse_mm, '.4f')} "
            f"| {_f(r.theta_mae_deg, '.3f')} |"
        )
    return lines


def plot(results: list[SceneResult], configs: list[Config], path: Path) -> Path:
    """frames/s (CPU) against nominal phi RMSE and against dz RMSE.

    Top row: every configuration, log axes. Bottom row: the front end's own
    configurations (no peer, not the paper's equations), linear axes, where the
    Pareto front is decided. Points carry their row number in the table; the
    key beside the plot names them. The rows on the Pareto front (of all three
    axes) are red.
    """
    from matplotlib.figure import Figure

    summ = summarise(results, configs)
    axis = error_scene(results)
    by_name = {c.name: c for c in configs}
    number = {s.config: k + 1 for k, s in enumerate(summ)}
    own = [s for s in summ if by_name[s.config].peer is None
           and by_name[s.config].options.mode == "model"]  # fmt: skip
    fig = Figure(figsize=(15, 10))
    axes = fig.subplots(2, 2, sharey="row")
    errors = (("phi_rmse_deg", "phi RMSE (deg)"), ("dz_rmse_mm", "dz RMSE (mm)"))
    for row, (rows, log) in enumerate(((summ, True), (own, False))):
        for ax, (key, label) in zip(axes[row], errors, strict=True):
            for s in rows:
                err = getattr(s.by_scene[axis], key)
                if not (np.isfinite(err) and err > 0):
                    continue
                ax.scatter(err, s.fps_cpu, c="C3" if s.on_front else "C0", zorder=3)
                ax.annotate(str(number[s.config]), (err, s.fps_cpu), textcoords="offset points",
                            xytext=(4, 3), fontsize=8)  # fmt: skip
            if log:
                ax.set_xscale("log")
                ax.set_yscale("log")
            ax.set_xlabel(f"{label} on {axis}" + ("" if log else ", the front end's own"))
            ax.grid(True, which="both", alpha=0.3)
        axes[row, 0].set_ylabel("frames/s (one core, CPU time, decode excluded)")
    axes[0, 0].scatter([], [], c="C3", label="on the Pareto front (speed, phi, dz)")
    axes[0, 0].scatter([], [], c="C0", label="dominated or < 90% ok")
    axes[0, 0].legend(fontsize=8, loc="lower left")
    key = "\n".join(f"{number[s.config]:>2}  {s.config}" for s in summ)
    fig.text(0.77, 0.5, key, fontsize=8, family="monospace", va="center")
    fig.tight_layout(rect=(0, 0, 0.76, 1))
    path = Path(path)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=120)
    atomic_write_bytes(path, buf.getvalue())
    return path


def main(argv: list[str] | None, out: Path, plot_path: Path | None, n_frames: int,
         scenes: list[str], configs: list[Config], cache: Path, log=None,
         repeats: int = 1) -> str:  # fmt: skip
    """Run, write the Markdown to ``out`` (and the plot); return the Markdown."""
    info = machine()
    command = "camwhisker " + shlex.join(sys.argv[1:] if argv is None else argv)
    t0 = time.perf_counter()
    results = run_benchmark(configs, scenes, n_frames, cache, log, repeats)
    text = markdown(results, configs, command, info, time.perf_counter() - t0, n_frames, repeats)
    atomic_write_text(out, text)
    if plot_path is not None:
        plot(results, configs, plot_path)
    return text
