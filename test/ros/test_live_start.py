"""``~/start`` without ROS: it watches the next stretch and return on the reference, then
applies the session start, and the sensor whose rest and sensitivity moved reads the
reference again; twice, during a stretch or without a reference it answers and goes on."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import S_HI, S_LO, cubic_cal, one_message

from strain_comp.core.calibration import Calibration
from strain_comp.core.calibration_file import save_calibration
from strain_comp.errors import ParameterError
from strain_comp.offline.session_start import calibrated_resistance
from strain_comp.ros.live import LiveCompensator
from strain_comp.ros.params import parse_values

CAL = cubic_cal("s1")
REST = S_LO + 0.05 * (S_HI - S_LO) / 1.1
R0 = calibrated_resistance(CAL, REST)


def moved(strain: float) -> float:
    """The sensor today: its rest 5 ohm higher, 40 % more sensitive."""
    return R0 + 5.0 + 1.4 * (calibrated_resistance(CAL, strain) - R0)


def node(tmp_path: Path) -> LiveCompensator:
    save_calibration(Calibration({"s1": replace(CAL, rest_resistance=R0)}), tmp_path / "c.yaml")
    return LiveCompensator(parse_values({"sensors": ["s1"], "s1.calibration": "c.yaml",
                                         "baseline_tracking": "off"}, base_dir=tmp_path))


def stretch(t0: float, seconds: float = 20.0, peak: float = 30.0) -> list[tuple[float, float]]:
    """(time, strain) at 20 Hz: a rest, a load to ``peak`` and back, a rest."""
    t = t0 + np.arange(0.0, seconds, 0.05)
    phase = np.clip((t - t0 - 4.0) / (seconds - 8.0), 0.0, 1.0)
    s = REST + (peak - REST) * np.sin(np.pi * phase) ** 2
    return list(zip(t.tolist(), s.tolist(), strict=True))


def feed(live: LiveCompensator, samples: list[tuple[float, float]],
         reference: bool = True) -> tuple[LiveCompensator, list[float]]:
    """Each sample's resistance, then its reference (``start_reference``, as the node)."""
    errors = []
    for t, s in samples:
        out = one_message(live, "s1", t, moved(s))
        if out is not None:
            errors.append(out.strain - s)
        if reference:
            live = live.start_reference("s1", t, s)
    return live, errors


def status(live: LiveCompensator) -> tuple[str, int, str, dict[str, str]]:
    """The ``strain_comp: session start`` diagnostic status."""
    return next(d for d in live.diagnostics(0.0) if d[0] == "strain_comp: session start")


def state(live: LiveCompensator) -> str:
    return status(live)[3]["state"]


def test_start_watches_a_stretch_then_reads_the_reference(tmp_path: Path) -> None:
    live = node(tmp_path)
    live, before = feed(live, stretch(0.0))
    assert state(live) == "idle"
    live, message = live.start(20.0)
    assert "waiting" in message and state(live) == "waiting"
    with pytest.raises(ParameterError, match="already waiting"):
        live.start(20.5)  # twice: refused, the watch goes on
    live, _ = feed(live, stretch(20.0)[:150])
    assert state(live) == "recording"
    with pytest.raises(ParameterError, match="already recording"):
        live.start(27.5)
    live, _ = feed(live, stretch(20.0)[150:])
    assert state(live) == "applied", live.starting.detail
    assert "stretch RMSE" in live.starting.detail
    assert live.params.calibration.sensors["s1"].input.zero_span is not None
    live, after = feed(live, stretch(40.0))
    rms = [float(np.sqrt(np.mean(np.square(e)))) for e in (before, after)]
    assert rms[1] < 0.2 * rms[0] and rms[1] < 0.5  # the moved sensor reads the reference
    live, message = live.start(60.0)  # again after an applied start: a new watch
    assert state(live) == "waiting"


def test_start_called_during_a_stretch_waits_for_a_whole_one(tmp_path: Path) -> None:
    live = node(tmp_path)
    samples = stretch(0.0)
    live, _ = feed(live, samples[:100])  # a reference seen: the watch is possible
    live, _ = live.start(samples[100][0])  # mid-load
    live, _ = feed(live, samples[100:])
    assert state(live) in ("recording", "applied", "refused")
    live, _ = feed(live, stretch(20.0))
    assert state(live) == "applied", live.starting.detail


def test_start_without_a_reference_spans_or_says_why(tmp_path: Path) -> None:
    live = node(tmp_path)
    live, _ = feed(live, stretch(0.0), reference=False)
    with pytest.raises(ParameterError, match="span_strain"):
        live.start(20.0)
    assert state(live) == "refused" and "no reference" in live.starting.detail
    assert status(live)[1] == 1 and "span_strain" in status(live)[2]  # WARN, and why
    live.set_tunable("span_strain", 30.0)
    live, _ = feed(live, [(20.0 + 0.05 * i, 30.0) for i in range(20)], reference=False)
    live, message = live.start(21.0)
    assert "span" in message and state(live) == "applied"
    out = one_message(live, "s1", 22.0, moved(30.0))
    assert out is not None and out.strain == pytest.approx(30.0, abs=0.5)


def test_a_stretch_that_never_returns_is_refused(tmp_path: Path) -> None:
    live = node(tmp_path)
    live, _ = feed(live, stretch(0.0)[:10])
    live, _ = live.start(0.5)
    held = [(0.5 + 0.5 * i, 25.0) for i in range(1300)]  # loaded for 650 s
    live, _ = feed(live, held)
    assert state(live) == "refused" and "within 600 s" in live.starting.detail
