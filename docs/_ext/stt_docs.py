"""Sphinx directives that generate pages from the code, so the pages cannot drift from it.

* ``scenario-schema``: the scenario reference, read from the dataclasses of
  :mod:`stt_drake.config.schema` (and the motion models and schedules of
  :mod:`stt_drake.core.motion`, the LCM section of :mod:`stt_drake.config.lcm`): one section
  per YAML mapping, with its docstring and a table of every field's YAML key, type and
  default.
* ``stt-modules``: one ``automodule`` per public module of a package (every module whose
  name has no leading underscore), so a new module is documented without editing a page.
* ``stt-public-api``: the names ``stt_drake`` exports (its ``__all__``), each linked to
  where it is documented, with the first line of its docstring.

The docstrings are written as plain text with the paper's notation, read by
:func:`plain_docstring` before reStructuredText sees them: ``|x|`` is an absolute value
(not a substitution), an indented formula after a line ending in ``:`` is shown as
written, and a list may follow its paragraph without a blank line.
"""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import pkgutil
import re
import types
import typing
from collections.abc import Iterator

from docutils import nodes
from docutils.statemachine import StringList
from sphinx.application import Sphinx
from sphinx.util.docutils import SphinxDirective
from sphinx.util.nodes import nested_parse_with_titles

#: Sections of the scenario reference, in page order: (YAML path, dataclass path).
#: The fields' own types lead to the rest (plants, motion models, schedules).
ROOT = ("scenario", "stt_drake.config.schema.Scenario")


def _import(path: str) -> object:
    module, _, name = path.rpartition(".")
    return getattr(importlib.import_module(module), name)


def _is_schema_class(kind: object) -> bool:
    """A dataclass of this package (Drake's own configs are linked, not expanded)."""
    return dataclasses.is_dataclass(kind) and getattr(kind, "__module__", "").startswith(
        "stt_drake."
    )


def _arguments(annotation: object) -> tuple[object, ...]:
    return typing.get_args(annotation)


def _is_union(annotation: object) -> bool:
    return typing.get_origin(annotation) in (typing.Union, types.UnionType)


def type_text(annotation: object) -> str:
    """A field's type as a reader writes it in YAML: ``float``, ``list[float]``,
    ``Quadrotor | FrankaArm``, ``Perception | None``."""
    if annotation is type(None):
        return "None"
    if _is_union(annotation):
        return " | ".join(type_text(argument) for argument in _arguments(annotation))
    origin = typing.get_origin(annotation)
    if origin is not None:
        inner = ", ".join(type_text(argument) for argument in _arguments(annotation))
        return f"{getattr(origin, '__name__', str(origin))}[{inner}]"
    return getattr(annotation, "__name__", str(annotation))


def nested_classes(annotation: object) -> Iterator[type]:
    """The package's dataclasses a field's type names (through unions and lists)."""
    if _is_schema_class(annotation):
        yield typing.cast(type, annotation)
        return
    for argument in _arguments(annotation):
        yield from nested_classes(argument)


def default_text(item: dataclasses.Field) -> str:
    """A field's default, as the loader fills it in when a file leaves the field out."""
    if item.default is not dataclasses.MISSING:
        value = item.default
    elif item.default_factory is not dataclasses.MISSING:
        value = item.default_factory()
    else:
        return "(required)"
    if _is_schema_class(type(value)):
        return f"{type(value).__name__} defaults"
    if value.__class__.__module__.startswith("pydrake"):
        return f"see {type(value).__name__}"
    return repr(value)


def _attribute_notes(kind: type) -> dict[str, str]:
    """Per-field notes from a Google-style ``Attributes:`` section of the docstring."""
    notes: dict[str, str] = {}
    lines = inspect.cleandoc(kind.__doc__ or "").splitlines()
    inside, current = False, ""
    for line in lines:
        if line.strip() == "Attributes:":
            inside = True
            continue
        if not inside:
            continue
        if line and not line.startswith(" "):
            break
        stripped = line.strip()
        name, colon, rest = stripped.partition(":")
        if line.startswith("    ") and not line.startswith("     ") and colon and " " not in name:
            current = name
            notes[current] = rest.strip()
        elif current and stripped:
            notes[current] += " " + stripped
    return notes


def _prose(kind: type) -> str:
    """The docstring without its ``Attributes:`` section (that goes into the table)."""
    text = inspect.cleandoc(kind.__doc__ or "")
    head, _, _ = text.partition("\nAttributes:")
    return head.strip()


def schema_sections() -> list[tuple[str, type]]:
    """Every mapping a scenario file can hold, breadth first from ``Scenario``: (YAML path,
    dataclass). A class reached twice (a motion model of two fields) appears once."""
    path, root = ROOT[0], typing.cast(type, _import(ROOT[1]))
    sections, seen, queue = [], set(), [(path, root)]
    while queue:
        path, kind = queue.pop(0)
        if kind in seen:
            continue
        seen.add(kind)
        sections.append((path, kind))
        for item in dataclasses.fields(kind):
            union = list(nested_classes(item.type))
            many = typing.get_origin(item.type) is list
            for nested in union:
                suffix = "[]" if many else ""
                tag = f" (!{nested.__name__})" if len(union) > 1 else ""
                queue.append((f"{path}.{item.name}{suffix}{tag}", nested))
    return sections


def _escape(text: str) -> str:
    return text.replace("|", "\\|").replace("*", "\\*")


def _row(cells: list[str]) -> list[str]:
    """One row of a ``list-table``."""
    return [f"   {'*' if i == 0 else ' '} - {cell}" for i, cell in enumerate(cells)]


