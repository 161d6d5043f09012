"""stt_drake.core.constants is the one definition of the constants the numpy reference and
the compiled kernels share: no other module assigns one of its names."""

from __future__ import annotations

import ast
from pathlib import Path

from scipy import special

from stt_drake.core import constants

PACKAGE = Path(constants.__file__).resolve().parents[1]
NAMES = {name for name in vars(constants) if name.isupper()}


def _module_level_assignments(path: Path) -> set[str]:
    names = set()
    for node in ast.parse(path.read_text(encoding="utf-8")).body:
        targets = node.targets if isinstance(node, ast.Assign) else []
        if isinstance(node, ast.AnnAssign):
            targets = [node.target]
        names.update(target.id for target in targets if isinstance(target, ast.Name))
    return names


def test_no_module_redefines_a_shared_constant():
    redefined = {
        f"{path.relative_to(PACKAGE)}: {name}"
        for path in PACKAGE.rglob("*.py")
        if path.name != "constants.py"
        for name in _module_level_assignments(path)
        if name in NAMES or name.lstrip("_") in NAMES
    }
    assert not redefined, f"import these from stt_drake.core.constants: {sorted(redefined)}"


def test_constants_is_pure_python():
    imported = [
        node
        for node in ast.parse(Path(constants.__file__).read_text(encoding="utf-8")).body
        if isinstance(node, ast.Import | ast.ImportFrom) and node.module != "__future__"
    ]
    assert imported == []


def test_sf_is_one_below_is_the_normal_quantile_of_two_to_the_minus_54():
    assert float(special.ndtri(2.0**-54)) == constants.SF_IS_ONE_BELOW


def test_a_hit_beyond_the_negligible_distance_is_below_half_the_spacing_below_one():
    """P(χ²_n > HIT_NEGLIGIBLE_SIGMAS²) < 2⁻⁵⁴ for n = 1, 2, 3: 1 − that is 1.0 in double."""
    for n in (1, 2, 3):
        tail = float(special.chdtrc(n, constants.HIT_NEGLIGIBLE_SIGMAS**2))
        assert 0.0 < tail < 2.0**-54, (n, tail)
        assert 1.0 - tail == 1.0
