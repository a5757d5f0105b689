"""YAML from untrusted files with limits: aliases, expanded size, nesting, integer range.

``load_limited(text, ...)`` is ``yaml.safe_load`` that raises ``LimitError`` instead of
expanding a "billion laughs" document, recursing into 1,000 levels of nesting
(``RecursionError``) or building an integer no float can hold (``OverflowError`` later);
every other fault is the usual ``yaml.YAMLError``. Used for calibration files and rosbag2
``metadata.yaml``. With libyaml (``yaml.CSafeLoader``) the limits are checked on libyaml's
event stream first (no nesting or alias beyond them reaches the composer), then the
document is composed by libyaml: about 5x faster than the pure-Python loader, which is
used otherwise.
"""

from __future__ import annotations

import gc
import re
import sys
from typing import Any

import yaml


class LimitError(Exception):
    """A YAML document exceeds a limit of ``load_limited``."""


class _LimitedLoader(yaml.SafeLoader):
    """yaml.SafeLoader that counts aliases and nesting while it composes, and refuses
    integers that no float can hold."""

    def __init__(self, stream: str, max_aliases: int, max_depth: int) -> None:
        super().__init__(stream)
        self.max_aliases = max_aliases
        self.max_depth = max_depth
        self.n_aliases = 0
        self.depth = 0

    def compose_node(self, parent: Any, index: Any) -> Any:
        if self.check_event(yaml.AliasEvent):
            self.n_aliases += 1
            if self.n_aliases > self.max_aliases:
                raise LimitError(f"more than {self.max_aliases} YAML aliases")
        self.depth += 1
        try:
            if self.depth > self.max_depth:
                raise LimitError(f"nested more than {self.max_depth} deep")
            return super().compose_node(parent, index)
        finally:
            self.depth -= 1


def _construct_int(loader: Any, node: Any) -> int:
    """An integer; a ConstructorError for one that no float can hold."""
    try:
        value = yaml.constructor.SafeConstructor.construct_yaml_int(loader, node)
    except ValueError:  # beyond Python's digit limit for int()
        value = None
    if value is None or abs(value) > sys.float_info.max:
        text = node.value if len(node.value) <= 20 else node.value[:20] + "..."
        raise yaml.constructor.ConstructorError(
            None, None, f"integer {text} beyond float range", node.start_mark)
    return value


_LimitedLoader.add_constructor("tag:yaml.org,2002:int", _construct_int)

_STR, _FLOAT, _INT = (f"tag:yaml.org,2002:{kind}" for kind in ("str", "float", "int"))
_CSafeLoader: Any = getattr(yaml, "CSafeLoader", None)
if _CSafeLoader is not None:
    class _LimitedCLoader(_CSafeLoader):
        """libyaml's SafeLoader refusing integers that no float can hold; plain strings,
        floats and integers are built without the generic constructor's bookkeeping (a
        third of a large calibration's load)."""

        def construct_object(self, node: Any, deep: bool = False) -> Any:
            if node.__class__ is yaml.ScalarNode:
                if node.tag == _STR:
                    return node.value
                if node.tag == _FLOAT:
                    return self.construct_yaml_float(node)
                if node.tag == _INT:
                    return _construct_int(self, node)
            return super().construct_object(node, deep)

    _LimitedCLoader.add_constructor("tag:yaml.org,2002:int", _construct_int)


def _check_events(text: str, max_aliases: int, max_nodes: int, max_depth: int) -> int:
    """The alias and nesting limits on libyaml's events (iterative), as ``_LimitedLoader``
    counts them while composing: a node's depth counts the collections around it, plus 1.
    Returns the number of aliases (none: the document holds at most ``max_nodes`` values)."""
    depth = aliases = nodes = 0
    for event in yaml.parse(text, Loader=_CSafeLoader):
        if isinstance(event, yaml.AliasEvent):
            aliases += 1
            if aliases > max_aliases:
                raise LimitError(f"more than {max_aliases} YAML aliases")
        if isinstance(event, (yaml.CollectionStartEvent, yaml.ScalarEvent, yaml.AliasEvent)) \
                and depth + 1 > max_depth:
            raise LimitError(f"nested more than {max_depth} deep")
        if isinstance(event, (yaml.CollectionStartEvent, yaml.ScalarEvent)):
            nodes += 1
            if nodes > max_nodes:
                raise LimitError(f"more than {max_nodes} values once YAML aliases are "
                                 "expanded")
        if isinstance(event, yaml.CollectionStartEvent):
            depth += 1
        elif isinstance(event, yaml.CollectionEndEvent):
            depth -= 1
    return aliases


