"""Recordings: one sensor's resistance with its reference strain and temperature, from a
bag (the topics of docs/design.md, "Topics") or a table (its columns scaled by ``scales``);
the reference and the temperature put on the resistance time stamps (``align``)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from strain_comp.errors import InputError
from strain_comp.io.bag import BagContents, BagWriter, Series, located, read_bag

RESISTANCE = "/resistance"
REFERENCE = "/strain_reference"
TEMPERATURE = "/temperature"
SCALE_KEYS = ("time", "resistance", "strain")
"""The columns a table's ``scales`` (``import-csv --scales``, ``from_frame``) multiply."""


def check_scales(scales: Mapping[str, float] | None, where: str,
                 keys: Sequence[str] = SCALE_KEYS) -> None:
    """Check factors per column (``import-csv --scales``, ``Recording.from_frame``)."""
    for key, factor in (scales or {}).items():
        if key not in keys:
            raise InputError(f"{where}: unknown scale key {key!r} (one of {', '.join(keys)})")
        sign_ok = isinstance(factor, (int, float)) and not isinstance(factor, bool) and (
            factor != 0 if key == "strain" else factor > 0)
        if not (sign_ok and np.isfinite(factor)):
            need = "a number other than 0" if key == "strain" else "a number > 0"
            raise InputError(f"{where}: scale {key}={factor!r} must be {need}")


def scaled(where: str, key: str, raw: np.ndarray, factor: float) -> np.ndarray:
    """``raw`` times its scale ``factor``."""
    with np.errstate(over="ignore", invalid="ignore"):
        out = raw * factor
    if np.any(np.isfinite(raw) & ~np.isfinite(out)):
        raise InputError(f"{where}: --scales {key}={factor:g}: the scaled values "
                         "overflow (beyond 1.8e308); check the factor")
    return out


