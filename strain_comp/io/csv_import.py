"""Tensile-tester CSVs into Recordings (docs/csv.md: formats, columns, units).
Bad rows are dropped and counted, not flagged: an imported recording is training and
evaluation data; fault handling is exercised on bags."""

from __future__ import annotations

import csv
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt

from strain_comp.errors import InputError
from strain_comp.io.bag.schemas import MAX_TIME_S
from strain_comp.io.recording import Recording, align, check_scales, scaled

CB_PDMS_GAUGE_MM = 40.0
_DEFAULT_COLUMNS: dict[str, dict[str, int | str]] = {
    "cb_pdms": {"resistance": 0, "time": 2, "strain": 3, "strain_time": 4},
    "fiber": {"time": 0, "strain": 1, "resistance": 3},
    "generic": {},
}
_WIDTH = {"cb_pdms": 7, "fiber": 4}
_LINES = re.compile(r"\r\n|\r|\n")
"""Line ends of a CSV (not the other Unicode line separators ``str.splitlines`` knows)."""


@dataclass
class ImportReport:
    """What the import did: rows kept and dropped by reason, glitches, units, notes."""

    path: str
    fmt: str
    rows: int = 0
    kept: int = 0
    dropped: dict[str, int] = field(default_factory=dict)
    glitches_repaired: int = 0
    strain_unit: str = "%"
    resistance_unit: str = "ohm"
    """The unit of the stored resistance: ohm, or the one given (``R/R0``)."""
    notes: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    """What looks wrong in the reference (``reference_warnings``), one line each."""

    def lines(self) -> list[str]:
        """Human-readable summary (the notes are printed apart, on stderr)."""
        out = [f"{self.path} ({self.fmt}): {self.rows} rows, {self.kept} kept"]
        out += [f"  dropped {n} rows: {reason}" for reason, n in self.dropped.items() if n]
        if self.fmt == "cb_pdms" or self.glitches_repaired:
            out.append(f"  position glitches repaired: {self.glitches_repaired}")
        out.append(f"  strain stored in {self.strain_unit}")
        if self.resistance_unit != "ohm":
            out.append(f"  resistance stored in {self.resistance_unit}")
        return out


_DELIMITERS = ("\t", ";", ",", "|")
_WHITESPACE = " "


def detect_delimiter(lines: Sequence[str]) -> str:
    """The delimiter of a CSV file: the first that splits every line alike, else spaces."""
    lines = [line for line in lines if line.strip()][:20]
    for delimiter in _DELIMITERS:
        counts = {len(row) for row in csv.reader(lines, delimiter=delimiter)}
        if len(counts) == 1 and counts.pop() >= 2:
            return delimiter
    return _WHITESPACE if all(len(line.split()) >= 2 for line in lines) else ","


def _read_rows(path: Path, delimiter: str | None) -> tuple[list[list[str]], str]:
    try:  # utf-8-sig: a byte-order mark is not part of the first field
        with path.open(newline="", encoding="utf-8-sig", errors="replace") as f:
            text = _LINES.split(f.read())
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from exc
    try:
        if delimiter is None:
            delimiter = detect_delimiter(text[:40])
        if delimiter == _WHITESPACE:
            rows = [line.split() for line in text]
        else:
            rows = list(csv.reader(text, delimiter=delimiter))
    except csv.Error as exc:  # e.g. a field over the csv module's limit of 128 KiB
        raise InputError(f"{path}: not a CSV file ({exc})") from exc
    rows = [row for row in rows if any(x.strip() for x in row)]
    if delimiter != ",":
        rows = [[x.replace(",", ".") if "," in x and "." not in x else x for x in row]
                for row in rows]
    return rows, delimiter


