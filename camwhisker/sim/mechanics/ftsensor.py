"""A simulated force-torque sensor under the sensor's housing: the load the springs carry.

The paper's test 2 (Sec. III-A) reads F_z with a 6-axis force-torque sensor
(ATI Nano17) while known dz steps are applied. Quasi-static, the springs carry
F_z = k_z dz and M_b = k_phi phi (:mod:`camwhisker.sensor.springs`), and so
does a sensor under the housing. :func:`simulate_force_log` samples that load
of a simulated stage run (:mod:`camwhisker.sim.mechanics.experiment`) on the
sensor's own clock, with its noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from camwhisker.io.forcelog import ForceLog
from camwhisker.sensor.springs import Stiffness
from camwhisker.sim.mechanics.experiment import StageRun, signal_arrays_from

__all__ = ["FTSensor", "NANO17", "FORCE_KINDS", "simulate_force_log", "simulate_force_logs"]


@dataclass(frozen=True)
class FTSensor:
    """Sample rate, per-sample noise (sd) and clock-offset range of a force-torque sensor."""

    rate_hz: float = 100.0
    fz_noise_mN: float = 3.1
    mb_noise_Nmm: float = 0.0156
    offset_range_s: tuple[float, float] = (3.0, 8.0)  # |offset|, sign drawn at random


#: The experiment kinds that come with a force log: the rigid whisker of the accuracy
#: tests, whose load the suspension alone carries (test 2: F_z; test 1: M_b).
FORCE_KINDS = ("test1", "test2")

#: ATI Nano17 (SI-12-0.12 calibration): resolution 1/320 N in F_z and 1/64 N mm in torque,
#: taken as the per-sample noise.
NANO17 = FTSensor()


def simulate_force_log(run: StageRun, stiffness: Stiffness, rng: np.random.Generator,
                       sensor: FTSensor = NANO17) -> tuple[ForceLog, float]:
    """The force log of a run and its true clock offset (t_camera = t_force + offset_s).

    The true load follows the run's noise-free dz and phi (quasi-static, as the
    signals); the log covers the run from 1 s before to 1 s after, like the stage log.
    ``mb_Nmm`` is the magnitude of the noisy 2D moment (the sensor's Mx, My).
    """
    duration = float(run.schedule_t_s[-1])
    t_true = np.arange(-1.0, duration + 1.0, 1.0 / sensor.rate_hz)
    x = np.interp(t_true, run.schedule_t_s, run.schedule_x_mm)
    clean = signal_arrays_from(run.steps, slice(0, run.info["n_steps"] + 1), x)
    fz = stiffness.fz_mN(clean["dz_mm"]) + sensor.fz_noise_mN * rng.standard_normal(t_true.size)
    m = stiffness.mb_Nmm(clean["phi_deg"])
    mx = m + sensor.mb_noise_Nmm * rng.standard_normal(t_true.size)
    my = sensor.mb_noise_Nmm * rng.standard_normal(t_true.size)
    magnitude = rng.uniform(*sensor.offset_range_s)
    offset_s = float(magnitude if rng.random() < 0.5 else -magnitude)
    log = ForceLog(t_s=t_true - offset_s, fz_mN=fz, mb_Nmm=np.hypot(mx, my),
                   source=f"<simulated {run.name}>")
    return log, offset_s


def simulate_force_logs(runs: list[StageRun], stiffness: Stiffness, seed: int,
                        sensor: FTSensor = NANO17) -> list[tuple[ForceLog, float]]:
    """:func:`simulate_force_log` for every run, each with its own generator from ``seed``."""
    children = np.random.SeedSequence([seed, 1]).spawn(len(runs))
    return [simulate_force_log(run, stiffness, np.random.default_rng(child), sensor)
            for run, child in zip(runs, children, strict=True)]
