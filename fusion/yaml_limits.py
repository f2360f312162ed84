"""The one YAML loader for user files (``meta.yaml`` and configuration files), with limits.

A YAML file comes from a user, so reading it must neither hang, nor exhaust memory, nor crash:

* the bytes must be UTF-8 text (a byte that is not is reported with its line);
* a mapping must not give the same key twice (YAML says keys are unique; PyYAML keeps the last
  one silently, so a typo'd copy of a block would override the first);
* collections nest at most :data:`MAX_NESTING` levels, aliases included (a 5000-deep document
  overflows Python's recursion);
* aliases add at most :data:`MAX_ALIAS_NODES` nodes to the document (a "billion laughs" file of
  2 kB expands to gigabytes in any consumer that walks it), and an alias must not refer to a
  collection that contains it.

Each broken rule raises one :class:`YamlError` naming the line; the caller adds the file name.
Numbers like ``1e5`` (no dot) are floats, as in YAML 1.2 (PyYAML's YAML 1.1 reads a string).
Every key's line is returned (:attr:`YamlDocument.key_lines`), so that a later validation
error can name the line of its key.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

import yaml

__all__ = ["MAX_ALIAS_NODES", "MAX_NESTING", "KeyPath", "YamlDocument", "YamlError", "load_yaml"]

MAX_NESTING = 50
"""Deepest nesting of mappings and sequences accepted (aliases expanded)."""
MAX_ALIAS_NODES = 10_000
"""Most nodes that aliases may add to a document (each use counts its node's whole subtree)."""

KeyPath = tuple[str | int, ...]
"""Path of a key or item: mapping keys and sequence indices, outermost first."""


class YamlError(ValueError):
    """A YAML text breaks a rule of the limited loader.

    Attributes
    ----------
    line : int or None
        1-based line of the problem, when known.
    rule : str
        Sentence naming the rule broken.
    key : KeyPath or None
        Path of the key concerned (duplicate keys), when there is one.
    """

    def __init__(self, line: int | None, rule: str, key: KeyPath | None = None) -> None:
        self.line = line
        self.rule = rule
        self.key = key
        super().__init__(f"line {line}: {rule}" if line is not None else rule)

    def __reduce__(self) -> tuple[Any, ...]:
        """Support pickling."""
        return (type(self), (self.line, self.rule, self.key))


@dataclass(frozen=True)
class YamlDocument:
    """A parsed YAML document.

    Attributes
    ----------
    data : Any
        The document's value (None for an empty document).
    key_lines : dict
        1-based line of every key and sequence item, by its :data:`KeyPath`.
    """

    data: Any
    key_lines: dict[KeyPath, int]


class _LimitedLoader(yaml.SafeLoader):
    """Safe loader that enforces the nesting and alias limits while composing the node graph
    (before anything is constructed, so a bomb is refused at the cost of its text)."""

    def __init__(self, text: str) -> None:
        super().__init__(text)
        self._open: list[yaml.Node] = []  # collections being composed, outermost first
        self._alias_nodes = 0
        self._sizes: dict[int, int] = {}
        self._heights: dict[int, int] = {}

    def compose_node(self, parent: yaml.Node | None, index: Any) -> yaml.Node | None:
        event = self.peek_event()
        line = event.start_mark.line + 1
        if parent is not None:
            self._open.append(parent)
        try:
            if isinstance(event, yaml.AliasEvent):
                node = super().compose_node(parent, index)
                assert node is not None  # an alias names a node composed before it
                self._check_alias(node, str(event.anchor), line)
                return node
            if isinstance(event, yaml.CollectionStartEvent) and len(self._open) >= MAX_NESTING:
                raise YamlError(line, f"collections nest deeper than {MAX_NESTING} levels")
            return super().compose_node(parent, index)
        finally:
            if parent is not None:
                self._open.pop()

    def fetch_flow_collection_start(self, TokenClass: Any) -> None:
        """Refuse deep flow nesting (``[[[...``) as it is scanned: the scanner's cost grows
        with the square of the flow depth (2 s for 5000 levels) before the composer sees it."""
        if self.flow_level >= MAX_NESTING:
            line = self.get_mark().line + 1
            raise YamlError(line, f"collections nest deeper than {MAX_NESTING} levels")
        super().fetch_flow_collection_start(TokenClass)

    def _check_alias(self, node: yaml.Node, anchor: str, line: int) -> None:
        if any(node is ancestor for ancestor in self._open):
            raise YamlError(line, f"alias *{anchor} refers to a collection that contains it")
        if len(self._open) + self._height(node) > MAX_NESTING:
            raise YamlError(
                line, f"alias *{anchor} makes collections nest deeper than {MAX_NESTING} levels"
            )
        self._alias_nodes += self._size(node)
        if self._alias_nodes > MAX_ALIAS_NODES:
            raise YamlError(
                line,
                f"aliases expand the document by more than {MAX_ALIAS_NODES} nodes "
                f"(at alias *{anchor}); write the data out instead",
            )

    def _size(self, node: yaml.Node) -> int:
        """Nodes in ``node``'s subtree, aliases expanded (memoized: the graph is acyclic)."""
        key = id(node)
        if key not in self._sizes:
            self._sizes[key] = 1 + sum(self._size(child) for child in _children(node))
        return self._sizes[key]

    def _height(self, node: yaml.Node) -> int:
        """Levels of collections in ``node`` (0 for a scalar), aliases expanded."""
        key = id(node)
        if key not in self._heights:
            inner = [self._height(child) for child in _children(node)]
            scalar = isinstance(node, yaml.ScalarNode)
            self._heights[key] = 0 if scalar else 1 + max(inner, default=0)
        return self._heights[key]


_LimitedLoader.yaml_implicit_resolvers = {
    key: list(value) for key, value in yaml.SafeLoader.yaml_implicit_resolvers.items()
}
_LimitedLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$"),
    list("-+0123456789."),
)