def _to_float(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        return np.nan


def _numeric(rows: list[list[str]], width: int, columns: list[int]
             ) -> tuple[np.ndarray, np.ndarray]:
    """Those columns as floats (NaN: unparsable) and the mask of rows shorter than ``width``."""
    table = np.full((len(rows), len(columns)), np.nan)
    short = np.zeros(len(rows), bool)
    for i, row in enumerate(rows):
        if len(row) < width:
            short[i] = True
        for j, c in enumerate(columns):
            if c < len(row):
                table[i, j] = _to_float(row[c])
    return table, short


def _column(name: str, key: int | str, header: list[str] | None, path: Path) -> int:
    if isinstance(key, int) or (isinstance(key, str) and re.fullmatch(r"-?[0-9]+", key)):
        index = int(key)
        if index < 0:
            raise InputError(f"{path}: column {name}={key!r}: an index counts from 0")
        return index
    if header is None or key not in [h.strip() for h in header]:
        raise InputError(f"{path}: column {name}={key!r} not found in the header "
                         f"{header if header else '(no header)'}")
    return [h.strip() for h in header].index(key)


def repair_position_glitches(pos: np.ndarray, *, threshold_mm: float = 0.5
                             ) -> tuple[np.ndarray, int]:
    """Replace isolated single-sample reads of 0 mm by the mean of their neighbours."""
    pos = np.asarray(pos, dtype=np.float64).copy()
    if pos.size < 3:
        return pos, 0
    mid = np.abs(pos[1:-1]) < 1e-9
    glitch = mid & (np.abs(pos[:-2]) > threshold_mm) & (np.abs(pos[2:]) > threshold_mm)
    idx = np.flatnonzero(glitch) + 1
    pos[idx] = 0.5 * (pos[idx - 1] + pos[idx + 1])
    return pos, int(idx.size)


def import_csv(path: str | Path, *, fmt: str, sensor: str, gauge_length_mm: float | None = None,
               columns: Mapping[str, int | str] | None = None,
               scales: Mapping[str, float] | None = None, delimiter: str | None = None,
               resistance_unit: str = "ohm") -> tuple[Recording, ImportReport]:
    """One tensile-tester CSV as a Recording, and what the import did (docs/csv.md)."""
    path = Path(path)
    mapping = _mapping(path, fmt, gauge_length_mm, columns, scales)
    rows, _ = _read_rows(path, delimiter)
    report = ImportReport(path=str(path), fmt=fmt, resistance_unit=resistance_unit)
    if resistance_unit != "ohm":
        report.notes.append(f"the 'resistance' topic holds the input in {resistance_unit}, "
                            f"not ohm (fit it with --input-unit {resistance_unit})")
    head, rows = _split_header(path, rows)
    fields, short = _fields(path, fmt, rows, head, mapping, scales)
    report.rows = len(rows)
    t = fields["time"]
    good = _good_rows(path, fmt, t, fields["resistance"], short, report)
    strain = None
    if "strain" in fields:
        strain = _reference(fields, good, report, gauge_length_mm=gauge_length_mm,
                            strain_factor=(scales or {}).get("strain", 1.0))
    report.kept = int(good.sum())
    return Recording(name=sensor, t=t[good], r=fields["resistance"][good], s=strain), report


_KEYS = ("time", "resistance", "strain", "strain_time")
"""The fields a column mapping may name, in the order they are read."""


def _mapping(path: Path, fmt: str, gauge_length_mm: float | None,
             columns: Mapping[str, int | str] | None, scales: Mapping[str, float] | None
             ) -> dict[str, int | str]:
    """The column mapping (the format's defaults under ``columns``), its inputs checked."""
    if gauge_length_mm is not None and not (np.isfinite(gauge_length_mm) and gauge_length_mm > 0):
        raise InputError(f"gauge length must be > 0 mm, got {gauge_length_mm}")
    mapping = {**_DEFAULT_COLUMNS[fmt], **(columns or {})}
    for key in ("time", "resistance"):
        if key not in mapping:
            raise InputError(f"{path}: the column mapping needs '{key}'")
    unknown = set(mapping) - set(_KEYS)
    if unknown:
        raise InputError(f"{path}: unknown column keys {sorted(unknown)}")
    check_scales(scales, str(path), _KEYS)
    return mapping


def _split_header(path: Path, rows: list[list[str]]
                  ) -> tuple[list[str] | None, list[list[str]]]:
    """The header row (a non-numeric first row; None: none) and the data rows."""
    head: list[str] | None = None
    has_header = bool(rows) and not all(np.isfinite(_to_float(x)) for x in rows[0] if x)
    if has_header:
        head, rows = rows[0], rows[1:]
    if not rows:
        raise InputError(f"{path}: no data rows")
    return head, rows


def _fields(path: Path, fmt: str, rows: list[list[str]], head: list[str] | None,
            mapping: Mapping[str, int | str], scales: Mapping[str, float] | None
            ) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Each mapped field's values, scaled (NaN: unparsable), and the mask of short rows."""
    cols = {k: _column(k, v, head, path) for k, v in mapping.items()}
    widest = max(len(row) for row in rows)
    for k, c in cols.items():
        if c >= widest:
            raise InputError(f"{path}: column {k}={c}: the widest row has {widest} fields "
                             "(columns count from 0)")
    width = max(_WIDTH.get(fmt, 0), max(cols.values()) + 1)
    used = sorted(set(cols.values()))
    table, short = _numeric(rows, width, used)
    factor = {k: 1.0 for k in cols} | dict(scales or {})
    fields = {key: scaled(str(path), key, table[:, used.index(cols[key])], factor[key])
              for key in _KEYS if key in cols}
    return fields, short


def _good_rows(path: Path, fmt: str, t: npt.NDArray[np.float64], r: npt.NDArray[np.float64],
               short: npt.NDArray[np.bool_], report: ImportReport) -> npt.NDArray[np.bool_]:
    """The rows kept, the others counted by reason in ``report.dropped``."""
    unparsable = short | ~np.isfinite(t) | np.isnan(r)
    not_finite = ~unparsable & ~np.isfinite(r)
    non_positive = ~unparsable & ~not_finite & (r <= 0)
    candidate = ~(unparsable | not_finite | non_positive)
    beyond = candidate & ((t < 0) | (t > MAX_TIME_S))
    candidate &= ~beyond
    running = np.maximum.accumulate(np.concatenate(([-np.inf], np.where(candidate, t, -np.inf))))
    backwards = candidate & (t <= running[:-1])
    good = candidate & ~backwards
    report.dropped = {"unparsable or missing field": int(unparsable.sum()),
                      "resistance not finite": int(not_finite.sum()),
                      f"resistance <= 0 {report.resistance_unit}": int(non_positive.sum()),
                      f"time < 0 or beyond {MAX_TIME_S} s": int(beyond.sum()),
                      "time not increasing": int(backwards.sum())}
    if not good.any():
        hint = (f"; times beyond {MAX_TIME_S} s: epoch milli- or nanoseconds? scale them "
                "(--scales time=1e-9)" if beyond.any() else "")
        raise InputError(f"{path}: no good row (format {fmt}){hint}")
    return good


def _reference(fields: Mapping[str, np.ndarray], good: np.ndarray, report: ImportReport, *,
               gauge_length_mm: float | None, strain_factor: float) -> np.ndarray:
    """The reference strain on the good rows' times (NaN outside its span), noted in ``report``."""
    t = fields["time"]
    s_raw = fields["strain"]
    t_s = fields.get("strain_time", t)
    ok = np.isfinite(s_raw) & np.isfinite(t_s)
    if "strain_time" not in fields:  # the reference shares the row: only good rows count
        ok &= good
    ts = t_s[ok]
    strain_src = _strain(s_raw[ok], report, gauge_length_mm=gauge_length_mm,
                         strain_factor=strain_factor)
    strain = align(t[good], ts, strain_src)
    outside = int(np.isnan(strain).sum())
    if outside:
        report.notes.append(f"{outside} samples outside the reference's time span "
                            "have no reference (NaN)")
    report.warnings = reference_warnings(
        strain_src, ts, percent=report.strain_unit != "mm" and strain_factor == 1.0)
    return strain


def _strain(pos: np.ndarray, report: ImportReport, *, gauge_length_mm: float | None,
            strain_factor: float) -> np.ndarray:
    """The reference column as strain by the format's rule; the unit and glitches in ``report``."""
    if report.fmt == "cb_pdms":
        pos, report.glitches_repaired = repair_position_glitches(np.abs(pos))
        return 100.0 * pos / (gauge_length_mm or CB_PDMS_GAUGE_MM)
    if report.fmt == "fiber" and gauge_length_mm is None:
        report.strain_unit = "mm"
        report.notes.append("no --gauge-length-mm: the 'strain' topic holds the "
                            "extension in mm, not % (fit it with --strain-unit mm)")
        return pos
    if gauge_length_mm is not None:
        return 100.0 * pos / gauge_length_mm
    report.strain_unit = ("the file's unit" if strain_factor == 1.0
                          else f"the file's unit x {strain_factor:g}")
    return pos


FRACTION_SPAN = 1.0
"""A reference in % whose span is below this looks like a fraction (0.3 for 30 %)."""
MICROSTRAIN_SPAN = 1000.0
"""A reference in % whose span is at least this looks like microstrain (3000 for 0.3 %)."""


def reference_warnings(values: np.ndarray, t: np.ndarray, *, percent: bool) -> list[str]:
    """What looks wrong in a reference column as read (finite values, before any gauge length)."""
    if values.size < 2:
        return []
    lines = []
    lo, hi = float(values.min()), float(values.max())
    if lo < 0.0 and hi <= 0.1 * -lo:
        lines.append(f"the reference runs from {hi + 0.0:.4g} to {lo:.4g}, below zero: a signed "
                     "stage position? pass --scales strain=-1 so that stretch is positive")
    back = int(np.sum(np.diff(t) < 0))
    if back:
        lines.append(f"the reference's time runs backwards at {back} rows: check the "
                     "time column of --columns (strain_time, else time)")
    span = hi - lo
    if percent and 0.0 < span < FRACTION_SPAN:
        lines.append(f"the reference spans only {span:.3g}: if it is a fraction, pass "
                     "--scales strain=100 (to %); if it is in another unit, fit with "
                     "--strain-unit UNIT")
    elif percent and span >= MICROSTRAIN_SPAN:
        lines.append(f"the reference spans {span:.4g}: if it is microstrain, pass --scales "
                     "strain=1e-4 (to %); if it is in another unit, fit with --strain-unit "
                     "UNIT")
    return lines
