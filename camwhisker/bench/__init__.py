"""``camwhisker bench``: speed against error, the front end beside the paper-literal
pipeline and general-purpose trackers.

- :mod:`~camwhisker.bench.configs`  the pipeline configurations
- :mod:`~camwhisker.bench.peers`    general-purpose point trackers on the same points
- :mod:`~camwhisker.bench.pareto`   the Pareto front of speed against error
- :mod:`~camwhisker.bench.run`      measuring, the table, the plot
"""
