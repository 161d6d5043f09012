"""Reading a scenario file: YAML text into the :mod:`stt_drake.config.schema` dataclasses,
unknown keys, missing required fields and type errors reported with their full field path
(the bytes and the YAML itself are checked first, :mod:`stt_drake.config.source`), the
limits of :mod:`stt_drake.config.limits` checked, the random field drawn, then
:func:`stt_drake.config.validate.validate`."""

import copy
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml
from pydrake.common.yaml import yaml_load_typed

from stt_drake.config.limits import check_limits, check_seed
from stt_drake.config.random_field import expand_random_obstacles
from stt_drake.config.schedules import check_schedule_nodes
from stt_drake.config.schema import Scenario, ScenarioError
from stt_drake.config.source import compose_checked, read_scenario_file, short_repr
from stt_drake.config.tracks import attach_tracks
from stt_drake.config.validate import (
    UNCERTAINTY_FIELDS,
    check_one_uncertainty,
    name_from_stem,
    validate,
    validate_dimension,
)
from stt_drake.config.validate_perception import check_noise_fields


class _TaggedLoader(yaml.SafeLoader):
    """Reads Drake's ``!Tag {...}`` variant syntax as plain mappings for the key check."""


class _FastTaggedLoader(getattr(yaml, "CSafeLoader", yaml.SafeLoader)):  # type: ignore[misc]
    """:class:`_TaggedLoader` on libyaml (composes ~6× faster; used for files that nest
    shallowly enough, :func:`stt_drake.config.source.compose_checked`)."""


for _loader in (_TaggedLoader, _FastTaggedLoader):
    _loader.add_multi_constructor(
        "!", lambda loader, suffix, node: {"__tag__": suffix, **loader.construct_mapping(node)}
    )


def _check_keys(schema: Any, data: Any, path: str) -> None:
    """Reject unknown keys and unknown ``!Tags`` with their full path (Drake's loader omits
    the nesting path)."""
    if not isinstance(data, dict):
        return
    variants = getattr(schema, "__args__", None)
    if variants is not None:  # Union / Optional: pick the tagged (or the only data) class
        classes = [v for v in variants if v is not type(None)]
        tag = data.get("__tag__")
        named = [c for c in classes if c.__name__ == tag]
        if tag is not None and not named:
            known = ", ".join("!" + c.__name__ for c in classes)
            raise ScenarioError(f"{path}: unknown type !{tag}; expected one of {known}")
        schema = named[0] if named else classes[0]
    elif data.get("__tag__") is not None:  # a tag where the field is not a variant
        tag, name = data["__tag__"], getattr(schema, "__name__", "?")
        if tag != name:
            raise ScenarioError(f"{path}: unknown type !{tag}; expected {name} (untagged)")
        raise ScenarioError(f"{path}: {name} is the only type here: drop the !{tag} tag")
    hints = _field_types(schema)
    if hints is None:
        return
    for key, value in data.items():
        if key == "__tag__":
            continue
        if key not in hints:
            known = ", ".join(hints)
            raise ScenarioError(f"{path}.{key}: unknown field; known fields are: {known}")
        hint = hints[key]
        item_schema = getattr(hint, "__args__", [None])[0] if _is_list(hint) else hint
        if isinstance(value, list):
            for i, item in enumerate(value):
                _check_keys(item_schema, item, f"{path}.{key}[{i}]")
        else:
            _check_keys(hint, value, f"{path}.{key}")


def _is_list(hint: Any) -> bool:
    return getattr(hint, "__origin__", None) is list


def _type_hints(schema: type) -> dict[str, Any]:
    return typing.get_type_hints(schema)


def _field_types(schema: Any) -> dict[str, Any] | None:
    """{field: type} of a dataclass or of a Drake-bound config (``__fields__``), else None."""
    if hasattr(schema, "__dataclass_fields__"):
        return _type_hints(schema)
    drake_fields = getattr(schema, "__fields__", None)
    if isinstance(schema, type) and isinstance(drake_fields, tuple):
        return {f.name: f.type for f in drake_fields}
    return None


