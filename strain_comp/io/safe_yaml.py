"""YAML from untrusted files within limits (aliases, expanded size, nesting, integer range):
``load_limited``. A plain document (every calibration file) is built from the parser's
events as the limits are checked (``_walk``); any other then goes through the loader."""

from __future__ import annotations

import re
import sys
from collections.abc import Iterator
from typing import Any

import yaml


class LimitError(Exception):
    """A YAML document exceeds a limit of ``load_limited``."""


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


_STR, _FLOAT, _INT, _BOOL, _NULL = (f"tag:yaml.org,2002:{kind}"
                                    for kind in ("str", "float", "int", "bool", "null"))
_SafeLoader: Any = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


class _Loader(_SafeLoader):  # type: ignore[misc]
    """libyaml's SafeLoader where installed, refusing integers that no float can hold."""


_Loader.add_constructor("tag:yaml.org,2002:int", _construct_int)


class _NotPlain(Exception):
    """The document holds more than ``_walk`` builds (a timestamp, a merge key)."""


_RESOLVERS: dict[str | None, list[tuple[str, re.Pattern[str]]]] = {
    first: [*rules, *yaml.resolver.Resolver.yaml_implicit_resolvers.get(None, [])]
    for first, rules in yaml.resolver.Resolver.yaml_implicit_resolvers.items()}
_UNSET = object()
"""A mapping's key not read yet."""
_SEQUENCE = object()
"""In place of a key: the open collection is a sequence."""


def _plain_scalar(event: Any, constructor: yaml.constructor.SafeConstructor) -> Any:
    """An untagged scalar as ``yaml.safe_load`` gives it; ``_NotPlain``: timestamp, merge key."""
    value = event.value
    tag = _STR
    if event.implicit[0]:  # plain: the implicit resolvers of yaml.SafeLoader, in order
        for rule, pattern in _RESOLVERS.get(value[:1], _RESOLVERS.get(None, [])):
            if pattern.match(value):
                tag = rule
                break
    if tag == _STR:
        return value
    if tag == _FLOAT:
        digits = value.replace("_", "").lower()
        if ":" not in digits and "." in digits and "inf" not in digits and "nan" not in digits:
            return float(digits)
    if tag in (_FLOAT, _INT, _BOOL, _NULL):
        node = yaml.ScalarNode(tag, value, event.start_mark, event.end_mark)
        return _construct_int(constructor, node) if tag == _INT else \
            constructor.construct_object(node)
    raise _NotPlain


def _walk(text: str, max_aliases: int, max_nodes: int, max_depth: int) -> tuple[bool, Any, int]:
    """(plain, the document if plain, aliases): the limits checked on the events in one pass."""
    constructor = yaml.constructor.SafeConstructor()
    open_: list[Any] = []  # the collections being filled, outermost first
    keys: list[Any] = []  # per open collection: its pending key, _UNSET or _SEQUENCE
    root: Any = None
    plain = True
    nodes = documents = aliases = depth = 0
    events: Iterator[Any] = yaml.parse(text, Loader=_Loader)
    for event in events:
        kind = event.__class__
        if kind is yaml.MappingEndEvent or kind is yaml.SequenceEndEvent:
            depth -= 1
            if plain:
                open_.pop()
                keys.pop()
            continue
        if kind is yaml.DocumentStartEvent:
            documents += 1
            plain = plain and documents == 1  # the composer names the fault
            continue
        if kind is yaml.AliasEvent:
            plain = False
            aliases += 1
            if aliases > max_aliases:
                raise LimitError(f"more than {max_aliases} YAML aliases")
        elif not (kind is yaml.ScalarEvent or kind is yaml.MappingStartEvent
                  or kind is yaml.SequenceStartEvent):
            continue
        if depth + 1 > max_depth:
            raise LimitError(f"nested more than {max_depth} deep")
        if kind is yaml.AliasEvent:
            continue
        nodes += 1
        if nodes > max_nodes:
            raise LimitError(f"more than {max_nodes} values once YAML aliases are expanded")
        if kind is not yaml.ScalarEvent:
            depth += 1
        plain = plain and event.anchor is None and event.tag is None
        if not plain:
            continue
        try:
            value: Any = (_plain_scalar(event, constructor) if kind is yaml.ScalarEvent
                          else {} if kind is yaml.MappingStartEvent else [])
        except _NotPlain:
            plain = False
            continue
        if not open_:
            root = value
        elif keys[-1] is _SEQUENCE:
            open_[-1].append(value)
        elif keys[-1] is _UNSET:
            plain = kind is yaml.ScalarEvent  # else a complex key
            keys[-1] = value
        else:
            open_[-1][keys[-1]] = value
            keys[-1] = _UNSET
        if kind is not yaml.ScalarEvent:
            open_.append(value)
            keys.append(_UNSET if kind is yaml.MappingStartEvent else _SEQUENCE)
    return plain, root, aliases


_FLOW_BRACKET = re.compile(r"[\[\]{}]")


def _check_flow_depth(text: str, max_depth: int) -> None:
    """LimitError for flow brackets nested deeper than ``max_depth``, counted on the text."""
    # libyaml's scanner refuses deep flow nesting itself, in words that differ by release
    depth = 0
    for match in _FLOW_BRACKET.finditer(text):
        if match.group() in "[{":
            depth += 1
            if depth > max_depth:
                raise LimitError(f"nested more than {max_depth} deep")
        elif depth:
            depth -= 1


def _check_expansion(root: yaml.Node, max_nodes: int, max_depth: int) -> None:
    """LimitError when ``root``, aliases expanded, exceeds the size or nesting limit."""
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
    """The single YAML document in ``text``, within the limits."""
    _check_flow_depth(text, max_depth)
    plain, document, aliases = _walk(text, max_aliases, max_nodes, max_depth)
    if plain:
        return document
    loader = _Loader(text)
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        if aliases:  # without aliases nothing expands: the events' checks were the limits
            _check_expansion(node, max_nodes, max_depth)
        return loader.construct_document(node)
    finally:
        loader.dispose()
