"""Files the package writes and reads, before any meaning: durable writes, JSON, TOML, CSV tables.

- :mod:`~camwhisker.files.atomic`: write to a temporary file, then rename into place.
- :mod:`~camwhisker.files.jsonfile`: strict JSON (NaN as null) and plain values.
- :mod:`~camwhisker.files.tomlfile`: TOML read with errors naming the file and key.
- :mod:`~camwhisker.files.figures`: figures saved as PNG, no pyplot, no backend chosen.
- :mod:`~camwhisker.files.tables`: CSV tables of named numeric columns, read and written.
"""