_FLOW_BRACKET = re.compile(r"[\[\]{}]")


def _check_flow_depth(text: str, max_depth: int) -> None:
    """LimitError when flow brackets open more than ``max_depth`` deep, checked on the text
    before any YAML scanner runs (libyaml's own scanner refuses deep flow nesting with its
    own words and limit, which differ between releases). Brackets inside quoted scalars are
    counted too: only a document nested absurdly deep can be refused by them."""
    depth = 0
    for match in _FLOW_BRACKET.finditer(text):
        if match.group() in "[{":
            depth += 1
            if depth > max_depth:
                raise LimitError(f"nested more than {max_depth} deep")
        elif depth:
            depth -= 1


def _check_expansion(root: yaml.Node, max_nodes: int, max_depth: int) -> None:
    """LimitError when ``root`` with every alias expanded holds more than ``max_nodes``
    values or is nested more than ``max_depth`` deep (iterative: no recursion)."""
    size: dict[int, int] = {}
    depth: dict[int, int] = {}
    stack: list[tuple[yaml.Node, bool]] = [(root, False)]
    while stack:
        node, done = stack.pop()
        key = id(node)
        if key in size and not done:
            continue
        children: list[yaml.Node] = []
        if isinstance(node, yaml.SequenceNode):
            children = list(node.value)
        elif isinstance(node, yaml.MappingNode):
            children = [n for pair in node.value for n in pair]
        if not done:
            size[key] = 0  # in progress: on the current path from the root
            if any(id(c) in size and id(c) not in depth for c in children):
                raise LimitError("a YAML alias refers to a value that contains it")
            stack.append((node, True))
            stack.extend((c, False) for c in children if id(c) not in size)
            continue
        size[key] = 1 + sum(size[id(c)] for c in children)
        depth[key] = 1 + max((depth[id(c)] for c in children), default=0)
        if size[key] > max_nodes:
            raise LimitError(f"more than {max_nodes} values once YAML aliases are expanded")
        if depth[key] > max_depth:
            raise LimitError(f"nested more than {max_depth} deep once YAML aliases are "
                             "expanded")


def load_limited(text: str, *, max_aliases: int = 100, max_nodes: int = 1_000_000,
                 max_depth: int = 64) -> Any:
    """Parse the single YAML document in ``text`` within the limits. The cyclic garbage
    collector is paused meanwhile: a document builds no cycles (an alias that contains
    itself is refused), and its passes over the many new objects of a large document
    tripled the load time of a 1024-sensor calibration.

    Args:
        text: The YAML text (untrusted).
        max_aliases: Most aliases (``*name``) the document may use.
        max_nodes: Most values the document may hold once its aliases are expanded.
        max_depth: Deepest nesting of collections, aliases expanded.

    Returns:
        The document as ``yaml.safe_load`` gives it; None for an empty document.

    Raises:
        LimitError: The document exceeds a limit.
        yaml.YAMLError: The text is not one valid YAML document, or holds an integer that
            no float can hold (a ``ConstructorError``).

    """
    collecting = gc.isenabled()
    gc.disable()
    try:
        return _load(text, max_aliases, max_nodes, max_depth)
    finally:
        if collecting:
            gc.enable()


def _load(text: str, max_aliases: int, max_nodes: int, max_depth: int) -> Any:
    """``load_limited`` with the collector as it is."""
    loader: Any = None
    aliases = 1  # unknown: the expansion is checked
    _check_flow_depth(text, max_depth)
    try:
        if _CSafeLoader is not None:
            aliases = _check_events(text, max_aliases, max_nodes, max_depth)
            loader = _LimitedCLoader(text)
        else:
            loader = _LimitedLoader(text, max_aliases, max_depth)
        node = loader.get_single_node()
        if node is None:
            return None
        if aliases:  # without aliases nothing expands: the events' checks were the limits
            _check_expansion(node, max_nodes, max_depth)
        return loader.construct_document(node)
    finally:
        if loader is not None:
            loader.dispose()
