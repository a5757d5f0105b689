"""Replay's /diagnostics of a batch of ticks, encoded at once: each sensor's health at each
tick (``strain_comp.core.health.HealthCounter``) and, for a fused sensor, its fusion state
(``OutputFusion.diagnostic_values``: as before the piece, or after the last reference
judged at or before the tick), laid out as columns by
``strain_comp.io.diagnostic_arrays``. The bytes are those of ``SensorHealth.to_diagnostic``
and ``cdr.diagnostic_array`` tick by tick. A fusion's keys grow when a reference is first
refused for a new reason, so the ticks are encoded in runs of one key set each."""

from __future__ import annotations

import itertools
from collections.abc import Iterator, Mapping

import numpy as np

from strain_comp.core.health import HealthTicks, status_name, times_text
from strain_comp.io.diagnostic_arrays import Status, diagnostic_arrays


class FusionTicks:
    """A fused sensor's ``fusion_*`` key-values at any tick of a piece: ``states[0]`` before
    it, ``states[i]`` after the reference judged at ``times[i - 1]``."""

    def __init__(self, states: list[dict[str, str]], times: np.ndarray) -> None:
        self.states = states
        order = np.argsort(times, kind="stable")
        self.sorted_times = times[order]
        self.latest = np.maximum.accumulate(order + 1) if order.size else order
        """Per time in order, the last state judged at or before it."""
        key_sets = [tuple(state) for state in states]
        ids = {keys: n for n, keys in enumerate(dict.fromkeys(key_sets))}
        self.key_sets = list(ids)
        """The sets of keys its states have, in order of appearance."""
        self.key_set = np.array([ids[keys] for keys in key_sets], np.int64)
        """Per state, its set of keys (index into ``key_sets``)."""

    @classmethod
    def of(cls, before: dict[str, str], judged: list[tuple[float, dict[str, str]]]
           ) -> FusionTicks:
        return cls([before, *(values for _, values in judged)],
                   np.array([t for t, _ in judged], np.float64))

    def at(self, ticks: np.ndarray) -> np.ndarray:
        """Index into ``states`` at each of ``ticks``: the last reference judged at or
        before the tick (in the order judged), else 0."""
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
    """The DiagnosticArray payloads of ``ticks`` [s] (a status per sensor of ``healths``,
    in its order), in runs of one fusion key set: (the run's ticks, payloads joined,
    lengths); none for no ticks."""
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
