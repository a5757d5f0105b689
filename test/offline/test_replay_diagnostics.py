"""Replay's /diagnostics, counted and encoded for many ticks at once
(``core.health.HealthCounter``, ``io.cdr.diagnostic_arrays``, ``offline.replay``),
are byte for byte what the engine stepped sample by sample and the per-message encoder
(mcap_ros2's, ``_library``) give at every tick, fused references included."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import changed_run, cubic_cal, lag_cal, line_calibration, noisy_stream
from mcap.reader import make_reader

from strain_comp.base.samples import STATUS_RULES, USED, Status
from strain_comp.core.calibration import Calibration
from strain_comp.core.chain import HELD, SPIKE, STEP
from strain_comp.core.engine import Engine
from strain_comp.core.fusion import SparseFusion
from strain_comp.core.health import (
    COUNTERS,
    HealthCounter,
    SensorHealth,
    diagnostics,
    times_text,
)
from strain_comp.core.outputs import BatchOutput
from strain_comp.io import cdr
from strain_comp.io.bag import BagWriter, read_bag
from strain_comp.io.recording import Recording
from strain_comp.offline import replay
from strain_comp.offline.fit import fit_sensor

PERIOD = 0.5


def gauge(s: np.ndarray) -> np.ndarray:
    """A gauge's resistance at strain ``s``: a mild quadratic."""
    return 1000.0 * (1.0 + 0.02 * s + 2e-4 * s ** 2)


