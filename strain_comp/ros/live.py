"""What a live transport does with each message, free of any transport.

The rclpy node and the DDS transport both hold one ``LiveCompensator``: it builds the
engine from validated node parameters, compiles its kernels at start-up (not on the first
message), applies the publish-rate limit and tunable changes, and turns health into
diagnostic statuses. The transports only move bytes, so a bag replayed through the node
logic gives exactly what ``replay`` gives.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from strain_comp.core.engine import ArrayOutput, Engine, SensorOutput, diagnostics
from strain_comp.errors import ParameterError
from strain_comp.ros.params import TUNABLE, NodeParams, validate_tunable


class LiveCompensator:
    """One engine plus the per-input publish bookkeeping of a live node."""

    def __init__(self, params: NodeParams, *, warm_up: bool = True) -> None:
        self.params = params
        self.tunables = dict(params.tunables)
        self.engine: Engine = params.build_engine()
        if warm_up:
            self.engine.warm_up()
        self._last_publish: dict[str, float] = {}
        self.temperature: dict[str, float] = {}
        self.n_errors = 0

    def _due(self, name: str, t: float) -> bool:
        """Publish-rate limit on message time: at most one output per 1/rate seconds."""
        rate = self.tunables["publish_rate_limit_hz"]
        last = self._last_publish.get(name)
        if rate > 0.0 and last is not None and 0.0 <= t - last < 1.0 / rate:
            return False
        self._last_publish[name] = t
        return True

    def on_sensor(self, name: str, t: float, value: float) -> SensorOutput | None:
        """Feed one resistance message; the output to publish, or None (rate limited)."""
        out = self.engine.step(name, t, value, self.temperature.get(name, math.nan))
        return out if self._due(name, t) else None

    def on_array(self, name: str, t: float, values: Any) -> ArrayOutput | None:
        """Feed one array message (values in the array's sensor order)."""
        out = self.engine.step_array(name, t, np.asarray(values, dtype=np.float64))
        return out if self._due(name, t) else None

    def on_temperature(self, name: str, value: float) -> None:
        """Remember a sensor's latest temperature [deg C] for its effect terms."""
        self.temperature[name] = float(value)

    def check_tunable(self, name: str, value: Any) -> float:
        """The validated value; ParameterError if out of range, unknown or read-only."""
        value = validate_tunable(name, value)
        if TUNABLE[name].read_only:
            raise ParameterError(name, "read-only: set it in the params file and restart")
        return value

    def set_tunable(self, name: str, value: Any) -> None:
        """Validate (``check_tunable``) and apply a tunable."""
        value = self.check_tunable(name, value)
        self.tunables[name] = value
        if name == "deadzone_scale":
            self.engine.set_deadzone_scale(value)
        elif name == "gap_reset_s":
            self.engine.gap_reset = value
        elif name == "stale_after_s":
            self.engine.stale_after = value

    def diagnostics(self, now: float) -> list[tuple[str, int, str, dict[str, str]]]:
        """Per-sensor statuses at clock time ``now`` [s] (plus the transport's own)."""
        statuses = diagnostics(self.engine.health(now))
        level = 1 if self.n_errors else 0
        statuses.append(("strain_comp: transport", level,
                         f"{self.n_errors} messages could not be handled" if self.n_errors
                         else "ok", {"n_errors": str(self.n_errors)}))
        return statuses