@dataclass(frozen=True)
class Recording:
    """One sensor: time [s], resistance [ohm], reference strain [%] and temperature [deg C]
    on the same time stamps (``s`` / ``temperature`` None when the bag has none).
    ``array``/``index``: the array topic prefix and column when it came from an array."""

    name: str
    t: np.ndarray
    r: np.ndarray
    s: np.ndarray | None = None
    temperature: np.ndarray | None = None
    array: str | None = None
    index: int | None = None

    def __len__(self) -> int:
        return int(self.t.size)

    @classmethod
    def from_arrays(cls, t: npt.ArrayLike, r: npt.ArrayLike, s: npt.ArrayLike | None = None,
                    *, name: str = "s1", temperature: npt.ArrayLike | None = None
                    ) -> Recording:
        """A recording from arrays, all of one length.

        Bad samples (NaN, R <= 0, time not increasing) are kept: the engine screens them.

        Args:
            t: Time [s].
            r: Resistance [ohm].
            s: Reference strain [%, or the calibration's unit]; None: no reference.
            name: The sensor's name.
            temperature: Temperature [deg C]; None: not recorded.

        Returns:
            The recording (float64 copies of the arrays).

        Raises:
            InputError: ``t`` or ``r`` is None, an array is not 1-D numbers, the lengths
                differ, or the name is empty.

        """
        columns = {"t": t, "r": r, "s": s, "temperature": temperature}
        arrays: dict[str, np.ndarray | None] = {}
        for key, value in columns.items():
            if value is None and key in ("t", "r"):
                raise InputError(f"recording {name!r}: {key} (the "
                                 f"{'time' if key == 't' else 'resistance'}) is required, "
                                 "got None")
            if value is None:
                arrays[key] = None
                continue
            try:
                array = np.array(value, dtype=np.float64)
            except (TypeError, ValueError) as err:
                raise InputError(f"recording {name!r}: {key} is not numbers ({err})") from None
            if array.ndim != 1:
                raise InputError(f"recording {name!r}: {key} must be 1-D, got shape "
                                 f"{array.shape}")
            arrays[key] = array
        t_array, r_array = arrays["t"], arrays["r"]
        assert t_array is not None and r_array is not None
        for key, array in arrays.items():
            if array is not None and array.size != t_array.size:
                raise InputError(f"recording {name!r}: {key} has {array.size} samples, t has "
                                 f"{t_array.size}")
        if not name or not isinstance(name, str):
            raise InputError(f"recording name must be a non-empty string, got {name!r}")
        return cls(name, t_array, r_array, arrays["s"], arrays["temperature"])

    @classmethod
    def from_frame(cls, frame: Any, *, name: str = "s1", time: str = "time_s",
                   resistance: str = "resistance_ohm", reference: str | None = "reference",
                   temperature: str | None = None,
                   scales: Mapping[str, float] | None = None) -> Recording:
        """A recording from the columns of a table.

        The default column names are those of ``evaluate --csv``.

        Args:
            frame: A pandas DataFrame, or any mapping of column names to arrays.
            name: The sensor's name.
            time: The time column [s, or another unit with a ``time`` scale].
            resistance: The resistance column [ohm, or with a ``resistance`` scale].
            reference: The reference strain column, used when the table has it (None:
                none).
            temperature: The temperature column [deg C], required when given (None: none).
            scales: A factor per column, as ``import-csv --scales``: ``time`` (into s),
                ``resistance`` (into ohm), ``strain`` (into the strain unit fitted, e.g.
                100 for a fraction to %); None: the columns as they are.

        Returns:
            The recording.

        Raises:
            InputError: ``frame`` is not a table, a required column is missing or holds
                other than numbers, a bad scale, or the columns are not 1-D of one length
                (``from_arrays``).

        """
        if not (isinstance(frame, Mapping) or hasattr(frame, "columns")):
            raise InputError(f"recording {name!r}: expected a pandas DataFrame or a mapping of "
                             f"column names to arrays, got {type(frame).__name__}")
        check_scales(scales, f"recording {name!r}")
        factors = dict(scales or {})

        def column(key: str | None, required: bool, scale: str = "") -> Any:
            if key is None:
                return None
            try:
                values = frame[key]
            except (KeyError, IndexError, TypeError):
                if not required:
                    return None
                raise InputError(f"recording {name!r}: no column {key!r} in the table") \
                    from None
            try:
                array = np.asarray(values, dtype=np.float64)
            except (TypeError, ValueError) as err:
                raise InputError(f"recording {name!r}: column {key!r} holds other than "
                                 f"numbers ({err}); read missing values as NaN (pandas: "
                                 "na_values)") from None
            return scaled(f"recording {name!r}", scale, array, factors[scale]) \
                if scale in factors else array
        return cls.from_arrays(column(time, True, "time"),
                               column(resistance, True, "resistance"),
                               column(reference, False, "strain"), name=name,
                               temperature=column(temperature, temperature is not None))


def align(t: npt.ArrayLike, t_src: npt.ArrayLike, values: npt.ArrayLike) -> np.ndarray:
    """Put ``values`` sampled at ``t_src`` on the times ``t`` (``PieceAlign`` in one piece)."""
    t = np.asarray(t, dtype=np.float64)
    aligner = PieceAlign()
    aligner.add(t, np.asarray(t_src), np.asarray(values))
    return aligner.take(t.ravel()).reshape(t.shape)


