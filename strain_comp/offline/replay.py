"""Offline replay: a bag's resistance through the engine's batch path into a new bag on the
node's topics (docs/design.md, "Topics"), each output at its input's log time; temperatures
and references held at their latest value, as the node holds them."""

from __future__ import annotations

import itertools
import math
import os
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt

from strain_comp.base.samples import DEFAULT_GAP_RESET
from strain_comp.core.calibration import Calibration
from strain_comp.core.engine import Engine
from strain_comp.core.fusion import SparseFusion
from strain_comp.core.health import (
    HealthCounter,
    HealthTicks,
    SensorHealth,
    status_name,
    times_text,
)
from strain_comp.core.outputs import BatchOutput
from strain_comp.core.tare import tare_engine
from strain_comp.errors import BagError, InputError
from strain_comp.io.bag import BagContents, BagWriter, Series, iter_bag, located
from strain_comp.io.bag.reader import WINDOW
from strain_comp.io.bag.schemas import Status as DiagnosticStatus
from strain_comp.io.cdr import Status, diagnostic_arrays
from strain_comp.io.recording import (
    hold_latest,
    reference_columns,
    temperature_series,
    topic_sensors,
)
from strain_comp.offline.series import PendingSeries, SeriesCSV, series_csv

OUTPUTS = ("strain", "direction", "status")
TICK_BATCH = 1024
"""/diagnostics ticks counted and encoded at once (a long sparse piece holds thousands)."""
STAMPED = "strain_stamped"
BAND = ("strain_std", "strain_std_stamped")
"""The standard deviation's outputs, where the calibration holds an uncertainty."""
RESISTANCE_TYPES = ("std_msgs/msg/Float64", "std_msgs/msg/Float32",
                    "std_msgs/msg/Float64MultiArray")
"""Message types a ``/NAME/resistance`` input is read from; other types are copied only."""


@dataclass
class ReplaySummary:
    """What ``replay_bag`` did: sensors and arrays replayed, health, messages, problems."""

    out_path: Path
    sensors: dict[str, SensorHealth]
    arrays: dict[str, list[str]]
    n_input_messages: int
    """Every input message copied through (references, temperatures and others included)."""
    n_output_messages: int
    problems: list[str] = field(default_factory=list)
    n_compensated: int = 0
    """Resistance messages run through the engine (an array message counts once)."""
    references: dict[str, dict[str, float]] = field(default_factory=dict)
    """Per fused sensor, ``OutputFusion.state`` and ``every``."""


@dataclass
class _Input:
    topic: str
    name: str
    sensors: list[str]
    is_array: bool


def _input(topic: str, contents: BagContents, calibration: Calibration) -> _Input | None:
    """The input of a topic whose sensors are all calibrated, else None (copied only)."""
    if contents.types.get(topic) not in RESISTANCE_TYPES:  # e.g. Temperature: never ohm
        return None
    sensors, _ = topic_sensors(topic, contents)
    if not all(name in calibration.sensors for name in sensors):
        return None
    return _Input(topic, topic[1:].rsplit("/", 1)[0], sensors,
                  contents.series[topic].values.ndim == 2)


