"""The ``camwhisker`` command line: wiring only, every computation lives in the library.

One module per part of the data flow, each registering its commands:

- :mod:`~camwhisker.cli.synth`   render, bound, make-samples, describe, make-experiment
- :mod:`~camwhisker.cli.batch`   batch: video(s) -> signal table(s)
- :mod:`~camwhisker.cli.overlay` overlay: video -> annotated video
- :mod:`~camwhisker.cli.live`    list-cameras, live, replay
- :mod:`~camwhisker.cli.contact` simulate-stage, calibrate, contact
- :mod:`~camwhisker.cli.texture` simulate-texture, texture: texture from sliding
- :mod:`~camwhisker.cli.validate` validate: the paper's accuracy tests (Fig. 6 A/B)
- :mod:`~camwhisker.cli.bench`   chain, contact-bench, bench
- :mod:`~camwhisker.cli.common`  the error every command reports, shared options
- :mod:`~camwhisker.cli.parser`  the parser and ``main``
"""

from camwhisker.cli.parser import build_parser, main

__all__ = ["build_parser", "main"]
