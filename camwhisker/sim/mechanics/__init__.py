"""Quasi-static whisker mechanics: simulated stage experiments with known truth.

- :mod:`~camwhisker.sim.mechanics.whisker`: the tapered whisker on its spring base
  (small-deflection beam in closed form, elastica by shooting).
- :mod:`~camwhisker.sim.mechanics.scenes`: pegs (rigid, compliant); a tilted box with
  Coulomb friction (stick at its corner, then slip up its face); a bottle whose
  side the whisker slides down, tangent to it; quasi-static sweeps of the base.
- :mod:`~camwhisker.sim.mechanics.rigid`: the rigid whisker of the paper's accuracy
  tests (its rotation from the stage geometry, an axial push).
- :mod:`~camwhisker.sim.mechanics.experiment`: stage runs with clocks, noise, truth.
- :mod:`~camwhisker.sim.mechanics.files`: writing runs to CSV files.
"""

from camwhisker.sim.mechanics.experiment import (
    FRONT_END_NOISE,
    KINDS,
    NOISE_LEVELS,
    PAPER_NOISE,
    NoiseModel,
    StageProtocol,
    StageRun,
    signal_arrays,
    simulate_run,
    simulate_runs,
)
from camwhisker.sim.mechanics.scenes import BoxScene, CircleScene, PegScene, sweep
from camwhisker.sim.mechanics.whisker import (
    WhiskerMechanics,
    beam_peg_response,
    solve_elastica,
)

__all__ = [
    "FRONT_END_NOISE",
    "KINDS",
    "NOISE_LEVELS",
    "PAPER_NOISE",
    "BoxScene",
    "CircleScene",
    "NoiseModel",
    "PegScene",
    "StageProtocol",
    "StageRun",
    "WhiskerMechanics",
    "beam_peg_response",
    "signal_arrays",
    "simulate_run",
    "simulate_runs",
    "solve_elastica",
    "sweep",
]