class _Replay:
    """The state carried from one piece of the bag to the next."""

    def __init__(self, calibration: Calibration, writer: BagWriter, engine: Engine,
                 period: float, tare: str, series: SeriesCSV | None = None,
                 references_every: float | None = None) -> None:
        self.calibration = calibration
        self.references_every = references_every
        self.fused: dict[str, SparseFusion] = {}
        self.reference: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        """Per sensor with a reference sample so far, its latest (t, value)."""
        self.series = series
        self.pending: dict[str, PendingSeries] = {}
        self.tare = tare
        self.writer = writer
        self.out = StagedWrites()
        self.engine = engine
        self.period = period
        self.inputs: dict[str, _Input | None] = {}
        self.t0: float | None = None
        self.ticks = np.empty(0)
        """Diagnostics ticks not yet written (later messages may fall before them)."""
        self.temperature: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        """Per sensor, its latest temperature sample so far (t, value), to hold across pieces."""
        self.n_in = 0
        self.n_out = 0
        self.n_compensated = 0
        self.problems: list[str] = []
        self.written: set[str] = {"/diagnostics"}
        self._contents = BagContents()

    def piece(self, contents: BagContents) -> None:
        """Replay one piece: outputs, ticks, copied inputs, in slices of ``TICK_BATCH`` ticks."""
        self.problems += contents.problems
        self._discover(contents)
        self._contents = contents
        inputs = [(inp, contents.series[topic]) for topic, inp in self.inputs.items()
                  if inp is not None and topic in contents.series
                  and contents.series[topic].t.size]
        self.out = StagedWrites()
        now, counters, fusion = self._run(contents, inputs) if inputs else (np.empty(0), {}, {})
        copies = StagedWrites()
        self.n_in += _copy_through(contents, copies, self.written, self._problem)
        # a bag's own /diagnostics shares the channel: copied after all the piece's ticks,
        # as its sequence numbers have always counted them, so the piece is one slice
        shared = "/diagnostics" in contents.types
        edges = [] if shared else now[TICK_BATCH::TICK_BATCH].tolist()
        for k, (lo, hi) in enumerate(itertools.pairwise([-math.inf, *edges, None])):
            self.out.write(self.writer, lo, hi)
            ticks = now if shared else now[k * TICK_BATCH:(k + 1) * TICK_BATCH]
            for a in range(0, ticks.size, TICK_BATCH):
                self.write_diagnostics(ticks[a:a + TICK_BATCH], counters, fusion)
            copies.write(self.writer, lo, hi)
            if hi is not None:
                self.writer.flush(before=hi)
        for fused in self.fused.values():
            fused.judged.clear()
        self.writer.flush(before=float(self.ticks[0]) if self.ticks.size else None)

    def _discover(self, contents: BagContents) -> None:
        """Take each new ``/NAME/resistance`` topic as an input (tared, fused) or not."""
        for topic in sorted(contents.series):  # as load_recordings: the first topic wins
            if topic.endswith("/resistance") and topic not in self.inputs:
                inp = _input(topic, contents, self.calibration)
                taken = {s for i in self.inputs.values() if i is not None for s in i.sensors}
                if inp is not None and not taken.isdisjoint(inp.sensors):
                    self._problem(f"{topic}: sensor {min(taken & set(inp.sensors))} appears "
                                  "twice; the topic copied, not replayed")
                    inp = None
                self.inputs[topic] = inp
                if inp is not None:
                    self.written.update(f"/{inp.name}/{what}"
                                        for what in (*OUTPUTS, STAMPED, *BAND))
                    series = contents.series[topic]
                    values = series.values if series.values.ndim == 2 else series.values[:, None]
                    tared = tare_engine(self.engine, {s: (series.t, values[:, j])
                                                      for j, s in enumerate(inp.sensors)},
                                        self.tare)
                    self.problems += [f"{s}: {line}" for s, line in tared.items()]
                    if self.references_every is not None:
                        self.fused.update({s: SparseFusion.for_calibration(
                            self.calibration.sensors[s], self.references_every, record=True)
                            for s in inp.sensors})

    def _problem(self, line: str) -> None:
        if line not in self.problems:
            self.problems.append(line)

    def _run(self, contents: BagContents, inputs: list[tuple[_Input, Series]]
             ) -> tuple[np.ndarray, dict[str, HealthCounter], dict[str, FusionTicks]]:
        """Stage the outputs of ``inputs``; the ticks completed, healths and fusion states."""
        t_all = np.concatenate([series.t for _, series in inputs])
        if self.t0 is None:
            self.t0 = float(t_all.min())
        # a diagnostics tick at the end of every period that holds messages
        new = self.t0 + self.period * (np.unique(np.floor((t_all - self.t0) / self.period))
                                       + 1.0)
        ticks = np.union1d(self.ticks, new)
        t_last = float(t_all.max())
        now, self.ticks = ticks[ticks < t_last], ticks[ticks >= t_last]
        # each input runs once over the piece; the health at each tick inside it comes
        # from the cumulative status counts of the samples at or before the tick
        before = self.engine.health()
        fusion_before = {s: f.fusion.diagnostic_values() for s, f in self.fused.items()}
        ran: dict[str, tuple[np.ndarray, BatchOutput]] = {}
        for inp, series in inputs:
            outs = self._outputs(inp, series.t, series.values, {
                s: self._temperature(contents, s, series.t) for s in inp.sensors})
            self.n_compensated += series.t.size
            if self.series is not None:
                self._series(inp, series, outs)
            ran.update({s: (series.t, out) for s, out in outs.items()})
        counters = {name: HealthCounter(h, *ran.get(name, (None, None)))
                    for name, h in before.items()}
        fusion = {s: FusionTicks(fusion_before[s], list(f.judged))
                  for s, f in self.fused.items()}
        return now, counters, fusion

    def _series(self, inp: _Input, series: Series, outs: dict[str, BatchOutput]) -> None:
        """Queue the piece's rows of ``replay --csv`` with the piece's reference samples."""
        assert self.series is not None
        values = series.values if series.values.ndim == 2 else series.values[:, None]
        for j, name in enumerate(inp.sensors):
            cal = self.calibration.sensors[name]
            pending = self.pending.setdefault(name, PendingSeries(name, cal.strain_unit))
            out = outs[name]
            pending.add(series.t, cal.input.to_ohm(values[:, j]), out.strain, out.direction,
                        out.status, *self._reference(inp, name))
            pending.flush(self.series)

    def write_diagnostics(self, ticks: np.ndarray, counters: dict[str, HealthCounter],
                           fusion: dict[str, FusionTicks]) -> None:
        """One /diagnostics message per tick (``diagnostic_payloads``)."""
        healths = {name: c.at(ticks, stale_after=self.engine.stale_for(name))
                   for name, c in counters.items()}
        for run, blob, lengths in diagnostic_payloads(ticks, healths, fusion):
            self.writer.write_diagnostic_payloads(ticks[run], blob, lengths)
        self.n_out += ticks.size

    def _outputs(self, inp: _Input, t: np.ndarray, values: np.ndarray,
                 temps: dict[str, np.ndarray | None]) -> dict[str, BatchOutput]:
        """Run ``inp``'s piece and stage its outputs."""
        if inp.is_array:  # cross-talk terms read the same tick's neighbours, as online
            outs = self.engine.run_array(inp.sensors, t, values, temps)
        else:
            outs = {inp.name: self.engine.run(inp.name, t, values, temps[inp.name])}
        outs = self._fused(inp, t, outs)
        columns = {what: np.stack([getattr(outs[s], what) for s in inp.sensors], axis=1)
                   for what in OUTPUTS}
        if any(outs[s].std is not None for s in inp.sensors):
            columns[BAND[0]] = np.stack([np.full(t.size, np.nan) if (v := outs[s].std) is None
                                         else v for s in inp.sensors], axis=1)
        for what, stacked in columns.items():
            self._stage(inp, what, t, stacked)
        self.n_out += (len(OUTPUTS) + 1) * t.size
        return outs

    def _stage(self, inp: _Input, what: str, t: np.ndarray, stacked: np.ndarray) -> None:
        """Hold the output ``what`` of ``inp`` (a column per sensor) and its stamped twin."""
        topic = f"/{inp.name}/{what}"
        if inp.is_array:
            self.out.add(t, _copier("write_float64_array", topic, t, stacked, inp.sensors))
        else:
            method = "write_int8" if what in ("direction", "status") else "write_float64"
            self.out.add(t, _copier(method, topic, t, stacked[:, 0]))
        if what in ("strain", BAND[0]):
            stamped = f"/{inp.name}/{STAMPED if what == 'strain' else BAND[1]}"
            self.out.add(t, lambda w, i: w.write_joint_state(stamped, t[i], inp.sensors,
                                                              stacked[i]))

    def _fused(self, inp: _Input, t: np.ndarray, outs: dict[str, BatchOutput]
               ) -> dict[str, BatchOutput]:
        """``outs`` with the latest reference at each sample fused, as the node does."""
        if self.references_every is None:
            return outs
        for name in inp.sensors:
            src_t, src_v = self._reference(inp, name)
            ok = np.isfinite(src_t) & np.isfinite(src_v)
            values = _held(self.reference, name, src_t[ok], src_v[ok], t)
            outs[name] = self.fused[name].fuse(
                t, outs[name], np.full(t.size, np.nan) if values is None else values)
        return outs

    def _temperature(self, contents: BagContents, name: str, t: np.ndarray
                     ) -> np.ndarray | None:
        """The latest temperature at or before each of ``t`` (NaN before the first)."""
        series = temperature_series(contents, name)
        empty = np.empty(0)
        return _held(self.temperature, name, empty if series is None else series.t,
                     empty if series is None else series.values, t)

    def _reference(self, inp: _Input, name: str) -> tuple[np.ndarray, np.ndarray]:
        """The piece's reference samples (t, value) of sensor ``name`` of ``inp``."""
        ref = self._contents.series.get(f"/{inp.name}/strain_reference")
        if ref is None:
            return np.empty(0), np.empty(0)
        columns, problem = reference_columns(self._contents, inp.topic)
        if problem is not None:
            self._problem(problem)
        if name not in columns:
            return np.empty(0), np.empty(0)
        column = columns[name]
        return ref.t, ref.values if column is None else ref.values[:, column]


