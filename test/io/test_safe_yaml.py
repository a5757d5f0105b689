"""``io.safe_yaml.load_limited`` against ``yaml.safe_load``: the same value for every
document within the limits (plain documents built from the event stream, others through
libyaml's loader), the same refusal for a document ``yaml.safe_load`` refuses, and the
limits in both ways.

Truth: PyYAML's own ``safe_load`` (pure Python and libyaml). Seeded."""

from __future__ import annotations

import math
import random
from typing import Any

import pytest
import yaml

from strain_comp.io import safe_yaml
from strain_comp.io.safe_yaml import LimitError, load_limited

SCALARS = ["1", "-0.0", "1.5", ".5", "+.5", "1.e+5", "1.5E-3", "1_000.25", "1e5", "0x1f",
           "0o17", "0b101", "-0b11", "017", "1:20", "190:20:30.15", ".inf", "-.Inf", ".NaN",
           "yes", "No", "on", "OFF", "true", "~", "null", "", "x", "apl", "a b", "'q'",
           '"1.5"', '"x\\ny"', "2026-01-01", "2026-01-01T10:00:00Z", "=", "<<", "-", "..."]


def random_document(rng: random.Random, depth: int = 0) -> str:
    """A YAML value in flow style from ``SCALARS``, mappings and sequences, now and then an
    anchor and alias or an explicit tag."""
    roll = rng.random()
    if depth > 3 or roll < 0.5:
        text = rng.choice(SCALARS)
        if rng.random() < 0.05:
            text = f"!!str {text or 'x'}"
        return text
    items = [random_document(rng, depth + 1) for _ in range(rng.randint(0, 4))]
    if roll < 0.75:
        return "[" + ", ".join(items) + "]"
    keys = [rng.choice(SCALARS[:27]) for _ in items]
    body = "{" + ", ".join(f"{k}: {v}" for k, v in zip(keys, items, strict=True)) + "}"
    return f"&a {body}" if rng.random() < 0.05 else body


def outcome(load: Any, text: str) -> tuple[str, str]:
    """('ok', repr of the value; NaN written alike) or ('refused', '')."""
    try:
        value = load(text)
    except yaml.YAMLError:
        return "refused", ""
    return "ok", repr(value).replace("nan", "NaN")


@pytest.mark.parametrize("seed", range(4))
def test_load_limited_gives_what_safe_load_gives(seed: int) -> None:
    rng = random.Random(seed)
    docs = [random_document(rng) for _ in range(300)]
    docs += [yaml.safe_dump(yaml.safe_load(d), default_flow_style=flow)
             for d in docs[:100] for flow in (None, False)
             if outcome(yaml.safe_load, d)[0] == "ok"]
    plain = 0
    for text in docs:
        want = outcome(lambda t: yaml.load(t, Loader=yaml.SafeLoader), text)
        assert outcome(load_limited, text) == want, text
        assert outcome(lambda t: yaml.load(t, Loader=yaml.CSafeLoader), text) == want, text
        try:
            plain += safe_yaml._walk(text, 100, 10**6, 64)[0]
        except (LimitError, yaml.YAMLError):
            pass
    assert plain > len(docs) // 2  # most documents take the one-pass way


def test_a_plain_document_holds_the_limits() -> None:
    deep = "- " * 65 + "1\n"  # block nesting: no bracket for the text's own check
    with pytest.raises(LimitError, match="nested more than 64 deep"):
        load_limited(deep)
    assert load_limited("- " * 63 + "1\n") is not None
    wide = "[" + ", ".join(["1.5"] * 1000) + "]"
    with pytest.raises(LimitError, match="more than 1000 values"):
        load_limited(wide, max_nodes=1000)
    assert load_limited(wide, max_nodes=1001) == [1.5] * 1000
    with pytest.raises(yaml.constructor.ConstructorError, match="beyond float range"):
        load_limited("x: 1" + "0" * 400)
    assert math.isinf(load_limited("x: .inf")["x"])
