"""Progress bars (tqdm) for long work, drawn on stderr only when it is a terminal and the
command is not ``--quiet`` (``wanted``)."""

from __future__ import annotations

import re
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

GRID_ROW = re.compile(r"grid row (\d+)/(\d+)")
"""How an APL-family fit reports a row of its sigma/p grid (``models.apl``'s progress)."""


def wanted(quiet: bool = False) -> bool:
    """Draw bars? Only on a terminal, and not when quiet."""
    return not quiet and sys.stderr.isatty()


@contextmanager
def bar(total: int | None, what: str, *, enabled: bool) -> Iterator[Any]:
    """A tqdm bar on stderr (disabled: drawing nothing), closed on leaving the block."""
    from tqdm import tqdm

    with tqdm(total=total, desc=what, disable=not enabled, file=sys.stderr, leave=False,
              dynamic_ncols=True) as shown:
        yield shown


def counter(shown: Any) -> Callable[[int, int], None]:
    """A ``progress(done, total)`` callable that moves ``shown`` to done of total."""
    def step(done: int, total: int) -> None:
        if shown.total != total:
            shown.total = total
        shown.update(done - shown.n)
    return step


def grid_progress(shown: Any) -> Callable[[str], None]:
    """An APL-family fit's ``progress``: ``grid row i/n`` moves ``shown``, others say the step."""
    def say(line: str) -> None:
        match = GRID_ROW.search(line)
        if match is None:
            shown.set_postfix_str(line.split(": ", 1)[-1][:40], refresh=True)
            return
        counter(shown)(int(match.group(1)), int(match.group(2)))
    return say