def _held(latest: dict[str, tuple[np.ndarray, np.ndarray]], name: str, src_t: np.ndarray,
          src_v: np.ndarray, t: np.ndarray) -> np.ndarray | None:
    """``hold_latest`` carried across pieces in ``latest``; None: no sample yet."""
    if name in latest:
        src_t = np.concatenate((latest[name][0], src_t))
        src_v = np.concatenate((latest[name][1], src_v))
    if not src_t.size:
        return None
    order = np.argsort(src_t, kind="stable")
    latest[name] = (src_t[order][-1:], src_v[order][-1:])
    return hold_latest(t, src_t, src_v)


def replay_bag(in_path: str | os.PathLike[str], calibration: Calibration,
               out_path: str | os.PathLike[str], *, diagnostics_period: float = 1.0,
               gap_reset: float = DEFAULT_GAP_RESET, window: int = WINDOW,
               tare: str = "calibration",
               inputs: Sequence[str | os.PathLike[str]] = (),
               csv: str | os.PathLike[str] | None = None,
               references_every: float | None = None) -> ReplaySummary:
    """Replay ``in_path`` into a new bag at ``out_path``, written atomically, by pieces."""
    engine = Engine(calibration, gap_reset=gap_reset)
    out_path = Path(out_path)
    with series_csv(csv, inputs=[in_path, *inputs, out_path]) as table, \
            BagWriter(out_path, inputs=[in_path, *inputs]) as writer:
        state = _Replay(calibration, writer, engine, diagnostics_period, tare, table,
                        references_every)
        for contents in iter_bag(in_path, window=window):
            state.piece(contents)
        inputs = [i for i in state.inputs.values() if i is not None]
        if not inputs:  # the bag's damage, if any, may be why
            raise BagError("; ".join([f"no /NAME/resistance topic for any calibrated "
                                      f"sensor ({', '.join(calibration.sensors)})",
                                      *located(in_path, state.problems)]))
        missing = [s for s in state.fused if s not in state.reference]
        if missing:
            raise InputError(f"--references-every {references_every:g}: {', '.join(missing)} "
                             "has no strain_reference in the bag (the references fused are "
                             "the bag's own /NAME/strain_reference)")
        # the ticks after the last input: the engine's health now
        state.write_diagnostics(state.ticks, {
            name: HealthCounter(h) for name, h in engine.health().items()},
            {s: FusionTicks(f.fusion.diagnostic_values(), []) for s, f in state.fused.items()})
        if table is not None:  # every row still waiting for its reference
            for pending in state.pending.values():
                pending.flush(table, final=True)
    replayed = {s for i in inputs for s in i.sensors}
    problems = state.problems + [
        f"calibrated sensor {s!r} has no input topic in the bag: not replayed "
        "(STALE in /diagnostics)" for s in calibration.sensors if s not in replayed]
    return ReplaySummary(out_path, engine.health(), {i.name: i.sensors for i in inputs
                                                    if i.is_array},
                         state.n_in, state.n_out + state.n_in, located(in_path, problems),
                         state.n_compensated,
                         {s: {"every": f.every, **f.fusion.state()}
                          for s, f in state.fused.items()})


