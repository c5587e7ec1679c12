"""The ``camwhisker`` command line: wiring only, every computation lives in the library.

One module per part of the data flow, each registering its commands. The commands a
researcher runs sit at the top, in the order of the work; the simulators and benchmarks
sit under ``camwhisker dev``:

- :mod:`~camwhisker.cli.synth`   dev render, bound, make-samples, describe, make-experiment
- :mod:`~camwhisker.cli.batch`   batch: video(s) -> signal table(s)
- :mod:`~camwhisker.cli.overlay` overlay: video -> annotated video
- :mod:`~camwhisker.cli.live`    list-cameras, live, replay
- :mod:`~camwhisker.cli.contact` calibrate, contact; dev simulate-stage
- :mod:`~camwhisker.cli.texture` texture: texture from sliding; dev simulate-texture
- :mod:`~camwhisker.cli.experiment` experiment: a folder of recordings, end to end
- :mod:`~camwhisker.cli.map`     map: contacts in space as a point cloud, a belief grid, pictures
- :mod:`~camwhisker.cli.validate` validate: the paper's accuracy tests (Fig. 6 A/B)
- :mod:`~camwhisker.cli.bench`   dev chain, contact-bench, bench
- :mod:`~camwhisker.cli.dev`     dev NAME-bench: the benchmark scripts
- :mod:`~camwhisker.cli.common`  the error every command reports, shared options
- :mod:`~camwhisker.cli.parser`  the parser and ``main``
"""

from camwhisker.cli.parser import build_parser, main

__all__ = ["build_parser", "main"]