def _locate_type_error(schema: Any, data: Any, path: str) -> str | None:
    """Find the value Drake's loader choked on, so its message can name the full path.

    Only called after ``yaml_load_typed`` failed; returns None when nothing is found (the
    caller then reports Drake's own message)."""
    variants = getattr(schema, "__args__", None)
    if variants is not None and not _is_list(schema):  # Union / Optional
        if data is None and type(None) in variants:
            return None
        classes = [v for v in variants if v is not type(None)]
        tag = data.get("__tag__") if isinstance(data, dict) else None
        named = [c for c in classes if c.__name__ == tag]
        schema = named[0] if named else classes[0]
    got = f" (got {short_repr(data)})"
    if _is_list(schema):
        if not isinstance(data, list):
            return f"{path}: must be a list{got}"
        for i, item in enumerate(data):
            found = _locate_type_error(schema.__args__[0], item, f"{path}[{i}]")
            if found:
                return found
        return None
    if schema is bool:
        return None if isinstance(data, bool) else f"{path}: must be true or false{got}"
    if schema is int:
        ok = isinstance(data, int) and not isinstance(data, bool)
        return None if ok or _parses(int, data) else f"{path}: must be an integer{got}"
    if schema is float:
        ok = isinstance(data, int | float) and not isinstance(data, bool)
        return None if ok or _parses(float, data) else f"{path}: must be a number{got}"
    if schema is str:
        return None if isinstance(data, str) else f"{path}: must be a string{got}"
    hints = _field_types(schema)
    if hints is None:
        return None
    if not isinstance(data, dict):
        return f"{path}: must be a mapping of fields{got}"
    for key, value in data.items():
        if key in hints:
            found = _locate_type_error(hints[key], value, f"{path}.{key}")
            if found:
                return found
    return None


def _parses(kind: type, data: Any) -> bool:
    if not isinstance(data, str):
        return False
    try:
        kind(data)
    except ValueError:
        return False
    return True


def read_scenario(path: str | Path, seed: int | None = None) -> Scenario:
    """Load, expand and validate (:func:`stt_drake.config.validate.validate`) a scenario file;
    raises ScenarioError on any bad input. :func:`stt_drake.assembly.load_scenario` adds
    the checks that need the built laws.

    `seed`, when given, replaces the file's `seed` before anything random is drawn, so a
    run is reproduced from (file, seed) alone. A recorded track's file (``!Recorded``) is
    relative to the scenario file's folder (:mod:`stt_drake.config.tracks`).
    """
    path = Path(path)
    text = read_scenario_file(path)
    return read_scenario_text(text, default_name=path.stem, seed=seed, base=path.parent)


def read_scenario_text(
    text: str,
    default_name: str = "scenario",
    seed: int | None = None,
    base: str | Path | None = None,
) -> Scenario:
    """Parse scenario YAML text (see :func:`read_scenario`); recorded track files are
    relative to the folder `base` (None: the current folder)."""
    return complete_scenario(parse_schema(text, default_name, base=base), seed)


#: Fields an obstacle must give, and what each one is (no invented uncertainty or risk).
OBSTACLE_REQUIRED = {
    "sigma": "the standard deviation of the obstacle centre, m; or give sigma_schedule, "
    "covariance, axes_sigma or covariance_schedule",
    "epsilon": "the probability ε ∈ (0, 1] with which the tube must avoid the obstacle",
    "p_d": "the probability p_d ∈ (ε, 1] of Assumption 3, that the obstacle eventually "
    "leaves the tube alone",
}

#: Fields a recorded motion must give (no default track).
RECORDED_REQUIRED = {
    "file": "the track file, .csv (header t,id,x,y[,z]) or .npz (arrays t, id, position), "
    "relative to the scenario file's folder",
    "id": "the track's id in that file (an integer)",
}

#: Fields a random obstacle field that draws must give.
RANDOM_REQUIRED = {
    "sigma_range": "[low, high] of the obstacles' standard deviations, m",
    "epsilon_range": "[low, high] of the obstacles' avoidance probabilities ε",
    "p_d": "the probability p_d of Assumption 3 for every drawn obstacle",
}


def _require_fields(data: dict, required: dict[str, str], path: str) -> None:
    for name, meaning in required.items():
        if data.get(name) is None:
            raise ScenarioError(f"{path}.{name}: required ({meaning})")


