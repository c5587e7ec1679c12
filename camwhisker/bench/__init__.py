"""Benchmarks: speed and error of each stage against the simulator's truth.

The library never imports this package; the command line and the tests do.

- :mod:`~camwhisker.bench.configs`    the pipeline configurations
- :mod:`~camwhisker.bench.peers`      general-purpose point trackers on the same points
- :mod:`~camwhisker.bench.pareto`     the Pareto front of speed against error
- :mod:`~camwhisker.bench.run`        ``camwhisker dev bench``: measuring, the table, the plot
- :mod:`~camwhisker.bench.vision`     the front end's speed and accuracy on rendered scenes
- :mod:`~camwhisker.bench.live`       the live loop's per-frame latency
- :mod:`~camwhisker.bench.view`       the live loop's latency with the browser view open and not
- :mod:`~camwhisker.bench.contact`    ``camwhisker dev contact-bench``: the contact back end
- :mod:`~camwhisker.bench.throughput` batch throughput with 1 and 2 worker processes
- :mod:`~camwhisker.bench.chain`      ``camwhisker dev chain``: filmed experiment against truth
- :mod:`~camwhisker.bench.belief`     contact belief (eq. 1): onset error, false contacts at rest
"""
