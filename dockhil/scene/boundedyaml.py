"""YAML read with bounds: what a small file may expand to is limited before it is built.

A few hundred bytes of nested aliases (`b: [*a, *a, ...]`) expand to billions of
nodes, and thousands of `[` exhaust the recursion limit. Here the document is
composed first, its nesting depth and its size with every alias expanded
checked as it is composed, and only a bounded document is built into Python
objects. Numbers with an exponent and no dot (`1e3`) read as
floats, as in YAML 1.2, not as strings.
"""

from __future__ import annotations

import re
from typing import Any

import yaml

from dockhil.errors import DockhilError


class YamlError(DockhilError):
    """A document refused: one line naming the source; `line` where it went wrong (None: unknown)."""

    def __init__(self, message: str, line: int | None = None):
        super().__init__(message)
        self.line = line


MAX_BYTES = 1 << 20  # a launch file is a page or two of text
MAX_DEPTH = 32  # mappings and lists nested in each other
MAX_NODES = 100_000  # scalars, lists and mappings, every alias expanded


class _Loader(yaml.SafeLoader):
    depth = 0

    def compose_node(self, parent, index):
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            node = super().compose_node(parent, index)
            if not hasattr(node, "expanded"):  # named before it is complete: it contains itself
                raise YamlError(
                    f"{self.name}:{event.start_mark.line + 1}: alias *{event.anchor} refers to the "
                    f"value that contains it (a recursive document); write the value out",
                    event.start_mark.line + 1,
                )
            return node
        self.depth += 1
        try:
            if self.depth > MAX_DEPTH:
                line = self.peek_event().start_mark.line + 1
                raise YamlError(f"{self.name}:{line}: nested deeper than {MAX_DEPTH} levels", line)
            node = super().compose_node(parent, index)
        finally:
            self.depth -= 1
        # Size and depth with every alias expanded, from the children's (composed before their parent,
        # as the value an alias names is composed before the alias): linear in the text.
        kids = (
            []
            if isinstance(node, yaml.ScalarNode)
            else node.value
            if isinstance(node, yaml.SequenceNode)
            else [x for pair in node.value for x in pair]
        )
        node.expanded = 1 + sum(k.expanded for k in kids)
        node.nesting = 1 + max((k.nesting for k in kids), default=0)
        line = node.start_mark.line + 1
        if node.expanded > MAX_NODES:
            raise YamlError(
                f"{self.name}:{line}: expands to more than {MAX_NODES} values "
                f"(each alias repeats what it names); write a smaller file",
                line,
            )
        if node.nesting > MAX_DEPTH:
            raise YamlError(
                f"{self.name}:{line}: nested deeper than {MAX_DEPTH} levels once its aliases are expanded", line
            )
        return node


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$"),
    list("-+0123456789."),
)


def load(text: str, source: str) -> tuple[Any, yaml.Node | None]:
    """(data, root node) of one YAML document; YamlError, one line naming `source`, if refused.
    The root node's marks give line numbers for later messages (see `line_of`)."""
    if len(text) > MAX_BYTES:
        raise YamlError(f"{source}: {len(text)} characters; a launch file may have at most {MAX_BYTES}")
    loader = None
    try:
        loader = _Loader(text)  # its reader refuses control characters here
        loader.name = source
        root = loader.get_single_node()
        if root is None:
            return None, None
        return loader.construct_document(root), root
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"{source}:{mark.line + 1}" if mark else source
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise YamlError(f"{where}: not valid YAML: {problem}", mark.line + 1 if mark else None) from None
    except ValueError as exc:  # a number too long to convert (Python limits int digits)
        raise YamlError(f"{source}: not valid YAML: {exc}") from None
    finally:
        if loader is not None:
            loader.dispose()


def line_of(root: yaml.Node | None, path: list) -> int | None:
    """The line of the value at `path` (keys and indices) in the composed document, or of the
    deepest part of it that exists; None without a document."""
    node, line = root, None
    for step in path:
        if node is None:
            break
        line = node.start_mark.line + 1
        if isinstance(node, yaml.MappingNode):
            node = next((v for k, v in node.value if isinstance(k, yaml.ScalarNode) and k.value == step), None)
        elif isinstance(node, yaml.SequenceNode) and isinstance(step, int) and 0 <= step < len(node.value):
            node = node.value[step]
        else:
            node = None
    if node is not None:
        line = node.start_mark.line + 1
    return line
