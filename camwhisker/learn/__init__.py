"""A learned time-series estimator: windows of a table's input columns -> its target columns.

- :mod:`~camwhisker.learn.series`: tables read and checked, targets encoded (angles on the
  circle), normalisation, windows that never span two tables, the validation splits.
- :mod:`~camwhisker.learn.knn`: the default kind, the nearest training windows by summary
  features (numpy and scipy).
- :mod:`~camwhisker.learn.net`: the conv kind's network (torch, imported only here).
- :mod:`~camwhisker.learn.train`: training by kind, the setting chosen on validation, the
  final fit on every table.
- :mod:`~camwhisker.learn.modeldir`: the model directory (docs/learn.md): arrays (npz, no
  pickle) with their SHA-256, and a JSON config.
- :mod:`~camwhisker.learn.predict`: a table's predictions, one row per input row; rows with
  gaps, each run of usable rows on its own.
- :mod:`~camwhisker.learn.sensor`: our sensor's runs as tables (phi, dz, theta, base travel
  -> r), and a model's r for a contact table (``contact --learned``).

The core package imports without torch; this package needs it only for the conv kind
(``pip install 'camwhisker[learn]'``).
"""
