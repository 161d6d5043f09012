"""A scenario file's bytes to plain YAML data, safely: what :mod:`stt_drake.config.load`
reads before it maps anything onto the schema.

* bytes: at most :data:`MAX_FILE_BYTES`, decoded as strict UTF-8 (a byte that is not UTF-8
  is named by its offset and line);
* size: before anything is composed, one pass over libyaml's event stream (C, constant
  memory) counts the values the file writes and refuses a file with more than
  :data:`MAX_EXPANDED_NODES` of them at the first one too many (:func:`count_values`): a
  16 MiB file of numbers took 116 s and 3.8 GB to compose in Python before;
* YAML: composed once into its node graph (by libyaml when the file nests no deeper than
  :data:`MAX_DEPTH`, else by the Python composer, whose recursion is bounded), which is
  checked before any Python data is made from it — no key twice in one mapping (named by
  its field path; YAML itself would keep the last one silently), no nesting deeper than
  :data:`MAX_DEPTH`, and aliases bounded: the data with every alias expanded may hold at
  most :data:`MAX_EXPANDED_NODES` values, computed on the graph in time linear in the file
  (a "billion laughs" file is refused without ever being expanded); a `precheck` of the
  caller's may refuse the graph before that (:mod:`stt_drake.config.load` bounds the
  schedules there);
* user values are echoed in messages through :func:`short_repr` only, never whole.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import yaml

from stt_drake.config.schema import ScenarioError
from stt_drake.core.rules import ECHO_LIMIT, short_repr

#: Largest scenario file read (bytes): the largest shipped file is a few kB.
MAX_FILE_BYTES = 16 * 1024 * 1024

#: Largest number of values (scalars, lists, mappings) the file may write, and the data may
#: hold with every YAML alias expanded. The largest file shipped or tested writes ~300 and a
#: 60-obstacle field ~2 000; Drake's typed loader (pure Python) reads ~45 000 values per
#: second, so a file at this bound takes ~6 s to load, and the schedules it can hold
#: (:data:`stt_drake.config.load.MAX_SCHEDULE_ENTRIES`, 14 values per entry of a 3D
#: covariance schedule) fit under it.
MAX_EXPANDED_NODES = 250_000

#: Deepest nesting of lists and mappings: the schema's deepest field is 5 levels down.
MAX_DEPTH = 64

#: Longest echo of a user value in a message (characters).
REPR_LIMIT = ECHO_LIMIT


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


_VALUE_EVENTS = (yaml.ScalarEvent, yaml.SequenceStartEvent, yaml.MappingStartEvent)
_START_EVENTS = (yaml.SequenceStartEvent, yaml.MappingStartEvent)
_END_EVENTS = (yaml.SequenceEndEvent, yaml.MappingEndEvent)


def count_values(text: str) -> int | None:
    """The deepest nesting of the YAML in `text`, after checking that it writes at most
    :data:`MAX_EXPANDED_NODES` values (scalars, lists, mappings; an alias is not a value
    written: its expansion is bounded by :func:`check_nodes`), on libyaml's event stream:
    constant memory, ~1 µs per value, stopped at the first value too many. None when
    libyaml is missing or the text is not YAML (the composer then reports it as before).

    Raises:
        ScenarioError: more values than :data:`MAX_EXPANDED_NODES`, naming the field (list
            indices dropped) and the line of the first value too many.
    """
    parser = getattr(yaml, "CSafeLoader", None)
    if parser is None:
        return None
    loader = parser(text)
    values = deepest = 0
    stack: list[_Frame] = []
    try:
        while loader.check_event():
            event = loader.get_event()
            if isinstance(event, _END_EVENTS):
                stack.pop()
                _node_done(stack)
                continue
            if not isinstance(event, (*_VALUE_EVENTS, yaml.AliasEvent)):
                continue
            name = _node_name(stack, event)
            if isinstance(event, _VALUE_EVENTS):
                values += 1
                if values > MAX_EXPANDED_NODES:
                    where = re.sub(r"(\[\d+\])+$", "", "scenario" + _path(stack) + name)
                    raise ScenarioError(
                        f"{where}: the file writes more than {MAX_EXPANDED_NODES} values (line "
                        f"{event.start_mark.line + 1} holds the first one too many): a scenario "
                        "never needs that many, and loading them would take minutes"
                    )
            if isinstance(event, _START_EVENTS):
                stack.append(_Frame(isinstance(event, yaml.MappingStartEvent), name))
                deepest = max(deepest, len(stack))
            else:
                _node_done(stack)
    except yaml.YAMLError:
        return None
    finally:
        loader.dispose()
    return deepest


class _Frame:
    """An open list or mapping of :func:`count_values`'s walk: its name in its parent, and
    where it is (a list's last index; a mapping's last key and whether a key comes next)."""

    __slots__ = ("expecting_key", "index", "key", "mapping", "name")

    def __init__(self, mapping: bool, name: str) -> None:
        self.mapping, self.name = mapping, name
        self.index, self.key, self.expecting_key = -1, "", True


def _node_name(stack: list[_Frame], event: yaml.Event) -> str:
    """The name the node `event` starts has in its parent ("" for a key or the root; the
    parent's state advanced: a list's index, a mapping's key)."""
    if not stack:
        return ""
    top = stack[-1]
    if not top.mapping:
        top.index += 1
        return f"[{top.index}]"
    if top.expecting_key:
        top.key = str(event.value) if isinstance(event, yaml.ScalarEvent) else "<key>"
        return ""
    return f".{top.key}"


def _node_done(stack: list[_Frame]) -> None:
    """A node ended inside the top frame: a mapping alternates between key and value."""
    if stack and stack[-1].mapping:
        stack[-1].expecting_key = not stack[-1].expecting_key


def _path(stack: list[_Frame]) -> str:
    return "".join(frame.name for frame in stack)


def compose_checked(
    text: str,
    loader_class: type[yaml.SafeLoader],
    fast_loader_class: type | None = None,
    precheck: Callable[[yaml.Node], None] | None = None,
) -> Any:
    """The YAML document in `text`, read with `loader_class`, as Python data, after
    :func:`count_values` and :func:`check_nodes` passed (and `precheck`, when given, on the
    node graph first; None for an empty document). `fast_loader_class`, libyaml's twin of
    `loader_class`, composes instead when the file nests at most :data:`MAX_DEPTH` levels
    (libyaml's composer recurses in C, unbounded: deeper files go to the Python one)."""
    loader = None
    deepest = count_values(text)
    try:
        if fast_loader_class is not None and deepest is not None and deepest <= MAX_DEPTH:
            loader_class = fast_loader_class
        loader = loader_class(text)
        if deepest is None:  # not counted by libyaml: count while composing in Python
            _count_composed(loader)
        node = loader.get_single_node()
        if node is None:
            return None
        if precheck is not None:
            precheck(node)
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


def _count_composed(loader: Any) -> None:
    """Make the Python composer of `loader` refuse a file composing more than
    :data:`MAX_EXPANDED_NODES` nodes (aliases included), for when :func:`count_values`
    could not count the file first (no libyaml, or libyaml reading it differently)."""
    compose_node = loader.compose_node
    composed = 0

    def counted(parent: Any, index: Any) -> Any:
        nonlocal composed
        composed += 1
        if composed > MAX_EXPANDED_NODES:
            line = loader.peek_event().start_mark.line + 1
            raise ScenarioError(
                f"scenario: the file writes more than {MAX_EXPANDED_NODES} values (line {line} "
                "holds the first one too many): a scenario never needs that many"
            )
        return compose_node(parent, index)

    loader.compose_node = counted


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
