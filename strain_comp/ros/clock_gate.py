"""Under sim time, an input and its own /clock tick arrive in either order: the gate holds
an input until its tick (docs/ros.md, "Time, and what a bag played into the node gives")."""

from __future__ import annotations

from typing import Any


class ClockGate:
    """An input whose clock reading equals its topic's previous stamp waits for the next tick."""

    def __init__(self) -> None:
        self.last: dict[str, int] = {}
        self.held: dict[str, Any] = {}

    def arrive(self, name: str, now_ns: int, item: Any) -> list[tuple[int, Any]]:
        """(stamp, item) pairs to process now, in order."""
        out = []
        if name in self.held:
            out.append((now_ns, self.held.pop(name)))
        elif self.last.get(name) == now_ns:
            self.held[name] = item
            return out
        self.last[name] = now_ns
        out.append((now_ns, item))
        return out

    def tick(self, now_ns: int) -> list[tuple[int, Any]]:
        """The clock moved to ``now_ns``: the held inputs to process now, stamped with it."""
        out = [(now_ns, item) for item in self.held.values()]
        for name in self.held:
            self.last[name] = now_ns
        self.held.clear()
        return out