Call = Callable[[BagWriter, np.ndarray], None]
"""A held write: the writer and the indices (ascending) of the messages to write now."""


class StagedWrites:
    """A piece's ``BagWriter`` calls, held until ``write`` makes them slice by slice."""
    # every call is made in every slice, empty ones too: topics named and numbered as in one go

    def __init__(self) -> None:
        self.calls: list[tuple[np.ndarray, np.ndarray, Call]] = []
        """(times [ns] in order, the order of the messages by time, the write)."""

    def add(self, t: npt.ArrayLike, call: Call) -> None:
        """Hold ``call``, a write of messages at the log times ``t`` [s]."""
        t_ns = np.round(np.asarray(t, np.float64).reshape(-1) * 1e9)
        order = np.argsort(t_ns, kind="stable")  # NaN last
        self.calls.append((t_ns[order], order, call))

    def write(self, writer: BagWriter, lo: float, hi: float | None) -> None:
        """Write the messages of log times [s] in [``lo``, ``hi``); ``hi`` None: all the rest."""
        lo_ns = np.round(lo * 1e9)
        hi_ns = None if hi is None else np.round(hi * 1e9)
        for t_ns, order, call in self.calls:  # a slice costs its messages, not the piece's
            a = int(np.searchsorted(t_ns, lo_ns, side="left"))
            b = t_ns.size if hi_ns is None else int(np.searchsorted(t_ns, hi_ns, side="left"))
            call(writer, np.sort(order[a:b]))