def _children(node: yaml.Node) -> list[yaml.Node]:
    if isinstance(node, yaml.MappingNode):
        return [part for pair in node.value for part in pair]
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    return []


def _key_lines(node: yaml.Node, path: KeyPath, lines: dict[KeyPath, int]) -> None:
    """Record the line of every key / item; raise on the first duplicate key."""
    if isinstance(node, yaml.MappingNode):
        seen: dict[Any, int] = {}
        for key_node, value_node in node.value:
            key: str | int = key_node.value if isinstance(key_node, yaml.ScalarNode) else "?"
            line = key_node.start_mark.line + 1
            child = (*path, key)
            if key in seen:
                raise YamlError(
                    line, f"duplicate key {key!r} (first given on line {seen[key]})", child
                )
            seen[key] = line
            lines[child] = line
            _key_lines(value_node, child, lines)
    elif isinstance(node, yaml.SequenceNode):
        for i, item in enumerate(node.value):
            child = (*path, i)
            lines[child] = item.start_mark.line + 1
            _key_lines(item, child, lines)


def _decode(raw: bytes) -> str:
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line_start = raw.rfind(b"\n", 0, exc.start) + 1
        raise YamlError(
            raw.count(b"\n", 0, exc.start) + 1,
            f"not UTF-8 text (byte 0x{raw[exc.start]:02x} at column {exc.start - line_start + 1})",
        ) from None


def load_yaml(raw: bytes) -> YamlDocument:
    """Parse one YAML document from a user's file, within the limits of this module.

    Parameters
    ----------
    raw : bytes
        The file's contents (UTF-8).

    Returns
    -------
    YamlDocument
        The value and the line of every key.

    Raises
    ------
    YamlError
        For bytes that are not UTF-8, invalid YAML, a duplicate key, nesting deeper than
        :data:`MAX_NESTING`, aliases adding more than :data:`MAX_ALIAS_NODES` nodes or a
        recursive alias: the first one found, with its line.
    """
    text = _decode(raw)
    loader: _LimitedLoader | None = None
    try:
        loader = _LimitedLoader(text)
        node = loader.get_single_node()
        if node is None:
            return YamlDocument(None, {})
        lines: dict[KeyPath, int] = {}
        _key_lines(node, (), lines)
        return YamlDocument(loader.construct_document(node), lines)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line = mark.line + 1 if mark is not None else None
        raise YamlError(line, f"invalid YAML: {exc.problem or exc.context}") from None
    except yaml.reader.ReaderError as exc:
        line = text.count("\n", 0, exc.position) + 1
        raise YamlError(
            line, f"invalid YAML: {exc.reason} (character #x{exc.character:04x})"
        ) from None
    except yaml.YAMLError as exc:
        raise YamlError(None, f"invalid YAML: {exc}") from None
    finally:
        if loader is not None:
            loader.dispose()
