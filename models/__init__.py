"""The robot descriptions (``franka_fr3.urdf``), installed as ``stt_drake.models``.

This folder stays at the repository's top level; pyproject.toml maps it into the package
(``[tool.setuptools.package-dir]``) so that a wheel ships it and ``importlib.resources``
finds it. The file makes it a regular package: setuptools' editable install does not
resolve a mapped folder without one.
"""
