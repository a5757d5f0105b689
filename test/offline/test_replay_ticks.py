"""Replay's /diagnostics of a long, sparse bag: built a batch of ticks at a time (memory
bounded however long a piece lasts), the same bag as built all at once."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from strain_comp.core.calibration_file import load_calibration
from strain_comp.io.bag import BagWriter
from strain_comp.offline import replay

ROOT = Path(__file__).resolve().parents[2]


def test_diagnostics_in_tick_batches_equal_all_at_once(tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    bag = tmp_path / "sparse.mcap"
    t = np.sort(np.random.default_rng(0).uniform(0.0, 2000.0, 900))
    r = 15.0 + 4.0 * np.sin(0.01 * t)
    r[::50] = np.nan  # bad samples counted in the healths
    with BagWriter(bag) as writer:
        writer.write_float64("/s1/resistance", t, r)
    cal = load_calibration(ROOT / "config" / "demo_calibration.yaml")
    outputs = []
    for batch in (7, 10**9):
        monkeypatch.setattr(replay, "TICK_BATCH", batch)
        out = tmp_path / f"out_{batch}.mcap"
        replay.replay_bag(bag, cal, out)
        outputs.append(out.read_bytes())
    assert outputs[0] == outputs[1]
    with (tmp_path / "out_7.mcap").open("rb") as handle:
        summary = make_reader(handle).get_summary()
    assert summary is not None and summary.statistics is not None
    diag = [c.id for c in summary.channels.values() if c.topic == "/diagnostics"]
    # one DiagnosticArray per second holding input: hundreds of ticks in a piece
    assert summary.statistics.channel_message_counts[diag[0]] > 300