def schema_rst() -> list[str]:
    """The scenario reference as reStructuredText lines."""
    lines: list[str] = []
    for path, kind in schema_sections():
        title = f"``{path}`` — {kind.__name__}"
        notes = _attribute_notes(kind)
        lines += [title, "-" * len(title), ""]
        lines += [f".. currentmodule:: {kind.__module__}", ""]
        lines += [f"Class: :class:`{kind.__module__}.{kind.__name__}`.", ""]
        lines += [*plain_docstring(_prose(kind).splitlines()), ""]
        header = ["key", "type", "default", *(["note"] if notes else [])]
        lines += [".. list-table::", "   :header-rows: 1", ""]
        lines += _row(header)
        for item in dataclasses.fields(kind):
            cells = [f"``{item.name}``", f"``{type_text(item.type)}``"]
            cells.append(f"``{default_text(item)}``")
            if notes:
                cells.append(_escape(notes.get(item.name, "")))
            lines += _row(cells)
        lines.append("")
    return lines


def parsed(directive: SphinxDirective, lines: list[str]) -> list[nodes.Node]:
    """Generated reStructuredText lines, parsed in the directive's place."""
    container = nodes.section()
    container.document = directive.state.document
    content = StringList(lines, source=f"<{directive.name}>")
    nested_parse_with_titles(directive.state, content, container)
    return list(container.children)


class ScenarioSchema(SphinxDirective):
    """``.. scenario-schema::``: the scenario reference, generated from the dataclasses."""

    def run(self) -> list[nodes.Node]:
        return parsed(self, schema_rst())


def public_modules(package: str) -> list[str]:
    """The public modules of a package and its public subpackages, sorted (a module or
    folder whose name starts with ``_`` is private; generated code is left out)."""
    found = [package]
    root = importlib.import_module(package)
    for info in pkgutil.iter_modules(root.__path__, prefix=f"{package}."):
        leaf = info.name.rpartition(".")[2]
        if leaf.startswith("_") or leaf == "stt_lcm":
            continue
        if info.ispkg:
            found += public_modules(info.name)
        else:
            found.append(info.name)
    return sorted(found)


class SttModules(SphinxDirective):
    """``.. stt-modules:: PACKAGE``: an ``automodule`` for each public module, with its
    members (a package only with its docstring: the names it re-exports are documented
    where they are defined)."""

    required_arguments = 1

    def run(self) -> list[nodes.Node]:
        lines: list[str] = []
        for name in public_modules(self.arguments[0]):
            title = f"``{name}``"
            lines += [title, "~" * len(title), ""]
            package = hasattr(importlib.import_module(name), "__path__")
            option = "   :no-members:" if package else "   :members:"
            lines += [f".. automodule:: {name}", option, ""]
        return parsed(self, lines)


def public_api_rst() -> list[str]:
    """The table of ``stt_drake.__all__``: name (linked to where it is documented) and the
    first paragraph of its docstring."""
    package = importlib.import_module("stt_drake")
    # A value without __module__ (a constant) is found through the package's own map of
    # names to modules, which its lazy loader reads.
    homes = getattr(package, "_PUBLIC", {})
    lines = [".. list-table::", "   :header-rows: 1", "   :widths: 35 65", ""]
    lines += _row(["name", "what it is"])
    for name in package.__all__:
        value = getattr(package, name)
        documented = inspect.isclass(value) or callable(value)
        module = getattr(value, "__module__", None) if documented else homes.get(name)
        role = "class" if inspect.isclass(value) else "func" if documented else "data"
        summary = (inspect.getdoc(value) or "") if documented else ""
        first = summary.split("\n\n", 1)[0].replace("\n", " ")
        lines += _row([f":{role}:`~{module or 'stt_drake'}.{name}`", _escape(first)])
    return [*lines, ""]


class SttPublicApi(SphinxDirective):
    """``.. stt-public-api::``: the top-level names, linked to their documentation."""

    def run(self) -> list[nodes.Node]:
        return parsed(self, public_api_rst())


#: Inline literals (``...``), inside which nothing is escaped.
_LITERAL = re.compile(r"(``.+?``)")

#: A bullet item's first line: "* ", "- " or "• ".
_BULLET = re.compile(r"^\s*[*\-•] ")


def _escape_bars(line: str) -> str:
    parts = _LITERAL.split(line)
    return "".join(p if p.startswith("``") else p.replace("|", "\\|") for p in parts)


def _indent(line: str) -> int:
    return len(line) - len(line.lstrip())


def plain_docstring(lines: list[str]) -> list[str]:
    """Plain-text docstring lines as reStructuredText shows them as written (see the module
    docstring): bars escaped, formula blocks made literal, blank lines before lists."""
    out: list[str] = []
    for index, line in enumerate(lines):
        line = _escape_bars(line)
        follows = next((x for x in lines[index + 1 :] if x.strip()), "")
        blank_next = index + 1 < len(lines) and not lines[index + 1].strip()
        if (
            line.rstrip().endswith(":")
            and not line.rstrip().endswith("::")
            and not line.lstrip().startswith(":")
            and blank_next
            and _indent(follows) > _indent(line)
            and not _BULLET.match(follows)
        ):
            line = line.rstrip() + ":"
        previous = out[-1] if out else ""
        if (
            _BULLET.match(line)
            and previous.strip()
            and not _BULLET.match(previous)
            and _indent(previous) == _indent(line)
        ):
            out.append("")
        out.append(line)
    return out


def _process_docstring(
    app: Sphinx, what: str, name: str, obj: object, options: object, lines: list[str]
) -> None:
    lines[:] = plain_docstring(lines)


def setup(app: Sphinx) -> dict[str, object]:
    app.connect("autodoc-process-docstring", _process_docstring)
    app.add_directive("scenario-schema", ScenarioSchema)
    app.add_directive("stt-modules", SttModules)
    app.add_directive("stt-public-api", SttPublicApi)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
