"""A scenario file's bytes to plain YAML data, safely: what :mod:`stt_drake.config.load`
reads before it maps anything onto the schema.

* bytes: at most :data:`MAX_FILE_BYTES`, decoded as strict UTF-8 (a byte that is not UTF-8
  is named by its offset and line);
* YAML: composed once into its node graph, which is checked before any Python data is made
  from it — no key twice in one mapping (named by its field path; YAML itself would keep
  the last one silently), no nesting deeper than :data:`MAX_DEPTH`, and aliases bounded:
  the data with every alias expanded may hold at most :data:`MAX_EXPANDED_NODES` values,
  computed on the graph in time linear in the file (a "billion laughs" file is refused
  without ever being expanded);
* user values are echoed in messages through :func:`short_repr` only, never whole.
"""

from __future__ import annotations

import re
import reprlib
from pathlib import Path
from typing import Any

import yaml

from stt_drake.config.schema import ScenarioError

#: Largest scenario file read (bytes): the largest shipped file is a few kB.
MAX_FILE_BYTES = 16 * 1024 * 1024

#: Largest number of values (scalars, lists, mappings) the data may hold with every YAML
#: alias expanded; a 60-obstacle field is ~2 000.
MAX_EXPANDED_NODES = 1_000_000

#: Deepest nesting of lists and mappings: the schema's deepest field is 5 levels down.
MAX_DEPTH = 64

#: Longest echo of a user value in a message (characters).
REPR_LIMIT = 80

_REPR = reprlib.Repr()
_REPR.maxlevel = 3
_REPR.maxlist = _REPR.maxtuple = _REPR.maxset = 8
_REPR.maxdict = 6
_REPR.maxstring = _REPR.maxother = 60
_REPR.maxlong = 40


def short_repr(value: Any, limit: int = REPR_LIMIT) -> str:
    """repr(value) cut to at most `limit` characters, computed without ever forming the
    whole repr (a list is cut after a few items, nesting after a few levels)."""
    text = _REPR.repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def read_scenario_file(path: str | Path) -> str:
    """The text of a scenario file: at most :data:`MAX_FILE_BYTES`, strict UTF-8 (a leading
    byte-order mark is dropped).

    Raises:
        ScenarioError: no such file, unreadable, too large, or not UTF-8 (naming the first
            bad byte).
    """
    path = Path(path)
    if not path.is_file():
        raise ScenarioError(f"{path}: no such scenario file")
    size = path.stat().st_size
    if size > MAX_FILE_BYTES:
        raise ScenarioError(
            f"{path}: the file has {size} bytes; a scenario file may have at most "
            f"{MAX_FILE_BYTES} (16 MiB)"
        )
    try:
        data = path.read_bytes()
    except OSError as error:
        raise ScenarioError(f"{path}: cannot be read ({error.strerror or error})") from None
    return decode_scenario_bytes(data, str(path))


def decode_scenario_bytes(data: bytes, where: str = "scenario") -> str:
    """`data` decoded as strict UTF-8; ScenarioError naming the first byte that is not."""
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as error:
        line = data.count(b"\n", 0, error.start) + 1
        raise ScenarioError(
            f"{where}: not UTF-8 text: byte 0x{data[error.start]:02x} at offset "
            f"{error.start} (line {line}) is not valid UTF-8; save the file as UTF-8"
        ) from None
    return text.removeprefix("\ufeff")


def yaml_error_message(error: yaml.YAMLError) -> str:
    """A YAML parser error as the problem and where it is (ScenarioError makes it one
    line)."""
    problem = getattr(error, "problem", None) or getattr(error, "context", None)
    mark = getattr(error, "problem_mark", None) or getattr(error, "context_mark", None)
    if problem is None:
        return str(error)
    where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
    return f"{problem}{where}"


def compose_checked(text: str, loader_class: type[yaml.SafeLoader]) -> Any:
    """The YAML document in `text`, read with `loader_class`, as Python data, after
    :func:`check_nodes` passed on its node graph (None for an empty document)."""
    loader = None
    try:
        loader = loader_class(text)
        node = loader.get_single_node()
        if node is None:
            return None
        check_nodes(node)
        return loader.construct_document(node)
    except RecursionError:
        raise ScenarioError(
            f"scenario: not valid YAML: nested deeper than {MAX_DEPTH} levels"
        ) from None
    except yaml.YAMLError as error:
        raise ScenarioError(f"scenario: not valid YAML: {yaml_error_message(error)}") from None
    finally:
        if loader is not None:
            loader.dispose()


def check_nodes(root: yaml.Node) -> None:
    """Refuse duplicate keys (with their field path), nesting deeper than :data:`MAX_DEPTH`,
    recursive aliases, and data whose alias expansion exceeds :data:`MAX_EXPANDED_NODES`
    values. Linear in the number of distinct nodes: an aliased node is sized once."""
    sizes: dict[int, int] = {}
    open_nodes: set[int] = set()

    def expanded(node: yaml.Node, path: str, depth: int) -> int:
        key = id(node)
        if key in sizes:  # an alias of a node already checked: same size
            return sizes[key]
        if key in open_nodes:
            raise ScenarioError(f"{path}: a YAML alias refers to a node that contains it")
        if depth > MAX_DEPTH:
            where = re.sub(r"(\[\d+\])+$", "", path)  # the field, not its list indices
            where = where if len(where) <= 100 else where[:97] + "..."
            raise ScenarioError(f"{where}: nested deeper than {MAX_DEPTH} levels")
        open_nodes.add(key)
        total = 1
        if isinstance(node, yaml.MappingNode):
            seen: dict[str, int] = {}
            for key_node, value_node in node.value:
                name = _key_name(key_node)
                child = path if name == "<<" else f"{path}.{name}"
                if name != "<<" and name in seen:
                    raise ScenarioError(
                        f"{child}: duplicate key (lines {seen[name] + 1} and "
                        f"{key_node.start_mark.line + 1}); each field may be given once"
                    )
                seen[name] = key_node.start_mark.line
                total += expanded(value_node, child, depth + 1)
        elif isinstance(node, yaml.SequenceNode):
            for i, item in enumerate(node.value):
                total += expanded(item, f"{path}[{i}]", depth + 1)
        open_nodes.discard(key)
        if total > MAX_EXPANDED_NODES:
            raise ScenarioError(
                f"{path}: YAML aliases expand this to more than {MAX_EXPANDED_NODES} values "
                "(a scenario never needs that many; is it an alias bomb?)"
            )
        sizes[key] = total
        return total

    expanded(root, "scenario", 0)


def _key_name(node: yaml.Node) -> str:
    if isinstance(node, yaml.ScalarNode):
        return str(node.value)
    return f"<{short_repr(node.tag, 30)} key>"