def staircase(t: np.ndarray) -> np.ndarray:
    """Rest 10 s, then 20 s cycles: 3 s ramp to a level, 7 s hold there, 3 s back, 7 s rest."""
    phase = np.clip(t - 10.0, 0.0, None) % 20.0
    level = 5.0 + 5.0 * (np.clip(t - 10.0, 0.0, None) // 20.0 % 3)
    up = np.clip(phase / 3.0, 0.0, 1.0) - np.clip((phase - 10.0) / 3.0, 0.0, 1.0)
    return np.where(t < 10.0, 0.0, level * up)


def _found(path: Path) -> list[tuple[int, bytes]]:
    with path.open("rb") as handle:
        return [(m.log_time, m.data) for _, c, m in make_reader(handle).iter_messages()
                if c.topic == "/diagnostics"]


def _ticks(times: np.ndarray, period: float) -> np.ndarray:
    t0 = times.min()
    return t0 + period * (np.unique(np.floor((times - t0) / period)) + 1.0)


def _library(ns: int, frame_id: str,
             statuses: list[tuple[str, int, str, str, list[tuple[str, str]]]]) -> bytes:
    """One DiagnosticArray as mcap_ros2's encoder serialises it (the reference)."""
    return cdr.message_encoder("diagnostic_msgs/msg/DiagnosticArray")({
        "header": {"stamp": {"sec": ns // 10**9, "nanosec": ns % 10**9},
                   "frame_id": frame_id},
        "status": [{"level": level, "name": name, "message": message, "hardware_id": hw,
                    "values": [{"key": k, "value": v} for k, v in values]}
                   for name, level, message, hw, values in statuses]})


def _payload(tick: float, statuses: list[tuple[str, int, str, dict[str, str]]]
             ) -> tuple[int, bytes]:
    ns = round(tick * 1e9)
    return ns, _library(ns, "", [
        (name, level, message, "", list(values.items()))
        for name, level, message, values in statuses])


def _bag(path: Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Three sensors over ~300 s: faults of every kind, long silences (stale), gaps."""
    rng = np.random.default_rng(3)
    streams = {}
    for k, name in enumerate(("s1", "s2", "s3")):
        t, r = noisy_stream(rng, n=1500)
        t = (np.sort(t) - t.min()) * (12.0 + 4 * k) + 50.0  # ~8 to ~5 Hz
        t[t.size // 2:] += 40.0  # a silence of 40 s: stale ticks, a gap reset
        streams[name] = (t, r)
    with BagWriter(path) as writer:
        for name, (t, r) in streams.items():
            writer.write_float64(f"/{name}/resistance", t, r)
    contents = read_bag(path)  # the times as stored (integer ns)
    return {name: (contents.series[f"/{name}/resistance"].t,
                   contents.series[f"/{name}/resistance"].values) for name in streams}


def _stepped(cal: Calibration, streams: dict[str, tuple[np.ndarray, np.ndarray]]
             ) -> list[tuple[int, bytes]]:
    """The /diagnostics a node would publish at each tick: the engine stepped sample by
    sample, ``health(now=tick)``, ``_library`` per message."""
    events = sorted((float(t), name, float(r)) for name, (ts, rs) in streams.items()
                    for t, r in zip(ts, rs, strict=True))
    engine = Engine(cal)
    found, i = [], 0
    for tick in _ticks(np.array([e[0] for e in events]), PERIOD).tolist():
        while i < len(events) and events[i][0] <= tick:
            engine.step(events[i][1], events[i][0], events[i][2])
            i += 1
        found.append(_payload(tick, diagnostics(engine.health(now=tick))))
    return found


@pytest.mark.parametrize("window", [700, 10**6])
def test_replay_diagnostics_equal_the_engine_stepped_tick_by_tick(tmp_path: Path,
                                                                  window: int) -> None:
    cal = Calibration({"s1": lag_cal("s1"), "s2": cubic_cal("s2"), "s3": lag_cal("s3")})
    streams = _bag(tmp_path / "in.mcap")
    replay.replay_bag(tmp_path / "in.mcap", cal, tmp_path / "out.mcap", window=window,
               diagnostics_period=PERIOD)
    found, expected = _found(tmp_path / "out.mcap"), _stepped(cal, streams)
    assert len(found) == len(expected) > 500
    assert found == expected
    levels = {p[p.index(b"strain_comp: s1") - 8] for _, p in expected}
    assert levels >= {0, 2, 3}  # ok, bad input and stale ticks all compared


def _fused_bag(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``changed_run`` with wrong references around 95 s and 185 s (refused beyond the
    gate: the fusion's keys grow mid-run) and a 60 s silence."""
    t, r, s = changed_run(300.0)
    s = s + 500.0 * ((np.abs(t - 95.0) < 6.0) | (np.abs(t - 185.0) < 6.0))
    keep = (t < 120.0) | (t > 180.0)
    t, r, s = t[keep], r[keep], s[keep]
    with BagWriter(path) as w:
        w.write_float64("/s1/resistance", t, r)
        w.write_float64("/s1/strain_reference", t, s)
    contents = read_bag(path)
    return (contents.series["/s1/resistance"].t, contents.series["/s1/resistance"].values,
            contents.series["/s1/strain_reference"].values)


def test_fused_replay_diagnostics_equal_the_fusion_judged_tick_by_tick(tmp_path: Path
                                                                       ) -> None:
    """Each tick's ``fusion_*`` values: the fusion's after the last reference judged at or
    before the tick, the whole run fused at once; health from the engine stepped."""
    cal = line_calibration()
    t, r, s = _fused_bag(tmp_path / "in.mcap")
    replay.replay_bag(tmp_path / "in.mcap", cal, tmp_path / "out.mcap", window=700,
               diagnostics_period=PERIOD, references_every=5.0)
    fusion = SparseFusion.for_calibration(cal.sensors["s1"], 5.0, record=True)
    state0 = fusion.fusion.diagnostic_values()
    fusion.fuse(t, Engine(cal).run("s1", t, r), s)
    engine, expected, i = Engine(cal), [], 0
    for tick in _ticks(t, PERIOD).tolist():
        while i < t.size and t[i] <= tick:
            engine.step("s1", float(t[i]), float(r[i]))
            i += 1
        [(name, level, message, values)] = diagnostics(engine.health(now=tick))
        judged = [v for when, v in fusion.judged if when <= tick]
        expected.append(_payload(tick, [(name, level, message,
                                         {**values, **(judged[-1] if judged else state0)})]))
    found = _found(tmp_path / "out.mcap")
    assert found == expected
    refused = [p for _, p in found if b"fusion_refused[beyond the gate]" in p]
    assert 0 < len(refused) < len(found)  # the key set changed mid-run


def test_fused_replay_encodes_as_message_by_message(tmp_path: Path,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    """A rest that falls after each release, fused: the columns encoded at once are the
    bytes of ``_library`` per message of the same columns."""
    t = np.arange(0.0, 70.0, 0.1)
    cal = Calibration({"s1": fit_sensor([Recording("s1", t, gauge(staircase(t)),
                                                   staircase(t))], "cubic", name="s1")})
    t = np.arange(0.0, 190.0, 0.1)
    s = staircase(t)
    r = gauge(s) * (1.0 - 0.01 * np.clip(np.floor((t - 10.0) / 20.0), 0.0, None))
    with BagWriter(tmp_path / "in.mcap") as w:
        w.write_float64("/s1/resistance", t, r)
        w.write_float64("/s1/strain_reference", t, s + 50.0 * (np.abs(t - 95.0) < 3.0))
    replay.replay_bag(tmp_path / "in.mcap", cal, tmp_path / "fast.mcap", window=300,
               references_every=5.0)

    def one_by_one(t_ns: np.ndarray, frame_id: str, statuses: list[cdr.Status]
                   ) -> tuple[np.ndarray, np.ndarray]:
        payloads = [_library(ns, frame_id, [
            (name, int(levels[k]), _at(message, k), hw,
             [(key, _at(value, k)) for key, value in values])
            for levels, name, message, hw, values in statuses])
            for k, ns in enumerate(t_ns.tolist())]
        return (np.frombuffer(b"".join(payloads), np.uint8),
                np.array([len(p) for p in payloads], np.int64))

    monkeypatch.setattr(replay, "diagnostic_arrays", one_by_one)
    replay.replay_bag(tmp_path / "in.mcap", cal, tmp_path / "slow.mcap", window=300,
               references_every=5.0)
    fast = _found(tmp_path / "fast.mcap")
    assert fast == _found(tmp_path / "slow.mcap")
    assert any(b"fusion_refused[beyond the gate]" in p for _, p in fast)


def _at(value: str | np.ndarray, k: int) -> str:
    """A ``diagnostic_arrays`` text at message k: constant, UTF-8 bytes, or an integer."""
    if isinstance(value, str):
        return value
    item = value[k]
    return item.decode() if isinstance(item, bytes) else str(item)


def _health_at(before: SensorHealth, t: np.ndarray, out: BatchOutput, tick: float,
               stale_after: float) -> SensorHealth:
    """The health at ``tick``, counted sample by sample (``STATUS_RULES``)."""
    h = replace(before)
    for i in np.flatnonzero(np.maximum.accumulate(t) <= tick).tolist():
        status = Status(int(out.status[i]))
        used, counter = STATUS_RULES[status]
        h.n_good += used
        if counter is not None:
            setattr(h, counter, getattr(h, counter) + 1)
        h.n_gaps += int(out.reset is not None and out.reset[i])
        correction = 0 if out.corrections is None else int(out.corrections[i])
        h.n_spikes += correction == SPIKE
        h.n_baseline_steps += correction == STEP
        h.last_status = status
        if status in USED:
            h.last_good_t = float(t[i])
    h.stale = h.last_good_t is None or tick - h.last_good_t > stale_after
    return h


def test_health_counter_equals_the_counts_sample_by_sample() -> None:
    """Field by field and as key-values, with a ``before`` that has counts, resets, input
    corrections and time running back."""
    rng = np.random.default_rng(5)
    n = 400
    t = np.cumsum(rng.uniform(-0.05, 0.3, n)) + 10.0
    status = rng.choice(len(Status), n, p=[0.6, *[0.4 / (len(Status) - 1)] * (len(Status) - 1)])
    out = BatchOutput(np.zeros(n), np.zeros(n, np.int8), status.astype(np.int8),
                      np.zeros(n, bool), np.zeros(n), rng.random(n) < 0.05,
                      rng.choice(np.array([0, HELD, SPIKE, STEP], np.int8), n,
                                 p=[0.85, 0.05, 0.05, 0.05]))
    before = SensorHealth(n_good=7, n_nan=2, n_gaps=1, last_good_t=9.5,
                          last_status=Status.NOT_FINITE)
    ticks = np.concatenate(([5.0, 9.9], np.linspace(10.0, t.max() + 3.0, 300)))
    assert {c for _, c in STATUS_RULES.values() if c} <= set(COUNTERS)
    for b in (before, SensorHealth()):
        found = HealthCounter(b, t, out).at(ticks, stale_after=0.4)
        levels, messages, values = found.diagnostic(times_text(found.last_good_t))
        for k, tick in enumerate(ticks.tolist()):
            h = _health_at(b, t, out, tick, 0.4)
            assert found.counters[k].tolist() == [getattr(h, c) for c in COUNTERS]
            level, message, expected = h.to_diagnostic()
            assert (int(levels[k]), messages[k].decode()) == (level, message)
            assert {key: _at(v, k) for key, v in values} == expected
    odd = np.array([0.0, -0.0, np.nan, 1e-7, 1e22, 0.1 + 0.2, 2.0**31, 0.0, 1e-7])
    assert times_text(odd).tolist() == [b"none" if v != v else repr(v).encode()
                                        for v in odd.tolist()]
    silent = HealthCounter(replace(before, stale=False)).at(ticks, stale_after=0.4)
    assert silent.stale.tolist() == (ticks - 9.5 > 0.4).tolist()


def test_diagnostic_arrays_equal_diagnostic_array_per_message() -> None:
    """Texts of every length (every alignment), UTF-8, constant and per-message fields,
    integers of every sign and size."""
    rng = np.random.default_rng(2)
    k = 60
    words = ["", "a", "ab", "abc", "abcd", "été", "x" * 37]
    t_ns = np.sort(rng.integers(0, 2**31 * 10**9, k))
    columns = [np.array([rng.choice(words).encode() for _ in range(k)]) for _ in range(4)]
    levels = [rng.integers(0, 4, k).astype(np.uint8) for _ in range(3)]
    numbers = rng.integers(-10**12, 10**12, k) // 10 ** rng.integers(0, 13, k)
    statuses: list[cdr.Status] = [
        (levels[0], "strain_comp: a", columns[0], "",
         [("n", columns[1]), ("count", numbers), ("held", np.repeat(numbers[::4], 4))]),
        (levels[1], "é", "ok", "hw", []),
        (levels[2], "c", columns[2], "", [("k1", "v"), ("kk2", columns[3])])]
    blob, lengths = cdr.diagnostic_arrays(t_ns, "frame", statuses)
    ends = np.cumsum(lengths)
    for j, ns in enumerate(t_ns.tolist()):
        expected = _library(ns, "frame", [
            (name, int(lv[j]), _at(msg, j), hw, [(key, _at(v, j)) for key, v in values])
            for lv, name, msg, hw, values in statuses])
        assert blob[ends[j] - lengths[j]:ends[j]].tobytes() == expected


@pytest.mark.parametrize("rig", [False, True])
def test_ticks_flushed_batch_by_batch_keep_the_order_of_one_log_time(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, rig: bool) -> None:
    """Inputs stamped on the ticks themselves (outputs, /diagnostics and copied inputs of
    one log time), with or without a /diagnostics input copied through: the bag written a
    few ticks at a time, each batch's slice of log time flushed (``replay.StagedWrites``), is
    the bag written in one go, in the order replay adds a piece's messages."""
    t = np.arange(0.0, 600.0, 0.5)
    with BagWriter(tmp_path / "in.mcap") as writer:
        writer.write_float64("/s1/resistance", t, 150.0 + 30.0 * np.sin(0.05 * t))
        writer.write_float64("/s2/resistance", t[::3], 140.0 + 20.0 * np.cos(0.03 * t[::3]))
        writer.write_temperature("/s1/temperature", t[::7], 25.0 + 0.01 * t[::7])
        if rig:
            writer.write_diagnostics(t[::40], [[("rig", 0, "ok", {"k": "v"})]] * t[::40].size)
    cal = Calibration({"s1": cubic_cal("s1"), "s2": cubic_cal("s2")})
    outputs = []
    for batch in (3, 10**9):
        monkeypatch.setattr(replay, "TICK_BATCH", batch)
        out = tmp_path / f"out_{batch}.mcap"
        replay.replay_bag(tmp_path / "in.mcap", cal, out, window=500)
        outputs.append(out.read_bytes())
    assert outputs[0] == outputs[1]
    # as written unbatched: at one log time the outputs, then /diagnostics, then the
    # copied inputs; channels numbered in that order
    with (tmp_path / "out_3.mcap").open("rb") as handle:
        reader = make_reader(handle)
        summary = reader.get_summary()
        order = [(m.log_time, _role(c.topic, m.data))
                 for _, c, m in reader.iter_messages(log_time_order=False)]
    assert summary is not None
    assert order == sorted(order)
    assert len({time for time, _ in order}) < len(order)  # times shared
    assert {role for _, role in order} == {0, 1, 2}
    assert any(b"rig" in p for _, p in _found(tmp_path / "out_3.mcap")) == rig
    ids = sorted(summary.channels.values(), key=lambda c: c.id)
    roles = [_role(c.topic, b"") for c in ids]
    assert roles == sorted(roles), [c.topic for c in ids]


def _role(topic: str, data: bytes) -> int:
    """0: an output, 1: replay's /diagnostics, 2: a copied input (the rig's diagnostics)."""
    if topic == "/diagnostics":
        return 2 if b"rig" in data else 1
    return 2 if topic.endswith(("/resistance", "/temperature")) else 0
