"""The packaged scenarios (``*.yaml``), installed as ``stt_drake.diagrams``.

This folder stays at the repository's top level; pyproject.toml maps it into the package
(``[tool.setuptools.package-dir]``) so that a wheel ships it and ``importlib.resources``
finds it. The file makes it a regular package: setuptools' editable install does not
resolve a mapped folder without one.
"""

import difflib
from importlib.resources import files
from pathlib import Path


def packaged_scenarios() -> dict[str, Path]:
    """The scenarios shipped in the package: name (file stem) → file, sorted by name.

    An installed wheel is unpacked (and an editable install maps the repository's
    diagrams/ folder), so every resource is a real file the loader can open.
    """
    folder = Path(str(files(__name__)))
    return {path.stem: path for path in sorted(folder.glob("*.yaml"))}


def scenario_file(scenario: str | Path, listed_by: str = "stt_drake.packaged_scenarios()") -> Path:
    """The scenario file `scenario` names: an existing path that is not a folder wins;
    otherwise a packaged scenario's name (``omni_hardware_case1``, also with ``.yaml``).
    A folder is never a scenario file, so a local folder named like a packaged scenario
    (``./omni_hardware_case1/``) does not hide it.

    Raises:
        FileNotFoundError: neither an existing file nor a packaged name (a folder of that
            name is said to be one); the message lists the packaged names closest to it
            and says that `listed_by` lists them all.
    """
    path = Path(scenario)
    folder = path.is_dir()
    if path.exists() and not folder:
        return path
    text = str(scenario)
    packaged = packaged_scenarios()
    name = text.removesuffix(".yaml")
    if name in packaged:
        return packaged[name]
    if folder:
        raise FileNotFoundError(
            f"{text}: is a folder, not a scenario file, and no packaged scenario has that "
            f"name ({listed_by} lists them all)"
        )
    close = difflib.get_close_matches(path.name.removesuffix(".yaml"), packaged, n=5, cutoff=0.5)
    hint = f"; close packaged names: {', '.join(close)}" if close else ""
    raise FileNotFoundError(
        f"{text}: no such scenario file, and no packaged scenario of that name{hint} "
        f"({listed_by} lists them all)"
    )