def _check_required(raw: dict) -> None:
    """The safety fields Drake's loader would fill with a default, found missing in the
    raw mapping: every obstacle's sigma (unless it gives another form of the uncertainty,
    of which it may give one only:
    :func:`stt_drake.config.validate.check_one_uncertainty`), epsilon and p_d, a recorded
    motion's file and id; a
    drawing random field's sigma_range, epsilon_range and p_d. And, since the defaults hide
    it after loading, that `perception:` writes at most one of each pair of noise models
    (:func:`stt_drake.config.validate_perception.check_noise_fields`)."""
    obstacles = raw.get("obstacles")
    for i, item in enumerate(obstacles if isinstance(obstacles, list) else []):
        if isinstance(item, dict):
            path = f"scenario.obstacles[{i}]"
            given = [name for name in UNCERTAINTY_FIELDS if item.get(name) is not None]
            check_one_uncertainty(given, path)
            needed = dict(OBSTACLE_REQUIRED)
            if any(name != "sigma" for name in given):
                del needed["sigma"]
            _require_fields(item, needed, path)
            motion = item.get("motion")
            if isinstance(motion, dict) and motion.get("__tag__") == "Recorded":
                _require_fields(motion, RECORDED_REQUIRED, f"{path}.motion")
    spec = raw.get("random_obstacles")
    if isinstance(spec, dict) and (spec.get("count") not in (None, 0) or spec.get("count_range")):
        _require_fields(spec, RANDOM_REQUIRED, "scenario.random_obstacles")
    perception = raw.get("perception")
    if isinstance(perception, dict):  # which noise fields the file wrote (defaults hide it)
        given = [name for name, value in perception.items() if value is not None]
        check_noise_fields(given, "scenario.perception")


@dataclass(frozen=True)
class ScenarioText:
    """A scenario as it travels to a campaign's worker processes (the parsed schema holds
    Drake objects that do not pickle): the file's `text`, its `name` (the file's stem) and
    `base`, the folder its recorded track files are named relative to."""

    text: str
    name: str
    base: str

    def parse(self, guide: bool = True) -> Scenario:
        """:func:`parse_schema` of this text, its tracks read relative to `base`."""
        return parse_schema(self.text, self.name, guide, self.base)


def parse_schema(
    text: str,
    default_name: str = "scenario",
    guide: bool = True,
    base: str | Path | None = None,
) -> Scenario:
    """YAML text → the schema dataclasses, with duplicate keys, unknown keys, missing
    required fields and type errors reported by their field path, and the recorded tracks
    read from their files (relative to the folder `base`, None: the current folder; each
    file once, its rules checked: :func:`stt_drake.config.tracks.attach_tracks`); nothing
    drawn, nothing else checked (:func:`complete_scenario` does that, once per seed: a
    campaign parses its file once and completes a copy per run, sharing the tracks). A
    scenario without a `name` is named `default_name`, made a valid name
    (:func:`stt_drake.config.validate.name_from_stem`). ``guide=False`` drops the file's
    `guide:` section: the paper's reactive tube on the same scenario (``--no-guide``)."""
    raw = compose_checked(text, _TaggedLoader, _FastTaggedLoader, check_schedule_nodes)
    if not isinstance(raw, dict):
        raise ScenarioError("scenario: the file must be a mapping of fields")
    _check_keys(Scenario, raw, "scenario")
    _check_required(raw)
    if "plant" in raw and raw["plant"] is None:  # a Union field: Drake's loader fills a
        # null `plant:` into an OmniRobot with a None field instead of refusing it
        raise ScenarioError(
            "scenario.plant: must be a mapping of fields (an omni robot) or a tagged plant "
            "(!Quadrotor {...}, !FrankaArm {...}); got an empty value"
        )
    try:
        scenario = yaml_load_typed(schema=Scenario, data=text)
    except (RuntimeError, ValueError, TypeError, AssertionError, yaml.YAMLError) as error:
        located = _locate_type_error(Scenario, raw, "scenario")
        raise ScenarioError(located or f"scenario: {error}") from None
    if not scenario.name:
        scenario.name = name_from_stem(default_name)
    if not guide:
        scenario.guide = None
    attach_tracks(scenario, None if base is None else Path(base))
    return scenario


def complete_scenario(schema: Scenario, seed: int | None = None) -> Scenario:
    """A copy of `schema` (from :func:`parse_schema`) with `seed` (when given) in place,
    its random field drawn and every rule of :func:`stt_drake.config.validate.validate`
    checked; `schema` itself is left as it was."""
    if seed is not None:
        check_seed(seed, "seed")
    scenario = copy.deepcopy(schema)
    if seed is not None:
        scenario.seed = seed
    validate_dimension(scenario)
    check_limits(scenario)  # before anything is drawn: finite numbers, seeds, memory
    expand_random_obstacles(scenario)
    validate(scenario)
    return scenario