def _sorted_last(t: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The samples in time order, the last one kept of those at one time."""
    order = np.argsort(t, kind="stable")
    t, values = t[order], values[order]
    last = np.append(t[1:] != t[:-1], True)
    return t[last], values[last]


class PieceAlign:
    """``align`` over pieces in time order (``iter_bag``), equal to it over the whole."""

    def __init__(self) -> None:
        self.exact = True
        self.finished = False
        self.copied: list[np.ndarray] = []  # values of the leading targets, stamps identical
        self.src_t = np.empty(0)
        self.src_v = np.empty(0)

    def add(self, t: np.ndarray, t_src: np.ndarray, values: np.ndarray) -> None:
        t_src = np.asarray(t_src, dtype=np.float64)
        values = np.asarray(values, dtype=np.float64)
        if self.exact and t_src.shape == t.shape and np.array_equal(t_src, t, equal_nan=True):
            if t.size:
                self.copied.append(values.copy())
        elif t.size or t_src.size:
            self.exact = False
        ok = np.isfinite(t_src) & np.isfinite(values)
        if not ok.any():
            return
        self.src_t, self.src_v = _sorted_last(np.concatenate((self.src_t, t_src[ok])),
                                              np.concatenate((self.src_v, values[ok])))
        if self.exact:  # held for the piece where the stamps first differ
            self.src_t, self.src_v = self.src_t[-1:], self.src_v[-1:]

    def finish(self) -> None:
        """No more pieces: every waiting target is known."""
        self.finished = True

    def horizon(self) -> float:
        """The latest target time whose value is known."""
        if self.exact or self.finished or self.src_t.size == 0:
            return math.inf
        return float(self.src_t[-1])

    def take(self, t: np.ndarray) -> np.ndarray:
        """Values at the next waiting targets."""
        out = np.full(t.size, np.nan)
        done = 0
        while self.copied and done < t.size:
            head = self.copied[0]
            n = min(head.size, t.size - done)
            out[done:done + n] = head[:n]
            done += n
            if n == head.size:
                self.copied.pop(0)
            else:
                self.copied[0] = head[n:]
        rest = t[done:]
        if rest.size and self.src_t.size:
            inside = (rest >= self.src_t[0]) & (rest <= self.src_t[-1])
            out[done:][inside] = np.interp(rest[inside], self.src_t, self.src_v)
            keep = max(int(np.searchsorted(self.src_t, rest[-1], side="right")) - 1, 0)
            self.src_t, self.src_v = self.src_t[keep:], self.src_v[keep:]
        return out


def hold_latest(t: npt.ArrayLike, t_src: npt.ArrayLike, values: npt.ArrayLike) -> np.ndarray:
    """Hold ``values`` sampled at ``t_src`` to the times ``t``, as a live node holds them."""
    t_src = np.asarray(t_src, dtype=np.float64)
    values = np.asarray(values)
    order = np.argsort(t_src, kind="stable")
    pos = np.searchsorted(t_src[order], t, side="right") - 1
    return np.where(pos >= 0, values[order][np.maximum(pos, 0)], np.nan)


def topic_sensors(topic: str, contents: BagContents) -> tuple[list[str], str | None]:
    """A resistance topic's sensors (its labels, else PREFIX_j) and a labels problem."""
    values = contents.series[topic].values
    prefix = topic[:-len(RESISTANCE)].lstrip("/")
    if values.ndim == 1:
        return [prefix], None
    labels = contents.labels.get(topic) or []
    k = values.shape[1]
    if len(labels) == k:
        return labels, None
    problem = (f"{topic}: {len(labels)} labels for {k} columns; sensors named by column"
               if labels else None)
    return [f"{prefix}_{j}" for j in range(k)], problem


def temperature_series(contents: BagContents, name: str) -> Series | None:
    """Sensor ``name``'s own ``/NAME/temperature`` (an array's too, as the node reads it)."""
    temp = contents.series.get(f"/{name}{TEMPERATURE}")
    return temp if temp is not None and temp.values.ndim == 1 else None


def reference_columns(contents: BagContents, topic: str) -> tuple[dict[str, int | None],
                                                                  str | None]:
    """Each sensor's column of ``topic``'s reference (None: 1-D), or none and why."""
    reference = topic[:-len(RESISTANCE)] + REFERENCE
    ref = contents.series[reference]
    labels, _ = topic_sensors(topic, contents)
    if contents.series[topic].values.ndim == 1:
        if ref.values.ndim == 1:
            return {labels[0]: None}, None
        return {}, f"{reference}: an array reference for a single sensor"
    ref_labels = contents.labels.get(reference) or labels
    if ref.values.ndim == 2 and ref.values.shape[1] == len(ref_labels) \
            and set(labels) <= set(ref_labels):
        return {n: ref_labels.index(n) for n in labels}, None
    return {}, f"{reference}: columns do not match {topic}; ignored"


def _recordings(contents: BagContents) -> tuple[dict[str, Recording], list[str]]:
    problems: list[str] = []
    out: dict[str, Recording] = {}
    series = contents.series
    for topic in sorted(series):
        if not topic.endswith(RESISTANCE):
            continue
        prefix = topic[:-len(RESISTANCE)]
        res = series[topic]
        ref = series.get(prefix + REFERENCE)
        labels, problem = topic_sensors(topic, contents)
        if problem is not None:
            problems.append(problem)
        columns: dict[str, int | None] = {}
        if ref is not None:
            columns, problem = reference_columns(contents, topic)
            if problem is not None:
                problems.append(problem)
        for j, name in enumerate(labels):
            if name in out:
                problems.append(f"{topic}: sensor {name} appears twice; column {j} skipped")
                continue
            s = None
            if ref is not None and name in columns:
                column = columns[name]
                s = align(res.t, ref.t, ref.values if column is None else ref.values[:, column])
            temp = temperature_series(contents, name)
            temperature = None if temp is None else align(res.t, temp.t, temp.values)
            if res.values.ndim == 1:
                r, array, index = res.values, None, None
            else:
                r, array, index = res.values[:, j], prefix.lstrip("/"), j
            out[name] = Recording(name, res.t, r, s, temperature, array, index)
    for topic in series:
        if topic.endswith(REFERENCE) and topic[:-len(REFERENCE)] + RESISTANCE not in series:
            problems.append(f"{topic}: reference without a resistance topic; ignored")
    return out, problems


def as_contents(recordings: Mapping[str, Recording]) -> BagContents:
    """Recordings (by sensor name) as one piece of a bag that ``load_recordings`` reads back
    as them: an array's sensors on one time base on its topics, every other sensor alone."""
    contents = BagContents()
    groups: dict[str, dict[str, Recording]] = {}
    for name, rec in recordings.items():
        groups.setdefault(name if rec.array is None else rec.array, {})[name] = rec
    for prefix, recs in groups.items():
        first = next(iter(recs.values()))
        if len(recs) > 1 and all(np.array_equal(r.t, first.t, equal_nan=True)
                                 for r in recs.values()):
            _put(contents, prefix, recs)
        else:
            for name, rec in recs.items():
                _put(contents, name, {name: rec})
    return contents


def _put(contents: BagContents, prefix: str, recs: Mapping[str, Recording]) -> None:
    """Recordings on one time base as ``/prefix``'s topics (several: as an array)."""
    t = np.asarray(next(iter(recs.values())).t, dtype=np.float64)
    topics = [(RESISTANCE, [rec.r for rec in recs.values()])]
    if any(rec.s is not None for rec in recs.values()):  # as an array's reference: NaN for none
        topics.append((REFERENCE, [np.full(t.size, np.nan) if rec.s is None else rec.s
                                   for rec in recs.values()]))
    for suffix, values in topics:
        topic = f"/{prefix}{suffix}"
        contents.series[topic] = Series(t, np.asarray(
            values[0] if len(recs) == 1 else np.column_stack(values), dtype=np.float64))
        if len(recs) > 1:
            contents.labels[topic] = list(recs)
    for name, rec in recs.items():
        if rec.temperature is not None:
            contents.series[f"/{name}{TEMPERATURE}"] = Series(
                t, np.asarray(rec.temperature, dtype=np.float64))


def write_recordings(recordings: Mapping[str, Recording], path: str | Path, *,
                     inputs: Sequence[str | Path] = (), temperature_every: int = 1) -> None:
    """Recordings (by sensor name) into a new MCAP bag, atomically, on the topics
    ``as_contents`` gives them; each temperature read every ``temperature_every`` samples."""
    contents = as_contents({name.strip("/"): rec for name, rec in recordings.items()})
    with BagWriter(path, inputs=inputs) as writer:
        for topic, series in contents.series.items():
            if topic.endswith(TEMPERATURE):
                writer.write_temperature(topic, series.t[::temperature_every],
                                         series.values[::temperature_every])
            elif series.values.ndim == 2:
                writer.write_float64_array(topic, series.t, series.values, contents.labels[topic])
            else:
                writer.write_float64(topic, series.t, series.values)


def load_recordings(path: str | Path) -> tuple[dict[str, Recording], list[str]]:
    """Read a bag into recordings (in pieces, without the whole-bag budget)."""
    contents = read_bag(path, budget=False)
    recordings, problems = _recordings(contents)
    return recordings, contents.problems + located(path, problems)
