"""The packaged scenarios (``*.yaml``), installed as ``stt_drake.diagrams``.

This folder stays at the repository's top level; pyproject.toml maps it into the package
(``[tool.setuptools.package-dir]``) so that a wheel ships it and ``importlib.resources``
finds it. The file makes it a regular package: setuptools' editable install does not
resolve a mapped folder without one.
"""