class FusionTicks:
    """A fused sensor's ``fusion_*`` key-values at any tick of a piece."""

    def __init__(self, before: dict[str, str], judged: list[tuple[float, dict[str, str]]]
                 ) -> None:
        self.states = [before, *(values for _, values in judged)]
        times = np.array([t for t, _ in judged], np.float64)
        order = np.argsort(times, kind="stable")
        self.sorted_times = times[order]
        self.latest = np.maximum.accumulate(order + 1) if order.size else order
        """Per time in order, the last state judged at or before it."""
        key_sets = [tuple(state) for state in self.states]
        ids = {keys: n for n, keys in enumerate(dict.fromkeys(key_sets))}
        self.key_sets = list(ids)
        """The sets of keys its states have, in order of appearance."""
        self.key_set = np.array([ids[keys] for keys in key_sets], np.int64)
        """Per state, its set of keys (index into ``key_sets``)."""

    def at(self, ticks: np.ndarray) -> np.ndarray:
        """Per tick, the state after the last reference judged at or before it (0: none)."""
        pos = np.searchsorted(self.sorted_times, ticks, side="right")
        found = np.zeros(ticks.size, np.int64)
        found[pos > 0] = self.latest[pos[pos > 0] - 1]
        return found

    def columns(self, keys: tuple[str, ...], index: np.ndarray
                ) -> list[tuple[str, np.ndarray]]:
        """(key, UTF-8 values at the ticks of ``index``) for every key of ``keys``."""
        used = np.unique(index)
        found = []
        for key in keys:
            texts = np.array([self.states[i][key].encode() for i in used.tolist()])
            found.append((key, texts[np.searchsorted(used, index)]))
        return found


