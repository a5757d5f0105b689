"""A pytest plugin: the bag reader's walk through ``bench_bag.py``'s library candidate, to
see which damaged-bag tests the library path keeps (docs/results.md).

    PYTHONPATH=.:bench BAG_LIBRARY=framing python -m pytest -p bag_library_plugin \\
        test/io/test_bag.py test/io/test_streaming.py test/test_budgets.py

``BAG_LIBRARY``: ``framing`` (the library's top-level walk, chunks read as today) or
``read`` (the library's whole reader).
"""

from __future__ import annotations

import os

import pytest


def pytest_configure(config: pytest.Config) -> None:
    """Route the reader before any test runs."""
    import bench_bag

    bench_bag.use_library(**{os.environ.get("BAG_LIBRARY", "framing"): True})