def diagnostic_payloads(ticks: np.ndarray, healths: Mapping[str, HealthTicks],
                        fusion: Mapping[str, FusionTicks]
                        ) -> Iterator[tuple[slice, np.ndarray, np.ndarray]]:
    """(ticks, payloads, lengths) of ``ticks``' DiagnosticArrays, a run per fusion key set."""
    if not ticks.size:
        return
    t_ns = np.round(ticks * 1e9).astype(np.int64)  # as the writer stamps its messages
    index = {name: f.at(ticks) for name, f in fusion.items()}
    changed = np.zeros(max(ticks.size - 1, 0), bool)  # where a fused sensor's keys change
    for name, i in index.items():
        changed |= np.diff(fusion[name].key_set[i]) != 0
    cuts = [0, *(np.flatnonzero(changed) + 1).tolist(), ticks.size]
    good_t = np.split(times_text(np.concatenate([np.empty(0),
                                                 *(h.last_good_t for h in healths.values())])),
                      np.cumsum([h.last_good_t.size for h in healths.values()])[:-1])
    columns = {name: h.diagnostic(texts)
               for (name, h), texts in zip(healths.items(), good_t, strict=True)}
    for a, b in itertools.pairwise(cuts):
        statuses: list[Status] = []
        for name, (levels, messages, values) in columns.items():
            run = [(key, v[a:b]) for key, v in values]
            if name in fusion:
                f = fusion[name]
                keys = f.key_sets[f.key_set[index[name][a]]]
                run += fusion[name].columns(keys, index[name][a:b])
            statuses.append((levels[a:b], status_name(name), messages[a:b], "", run))
        yield slice(a, b), *diagnostic_arrays(t_ns[a:b], "", statuses)


COPIED = {"std_msgs/msg/Float64": "write_float64", "std_msgs/msg/Int8": "write_int8",
          "std_msgs/msg/Float64MultiArray": "write_float64_array",
          "sensor_msgs/msg/Temperature": "write_temperature"}
"""The input types copied into the output bag, with the writer's method that writes them."""


def _copier(method: str, topic: str, t: np.ndarray, values: np.ndarray, *extra: object) -> Call:
    """The held ``BagWriter`` call ``method(topic, t, values, *extra)`` of a slice's messages."""
    return lambda w, i: getattr(w, method)(topic, t[i], values[i], *extra)


def _diagnostics_copier(topic: str, diagnostics: list[tuple[float, list[DiagnosticStatus]]]
                        ) -> Call:
    """The held ``BagWriter.write_diagnostics`` of a slice's messages of ``diagnostics``."""
    t = np.array([d[0] for d in diagnostics])
    return lambda w, i: w.write_diagnostics(t[i], [diagnostics[k][1] for k in i.tolist()],
                                            topic=topic)


def _copy_through(contents: BagContents, out: StagedWrites, written: set[str],
                  problem: Callable[[str], None]) -> int:
    """Write the input topics into the output bag; the number of messages copied."""
    n = 0
    for topic, kind in contents.types.items():
        series = contents.series.get(topic)
        if topic in written and topic != "/diagnostics":
            problem(f"{topic}: an input topic with an output's name; not copied")
        elif kind == "diagnostic_msgs/msg/DiagnosticArray":
            if contents.diagnostics:
                out.add([d[0] for d in contents.diagnostics],
                        _diagnostics_copier(topic, contents.diagnostics))
                n += len(contents.diagnostics)
        elif series is None or kind not in COPIED:
            problem(f"{topic}: type {kind} is not copied to the output")
        else:
            labels: tuple[list[str], ...] = ()
            if kind == "std_msgs/msg/Float64MultiArray":
                labels = (contents.labels.get(topic)
                          or [str(i) for i in range(series.values.shape[1])],)
            out.add(series.t, _copier(COPIED[kind], topic, series.t, series.values, *labels))
            n += series.t.size
    return n
