#!/usr/bin/env python3
"""Fuzz the calibration loader, the bag reader, the command line, the CSV importer and the
live node for a bounded time.

* **yaml**: random mutations of a valid calibration (every model, a divider input, every
  effect kind): byte flips, truncations, inserted YAML syntax, deleted lines, and
  structural edits of the parsed tree (deleted keys, values swapped for other types, NaN,
  inf, huge or negative numbers, emptied or lengthened lists). ``load_calibration`` may
  only raise ``CalibrationError``; a file that loads must then drive an ``Engine`` through
  a few good and bad samples without any exception (a loaded calibration always works).
* **bag**: byte flips, overwritten spans, truncations, deleted or duplicated spans of
  small valid MCAP bags (every message type, several chunk sizes). ``read_bag`` may only
  raise ``BagError`` or return contents (with ``problems``) whose series are consistent;
  every ``--replay-every``-th readable input is also replayed, which may raise only
  ``BagError``.

* **cli**: random ``strain-comp`` command lines built from the real subcommands and flags
  (``node`` excepted), with hostile values (wrong types, huge and negative numbers, unknown
  options) and hostile files (empty, random bytes, non-UTF-8, "billion laughs" and deeply
  nested YAML, a FIFO, a directory, symbolic, hard and looping links, a rosbag2 directory
  whose metadata leaves it, ``/dev/null``) as inputs and as outputs. Every run must exit
  0, 2, 70 or 130 with no traceback and exactly one ``strain-comp: error:`` line when the
  input fails, and leave every input file byte for byte as it was. Runs that end in a fault
  of the program (exit 70, one ``strain-comp: internal error:`` line naming the traceback's
  file) are listed: they keep the contract but are bugs.

* **csv**: mutations of a small generic CSV (byte flips, a byte-order mark, Unicode line
  separators, fields over 128 KiB, epoch nanoseconds, NaN, truncations, repeated spans)
  imported with random column mappings (indices far past the row, ``²``, ``-1``, names).
  ``import_csv`` may only raise ``InputError`` (one line); what it imports must be what the
  bag readers keep (finite increasing times within 2^31 s, finite positive resistance),
  every row kept or counted as dropped, and the bag must write.

* **node**: ``compensator`` (sim time; one sensor with a temperature term and the 6-sensor
  array) in its own process, and this process as a hostile peer: sensor values, temperatures
  and arrays (NaN, inf, huge, tiny, wrong sizes, offsets and labels), /clock ticks
  (negative, 2^31 - 1, backwards), ``set_parameters`` (``use_sim_time`` flips, bad values
  and types, read-only and unknown names), ``~/tare`` and ``~/reload_calibration``. Every
  strain the node publishes must be finite; it must stay alive and print no traceback; its
  RSS is sampled every second and must stay flat (the last quarter's median within
  ``RSS_GROWTH_MIB`` of the second quarter's). The clock runs, stands still (/clock
  silent while inputs keep coming) and runs backwards in stretches of 2 s.

* **evaluate**: ``evaluate FOLDER --csv --json --plots --jobs 1|2`` over folders of one to
  five seed and damaged bags (names that repeat a stem, ``...mcap``). The command line's
  contract (``check_cli``) and its outputs: no temporary file, nothing outside ``--plots``
  but the table and the JSON, a JSON that parses with no non-finite number; the RSS after
  each folder stays flat (as the node's, below).

* **api**: random calls of ``sc.fit``, ``sc.estimate``, ``sc.evaluate`` and
  ``Recording.from_frame`` (``api_call``: hostile arrays, frames and keyword types); each
  may only return or raise a ``StrainCompError`` of one line.

Anything else is a crash: the input and its traceback are saved under ``--out`` (**api**:
each class's first call and traceback, in ``api_internal.txt``). Inputs that take longer
than ``--timeout`` seconds count as hangs (saved too).

    python scripts/fuzz.py --seconds 120 [--target yaml|bag|cli|csv|node|evaluate|db3|api|all]
        [--seed 0]
        [--out DIR]
"""

from __future__ import annotations

import argparse
import math
import os
import signal
import sys
import tempfile
import time
import traceback
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from strain_comp.base.samples import used_mask
from strain_comp.core.calibration import Calibration, InputSettings, SensorCalibration
from strain_comp.core.calibration_file import load_calibration, save_calibration
from strain_comp.core.effects import KINDS
from strain_comp.core.engine import Engine
from strain_comp.errors import BagError, CalibrationError
from strain_comp.io.bag import BagWriter, read_bag
from strain_comp.io.recording import Recording
from strain_comp.models import MODEL_NAMES
from strain_comp.offline.fit import fit_sensor
from strain_comp.offline.replay import replay_bag
from strain_comp.offline.rig import simulate


class Hang(Exception):
    """An input took longer than the time limit."""


@dataclass
class Stats:
    """Counts of one fuzz target's run."""

    target: str
    inputs: int = 0
    rejected: int = 0
    """Inputs refused with the documented error (CalibrationError / BagError)."""
    accepted: int = 0
    crashes: list[tuple[bytes, str]] = field(default_factory=list)

    def line(self) -> str:
        return (f"{self.target}: {self.inputs} inputs, {self.accepted} accepted, "
                f"{self.rejected} rejected cleanly, {len(self.crashes)} crashes")


# ---------------------------------------------------------------- seeds

def seed_calibration(fitted: dict[str, SensorCalibration]) -> Calibration:
    """Every model of ``fitted`` as a sensor, a divider-input copy, and every effect kind."""
    sensors = {name: SensorCalibration(**{**vars(cal), "name": name})
               for name, cal in fitted.items()}
    first = next(iter(fitted.values()))
    r_mid = 0.5 * (first.valid_range.r_lo + first.valid_range.r_hi)
    sensors["divider"] = SensorCalibration(**{
        **vars(first), "name": "divider",
        "input": InputSettings("divider", r1=r_mid, vin=3.3),
        "effects": [{"name": kind, "kind": kind,
                     "params": {"neighbour": next(iter(fitted))} if kind == "crosstalk" else {},
                     "coef": 0.01} for kind in KINDS]})
    return Calibration(sensors)


def fit_every_model() -> dict[str, SensorCalibration]:
    """Each model fitted quickly on 60 s of the rig's random scenario (a sound seed)."""
    rec = replace(simulate("random", seed=2, duration=60.0)["s1"], name="s")
    fitted = {}
    for model in MODEL_NAMES:
        options: dict[str, Any] = {"tau": 0.2}
        if model in ("apl", "pl"):
            options.update(sigma_grid=[0.03], p_grid=[1.0], refine=False)
        if model == "rational":
            options["mode"] = "split"
        fitted[model] = fit_sensor([rec], model, name=model, options=options)
    return fitted


def replay_calibration(fitted: dict[str, SensorCalibration]) -> Calibration:
    """Sensors ``s1`` (apl), ``p`` and ``q`` (cubic): the seed bags' per-sensor and array
    inputs."""
    return Calibration({name: SensorCalibration(**{**vars(fitted[model]), "name": name})
                        for name, model in (("s1", "apl"), ("p", "cubic"), ("q", "cubic"))})


def seed_bags(directory: Path) -> list[bytes]:
    """Small valid bags: every message type, chunk sizes from tiny to one chunk."""
    t = 1.0 + np.arange(300) * 0.01
    seeds = []
    for chunk_size in (400, 3000, 1 << 20):
        path = directory / f"seed_{chunk_size}.mcap"
        with BagWriter(path, chunk_size=chunk_size) as w:
            w.write_float64("/s1/resistance", t, 15.0 + 5.0 * np.sin(t))
            w.write_float64("/s1/strain_reference", t, 10.0 + 10.0 * np.sin(t))
            w.write_int8("/s1/direction", t, np.sign(np.cos(t)))
            w.write_float64_array("/a/resistance", t, np.c_[t, 2 * t], ["p", "q"])
            w.write_temperature("/s1/temperature", t[::30], 20.0 + t[::30])
            w.write_diagnostics(t[:3], [[("s1", 0, "ok", {"k": "v"})]] * 3)
        seeds.append(path.read_bytes())
    return seeds


# ---------------------------------------------------------------- mutations

SWAPS: list[Any] = [None, True, False, 0, -1, 1, 1e308, -1e308, math.nan, math.inf, -math.inf,
                    10**30, -0.0, "", "x", "1.5", [], {}, [1.0, 2.0], {"a": 1}, [[1.0]],
                    [None], list(range(300)), "apl", "divider", 2.5e-320]
SNIPPETS = [b"{", b"}", b"[", b"]", b": ", b"- ", b"\t", b"&a ", b"*a", b"!!binary ",
            b"!!python/object:os.system ", b"? ", b"|\n", b"'", b'"', b"\xff\xfe", b"\x00",
            b"~", b".nan", b"-.inf", b"1e999", b"0x1F", b"<<: *a", b"%YAML 1.1\n", b"---\n",
            b"...\n"]


def _paths(node: Any, prefix: tuple = ()) -> Iterator[tuple]:
    yield prefix
    if isinstance(node, dict):
        for key, value in node.items():
            yield from _paths(value, (*prefix, key))
    elif isinstance(node, list):
        for i, value in enumerate(node):
            yield from _paths(value, (*prefix, i))


def _structural(text: bytes, rng: np.random.Generator) -> bytes:
    tree = yaml.safe_load(text)
    paths = [p for p in _paths(tree) if p]
    for _ in range(int(rng.integers(1, 4))):
        path = paths[int(rng.integers(0, len(paths)))]
        parent = tree
        try:
            for key in path[:-1]:
                parent = parent[key]
            key = path[-1]
            op = int(rng.integers(0, 5))
            if op == 0:
                del parent[key]
            elif op == 1:
                parent[key] = SWAPS[int(rng.integers(0, len(SWAPS)))]
            elif op == 2 and isinstance(parent[key], list):
                parent[key] = parent[key][:int(rng.integers(0, len(parent[key]) + 1))]
            elif op == 3 and isinstance(parent[key], list):
                parent[key] = parent[key] + parent[key][:int(rng.integers(1, 4))]
            elif isinstance(parent[key], (int, float)) and not isinstance(parent[key], bool):
                parent[key] = parent[key] * float(rng.choice([-1.0, 0.0, 1e-9, 1e9, 1.0001]))
        except (KeyError, IndexError, TypeError):
            continue  # an earlier edit removed this path
    return yaml.safe_dump(tree, sort_keys=False).encode()


def mutate_yaml(text: bytes, rng: np.random.Generator) -> bytes:
    """One mutated calibration file (see the module docstring)."""
    op = int(rng.integers(0, 6))
    if op <= 1:
        return _structural(text, rng)
    buf = bytearray(text)
    if op == 2:  # bit flips
        for i in rng.integers(0, len(buf), int(rng.integers(1, 8))):
            buf[i] ^= 1 << int(rng.integers(0, 8))
    elif op == 3:  # truncation
        del buf[int(rng.integers(0, len(buf))):]
    elif op == 4:  # YAML syntax inserted
        i = int(rng.integers(0, len(buf) + 1))
        buf[i:i] = SNIPPETS[int(rng.integers(0, len(SNIPPETS)))]
    else:  # a line deleted or duplicated
        lines = bytes(buf).split(b"\n")
        i = int(rng.integers(0, len(lines)))
        if rng.random() < 0.5:
            del lines[i]
        else:
            lines.insert(i, lines[i])
        buf = bytearray(b"\n".join(lines))
    return bytes(buf)


def mutate_bag(data: bytes, rng: np.random.Generator) -> bytes:
    """One damaged bag: flips, overwritten or deleted or duplicated spans, truncation."""
    buf = bytearray(data)
    for _ in range(int(rng.integers(1, 5))):
        if len(buf) < 2:
            break
        i = int(rng.integers(0, len(buf)))
        op = int(rng.integers(0, 5))
        if op == 0:
            buf[i] ^= 1 << int(rng.integers(0, 8))
        elif op == 1:
            fill = int(rng.choice([0x00, 0xFF, int(rng.integers(0, 256))]))
            span = int(rng.integers(1, 16))
            buf[i:i + span] = bytes([fill]) * len(buf[i:i + span])
        elif op == 2:
            del buf[i:]
        elif op == 3:
            j = min(len(buf), i + int(rng.integers(1, 64)))
            buf[i:i] = buf[i:j]
        else:
            del buf[i:i + int(rng.integers(1, 64))]
    return bytes(buf)


# ---------------------------------------------------------------- checks

def _exercise(calibration: Calibration) -> None:
    """A loaded calibration must run: good, bad and out-of-range samples, batch and step;
    once a sample was used, every output is finite (an absurd divider may make every
    sample an open or short circuit: then all are held, NaN)."""
    engine = Engine(calibration)
    for name, cal in calibration.sensors.items():
        lo, hi = cal.valid_range.r_lo, cal.valid_range.r_hi
        if cal.input.kind == "divider":
            r1, vin = float(cal.input.r1), float(cal.input.vin)
            lo, hi = vin * r1 / (r1 + hi), vin * r1 / (r1 + lo)
        r = np.array([lo, hi, 0.5 * (lo + hi), math.nan, -1.0, 2 * hi, hi, lo])
        t = np.arange(r.size) * 0.1
        out = engine.run(name, t, r)
        steps = [engine.step(name, ti, ri) for ti, ri in zip(t + 10.0, r, strict=True)]
        strain = np.concatenate([out.strain, [o.strain for o in steps]])
        status = np.concatenate([out.status, [o.status for o in steps]])
        used = used_mask(status)
        if used.any() and not np.isfinite(strain[int(np.argmax(used)):]).all():
            raise AssertionError(f"{name}: non-finite strain {strain} (status {status})")
    engine.health(now=100.0)


def check_yaml(path: Path) -> bool:
    """True if the file loaded (and ran), False if it was refused; raises on a crash."""
    try:
        calibration = load_calibration(path)
    except CalibrationError as err:
        if "\n" in str(err) or not str(err).startswith(str(path)):
            raise AssertionError(f"error message not one line naming the file: {err}") \
                from None
        return False
    _exercise(calibration)
    return True


def check_bag(path: Path, calibration: Calibration | None) -> bool:
    """True if the bag read (and replayed), False if refused with BagError; raises else."""
    try:
        contents = read_bag(path)
    except BagError:
        return False
    for topic, series in contents.series.items():
        if series.t.shape[0] != series.values.shape[0] or not np.isfinite(series.t).all():
            raise AssertionError(f"{topic}: inconsistent series")
    if not all(isinstance(p, str) for p in contents.problems):
        raise AssertionError("problems must be strings")
    if calibration is not None:
        try:
            replay_bag(path, calibration, path.with_suffix(".out.mcap"))
        except BagError:
            pass
    return True


# ---------------------------------------------------------------- driver

def _alarm(signum: int, frame: Any) -> None:
    raise Hang("time limit exceeded")


def run_target(stats: Stats, make: Callable[[], bytes], check: Callable[[Path], bool],
               path: Path, *, seconds: float | None = None, iterations: int | None = None,
               timeout: float = 10.0) -> Stats:
    """Feed ``make()`` inputs to ``check`` until the time or the iteration count runs out."""
    deadline = time.monotonic() + (seconds if seconds is not None else math.inf)
    use_alarm = hasattr(signal, "SIGALRM")
    if use_alarm:
        previous = signal.signal(signal.SIGALRM, _alarm)
    try:
        while time.monotonic() < deadline and (iterations is None or stats.inputs < iterations):
            data = make()
            path.write_bytes(data)
            stats.inputs += 1
            try:
                if use_alarm:
                    signal.setitimer(signal.ITIMER_REAL, timeout)
                ok = check(path)
            except Exception:  # what the fuzzer looks for
                stats.crashes.append((data, traceback.format_exc()))
                continue
            finally:
                if use_alarm:
                    signal.setitimer(signal.ITIMER_REAL, 0.0)
            stats.accepted += ok
            stats.rejected += not ok
    finally:
        if use_alarm:
            signal.signal(signal.SIGALRM, previous)
    return stats


def fuzz_yaml(seed_text: bytes, rng: np.random.Generator, work: Path, **limits: Any) -> Stats:
    """Fuzz ``load_calibration`` (and the engine on what loads) from one seed file."""
    return run_target(Stats("yaml"), lambda: mutate_yaml(seed_text, rng), check_yaml,
                      work / "cal.yaml", **limits)


def fuzz_bag(seeds: list[bytes], calibration: Calibration | None, rng: np.random.Generator,
             work: Path, *, replay_every: int = 10, **limits: Any) -> Stats:
    """Fuzz ``read_bag`` (and ``replay_bag`` on every ``replay_every``-th input)."""
    stats = Stats("bag")

    def make() -> bytes:
        return mutate_bag(seeds[int(rng.integers(0, len(seeds)))], rng)

    def check(path: Path) -> bool:
        replay = calibration if replay_every and stats.inputs % replay_every == 0 else None
        return check_bag(path, replay)

    return run_target(stats, make, check, work / "bag.mcap", **limits)



# ---------------------------------------------------------------- rosbag2 .db3

DB3_SCHEMA = """
CREATE TABLE schema(schema_version INTEGER PRIMARY KEY, ros_distro TEXT NOT NULL);
CREATE TABLE metadata(id INTEGER PRIMARY KEY, metadata_version INTEGER NOT NULL,
                      metadata TEXT NOT NULL);
CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL,
                    serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL,
                    type_description_hash TEXT NOT NULL);
CREATE TABLE message_definitions(id INTEGER PRIMARY KEY, topic_type TEXT NOT NULL,
                                 encoding TEXT NOT NULL,
                                 encoded_message_definition TEXT NOT NULL,
                                 type_description_hash TEXT NOT NULL);
CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL,
                      timestamp INTEGER NOT NULL, data BLOB NOT NULL);
CREATE INDEX timestamp_idx ON messages (timestamp ASC);
INSERT INTO schema VALUES (4, 'jazzy');
"""
"""rosbag2's sqlite3 schema (version 4, Jazzy's), as ``ros2 bag record`` creates it."""
DB3_METADATA = """rosbag2_bagfile_information:
  version: 8
  storage_identifier: sqlite3
  relative_file_paths: [bag.db3]
  compression_format: ''
  compression_mode: ''
"""
HOSTILE_SQL = ["[" * 5000, "- 1\n- 2\n", "{a: &x [*x]}", "\x00\xff", "x" * 5000, "", "cdr",
               "/s1/resistance", "std_msgs/msg/Float64", "cdr\n", "/s1/resistance\n"]


def seed_db3(directory: Path) -> bytes:
    """A small .db3 file (resistance, reference, array, temperature, diagnostics)."""
    from strain_comp.io.bag.reader import raw_messages

    mcap = directory / "seed_for_db3.mcap"
    mcap.write_bytes(seed_bags(directory)[0])
    messages, _ = raw_messages(mcap)
    path = directory / "seed.db3"
    path.unlink(missing_ok=True)
    import sqlite3

    with sqlite3.connect(path) as db:
        db.executescript(DB3_SCHEMA)
        ids: dict[tuple[str, str], int] = {}
        for topic, kind, _, _ in messages:
            if (topic, kind) not in ids:
                ids[(topic, kind)] = len(ids) + 1
                db.execute("INSERT INTO topics VALUES (?, ?, ?, 'cdr', '', '')",
                           (ids[(topic, kind)], topic, kind))
        db.executemany("INSERT INTO messages (topic_id, timestamp, data) VALUES (?, ?, ?)",
                       [(ids[(t, k)], stamp, data) for t, k, stamp, data in messages])
    return path.read_bytes()


def _sql_value(rng: np.random.Generator) -> object:
    """A value of a random sqlite type: integer (huge, negative), real, text, blob, NULL."""
    pick = int(rng.integers(0, 9))
    return [None, int(rng.integers(-5, 70)), 2**63 - 1, -(2**63), float("nan"), 1e300,
            HOSTILE_SQL[int(rng.integers(0, len(HOSTILE_SQL)))],
            bytes(rng.integers(0, 256, int(rng.integers(0, 64)), dtype=np.uint8)),
            b"/s1/resistance"][pick]


def mutate_db3(data: bytes, rng: np.random.Generator, work: Path) -> bytes:
    """Damaged bytes (as ``mutate_bag``) or hostile rows: a random column of random rows
    set to a value of another type, rows duplicated or deleted, the index or a table
    dropped, a message as large as 3 MiB."""
    if rng.random() < 0.4:
        return mutate_bag(data, rng)
    import sqlite3

    path = work / "mutating.db3"
    path.write_bytes(data)
    with sqlite3.connect(path) as db:
        for _ in range(int(rng.integers(1, 4))):
            table, column = [("topics", "name"), ("topics", "type"), ("topics", "id"),
                             ("topics", "serialization_format"),
                             ("topics", "offered_qos_profiles"), ("messages", "data"),
                             ("messages", "timestamp"), ("messages", "topic_id"),
                             ("messages", "id")][int(rng.integers(0, 9))]
            op = int(rng.integers(0, 10))
            try:
                if op < 6:
                    db.execute(f"UPDATE {table} SET {column} = ? WHERE abs(random()) % ? = 0",
                               (_sql_value(rng), int(rng.integers(1, 50))))
                elif op == 6:
                    db.execute(f"INSERT INTO {table} SELECT * FROM {table} "
                               "WHERE abs(random()) % 20 = 0")
                elif op == 7:
                    db.execute(f"DELETE FROM {table} WHERE abs(random()) % 5 = 0")
                elif op == 8:
                    db.execute(["DROP INDEX timestamp_idx", "DROP TABLE topics",
                                "ALTER TABLE messages DROP COLUMN data"][int(rng.integers(0, 3))])
                else:
                    db.execute("UPDATE messages SET data = zeroblob(?) WHERE id = ?",
                               (int(rng.integers(0, 3 * 2**20)), int(rng.integers(1, 50))))
            except sqlite3.Error:
                pass  # a constraint the mutation broke: the file stays as it was
    return path.read_bytes()


def mutate_metadata(rng: np.random.Generator) -> str:
    """metadata.yaml: the plain one, or hostile listings and compression fields."""
    pick = int(rng.integers(0, 8))
    if pick < 3:
        return DB3_METADATA
    listing = [["bag.db3"] * int(rng.integers(2, 3000)), ["./bag.db3", "bag.db3"],
               [f"part_{i}.db3" for i in range(int(rng.integers(1, 5000)))],
               ["../bag.db3"], "bag.db3", [1, None]][int(rng.integers(0, 6))]
    extra = ["", "  compression_mode: MESSAGE\n  compression_format: zstd\n",
             "  compression_mode: FILE\n", "  offered_qos_profiles: " + "[" * 3000 + "\n",
             "  topics_with_message_count: [{topic_metadata: {offered_qos_profiles: "
             "[1, 2]}}]\n"][int(rng.integers(0, 5))]
    text = DB3_METADATA.replace("  relative_file_paths: [bag.db3]\n",
                                f"  relative_file_paths: {yaml.safe_dump(listing)}"
                                .rstrip("\n").replace("\n", " ") + "\n")
    return text.replace("  compression_format: ''\n  compression_mode: ''\n", "") + extra \
        if extra else text


def fuzz_db3(rng: np.random.Generator, work: Path, **limits: Any) -> Stats:
    """Fuzz the rosbag2 .db3 reader (``read_bag`` and ``raw_messages`` on a bag directory):
    damaged sqlite files, hostile rows, hostile metadata.yaml."""
    from strain_comp.io.bag.reader import raw_messages

    work.mkdir(parents=True, exist_ok=True)
    seed = seed_db3(work)
    bag = work / "db3bag"
    bag.mkdir(exist_ok=True)

    def make() -> bytes:
        (bag / "metadata.yaml").write_text(mutate_metadata(rng))
        return mutate_db3(seed, rng, work)

    def check(path: Path) -> bool:
        try:
            contents = read_bag(bag)
            _, problems = raw_messages(bag)
        except BagError as err:
            if "\n" in str(err):
                raise AssertionError(f"a BagError of several lines: {err}") from None
            return False
        for topic, series in contents.series.items():
            if series.t.shape[0] != series.values.shape[0] or not np.isfinite(series.t).all():
                raise AssertionError(f"{topic}: inconsistent series")
        if not all(isinstance(p, str) and "\n" not in p for p in problems):
            raise AssertionError("problems must be one-line strings")
        return True

    return run_target(Stats("db3"), make, check, bag / "bag.db3", **limits)


# ---------------------------------------------------------------- Python API

def _array(rng: np.random.Generator, n: int) -> Any:
    """A random array-like of about ``n`` values: finite, with NaN/inf, negative, reversed,
    constant, integers, strings, 2-D, empty, a list or a scalar."""
    base = np.cumsum(rng.random(n) * 0.02) + 1.0
    pick = int(rng.integers(0, 12))
    if pick == 0:
        base[rng.random(n) < 0.1] = np.nan
    elif pick == 1:
        base[rng.random(n) < 0.1] = np.inf
    elif pick == 2:
        base = -base
    elif pick == 3:
        base = base[::-1].copy()
    elif pick == 4:
        base = np.full(n, 3.0)
    elif pick == 5:
        return base.astype(np.int64)
    elif pick == 6:
        return base.astype(str)
    elif pick == 7:
        return base.reshape(1, -1) if n else base.reshape(0, 1)
    elif pick == 8:
        return base[:0]
    elif pick == 9:
        return base.tolist()
    elif pick == 10:
        return float(base[0]) if n else None
    return base


def _junk(rng: np.random.Generator) -> Any:
    """A keyword value of a random type."""
    return [None, 0, -1, 2.5, float("nan"), "", "x", "%", "calibration", "auto", "clamp",
            "extend", "off", [], ["s1"], {"a": 1}, ("s1",), True, b"s1", np.float64(1.0),
            object()][int(rng.integers(0, 21))]


def api_call(rng: np.random.Generator, cal: Calibration) -> tuple[str, Callable[[], Any]]:
    """One random call of sc.fit / sc.estimate / sc.evaluate / Recording.from_frame (arrays,
    frames and keyword types hostile), as (a description, the call)."""
    import strain_comp as sc

    n = int(rng.choice([0, 1, 2, 5, 50, 400]))
    t = np.arange(n) * 0.02 if rng.random() < 0.6 else _array(rng, n)
    r = 1000.0 + 50.0 * np.sin(np.arange(n) * 0.05) if rng.random() < 0.5 else _array(rng, n)
    s = 10.0 + 10.0 * np.sin(np.arange(n) * 0.05) if rng.random() < 0.5 else _array(rng, n)
    columns = {"time_s": t, "resistance_ohm": r, "reference": s}
    if rng.random() < 0.3:
        columns.pop(list(columns)[int(rng.integers(0, 3))])
    if rng.random() < 0.2:
        columns["temperature"] = _array(rng, n)
    frame_kw: dict[str, Any] = {k: _junk(rng) for k in ("name", "time", "resistance",
                                                         "reference", "temperature")
                                if rng.random() < 0.2}

    def recording() -> Any:
        return Recording.from_frame(columns, **frame_kw)

    which = int(rng.integers(0, 4))
    keys = ("tare", "out_of_range", "tracking")
    kw: dict[str, Any] = {k: _junk(rng) for k in keys if rng.random() < 0.25}
    if which == 0:
        return f"Recording.from_frame({sorted(columns)}, n={n}, {frame_kw})", recording
    if which == 1:
        if rng.random() < 0.2:
            kw["sensor"] = _junk(rng)
        if rng.random() < 0.2:
            kw["temperature"] = _array(rng, n)
        return (f"estimate(n={n}, {kw})", lambda: sc.estimate(cal, t, r, **kw))
    if which == 2:
        if rng.random() < 0.2:
            kw["references_every"] = _junk(rng)
        return f"evaluate(n={n}, {kw})", lambda: sc.evaluate(
            cal, recording() if rng.random() < 0.8 else _junk(rng), **kw)
    model = str(rng.choice(["cubic", "pl", "rational", "cubic", "quintic"]))
    fit_kw: dict[str, Any] = {k: _junk(rng) for k in ("sensors", "strain_unit", "pool",
                                                       "input_unit") if rng.random() < 0.15}
    if rng.random() < 0.15:
        fit_kw[str(rng.choice(["N", "eps", "bogus", "ridge"]))] = _junk(rng)
    return f"fit({model}, n={n}, {fit_kw})", lambda: sc.fit(
        recording() if rng.random() < 0.85 else [recording(), recording()], model, **fit_kw)


@dataclass
class ApiStats:
    """Counts of an API fuzz run: calls, clean refusals and internal errors by class (with
    the traceback of each class's first call)."""

    calls: int = 0
    refused: int = 0
    internal: dict[str, list[str]] = field(default_factory=dict)
    traces: dict[str, str] = field(default_factory=dict)
    rss_mib: list[float] = field(default_factory=list)

    def line(self) -> str:
        n = sum(len(v) for v in self.internal.values())
        return (f"api: {self.calls} calls, {self.refused} refused cleanly, {n} internal "
                f"errors in {len(self.internal)} classes; RSS {self.rss_mib[0]:.0f} -> "
                f"{self.rss_mib[-1]:.0f} MiB (max {max(self.rss_mib):.0f})")


def _own_rss() -> float:
    """This process's resident memory [MiB] (``_rss_mib``)."""
    return _rss_mib(os.getpid()) or 0.0


def fuzz_api(rng: np.random.Generator, *, seconds: float | None = None,
             iterations: int | None = None, timeout: float = 30.0) -> ApiStats:
    """Random calls (``api_call``) against the demo calibration: anything raised that is
    not a StrainCompError is an internal error, grouped by function, type and message."""
    import warnings

    from strain_comp.errors import StrainCompError

    cal = load_calibration(Path(__file__).resolve().parent.parent / "config" /
                           "demo_calibration.yaml")
    stats = ApiStats(rss_mib=[_own_rss()])
    deadline = time.monotonic() + (seconds if seconds is not None else math.inf)
    previous = signal.signal(signal.SIGALRM, _alarm)
    try:
        while time.monotonic() < deadline and (iterations is None or stats.calls < iterations):
            what, call = api_call(rng, cal)
            stats.calls += 1
            try:
                signal.setitimer(signal.ITIMER_REAL, timeout)
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    call()
            except StrainCompError as err:
                stats.refused += 1
                if "\n" in str(err):
                    stats.internal.setdefault("multi-line error", []).append(what)
            except Exception as err:  # what the fuzzer looks for
                key = f"{what.split('(')[0]}: {type(err).__name__}: {str(err)[:70]}"
                stats.internal.setdefault(key, []).append(what)
                stats.traces.setdefault(key, f"{what}\n{traceback.format_exc()}")
            finally:
                signal.setitimer(signal.ITIMER_REAL, 0.0)
            if stats.calls % 50 == 0:
                stats.rss_mib.append(_own_rss())
    finally:
        signal.signal(signal.SIGALRM, previous)
    stats.rss_mib.append(_own_rss())
    return stats


# ---------------------------------------------------------------- command line

NUMBERS = ["0", "1", "3", "-1", "2.5", "1e12", "1e400", "-1e400", "nan", "inf", "abc", "",
           "9223372036854775807", "9223372036854775808", "0x10", "1_000"]
OPTION_VALUES = ["abc", "2.5", "3", "11", "-1", "0", "1e400", "[0.1, 0.3]", "[]", "true",
                 "null", "split", "combined", "free", "{a: 1}", "", "[1, [2]]", "&a [*a]"]
OPTION_KEYS = ["N", "M", "mode", "k_sigma", "deadzone", "tau", "n_cells", "max_nfev",
               "hold_rate", "min_hold", "sigma_grid", "p_grid", "refine", "eps", "ridge",
               "output_nfev", "search_nfev", "search_top", "cell_weights", "progress",
               "bogus", ""]
FAST_CELLS = ["sigma_grid=[0.03]", "p_grid=[1.0]", "refine=false", "progress=false"]
COMMANDS = ("simulate", "import-csv", "fit", "evaluate", "replay", "diagnose")
"""``node`` is left out: with a valid parameter file it starts the node and runs forever."""


def hostile_files(work: Path, fitted: dict[str, SensorCalibration]) -> dict[str, list[Path]]:
    """Input files by kind under ``work/in`` (good ones and hostile ones) and output paths
    under ``work/out`` (fresh, and ones that must be refused: FIFO, directory, symbolic
    link, device)."""
    import os

    from strain_comp.offline.rig import write_sim_bag

    ins, outs = work / "in", work / "out"
    ins.mkdir(parents=True)
    outs.mkdir()
    bag = ins / "good.mcap"
    write_sim_bag(simulate("triangle", seed=1, duration=20.0), bag)
    cal = ins / "cal.yaml"
    save_calibration(Calibration({"s1": fitted["cubic"]}), cal)
    csv = ins / "good.csv"
    csv.write_text("t,r,s\n" + "".join(f"{k * 0.1},{10 + (k % 50) * 0.1},{k % 50}\n"
                                        for k in range(300)))
    (ins / "empty").write_bytes(b"")
    (ins / "random.bin").write_bytes(np.random.default_rng(7).bytes(4096))
    (ins / "latin1.yaml").write_bytes(b"format: \xff\xfe\n")
    (ins / "laughs.yaml").write_text("a: &a [x,x,x,x,x,x,x,x,x,x]\n" + "".join(
        f"{c}: &{c} [{', '.join([f'*{p}'] * 10)}]\n"
        for p, c in zip("abcdefgh", "bcdefghi", strict=True)))
    (ins / "deep.yaml").write_text("[" * 2000 + "]" * 2000)
    (ins / "bigint.yaml").write_text("format: strain_comp/calibration/v1\nsensors: {s1: {"
                                     "model: {name: cubic, params: {c: [1" + "0" * 400 +
                                     ", 0, 0, 0]}}}}\n")
    os.mkfifo(ins / "fifo")
    (ins / "dir").mkdir()
    os.symlink(bag, ins / "link.mcap")
    os.link(bag, ins / "hard.mcap")
    os.symlink(ins / "loop", ins / "loop")
    rosbag = ins / "rosbag2"
    rosbag.mkdir()
    (rosbag / "metadata.yaml").write_text("rosbag2_bagfile_information:\n"
                                          "  relative_file_paths: [../good.mcap, 7]\n")
    os.mkfifo(outs / "fifo")
    (outs / "dir").mkdir()
    os.symlink(outs / "target", outs / "link")
    inputs = [bag, cal, csv, *(ins / n for n in ("empty", "random.bin", "latin1.yaml",
              "laughs.yaml", "deep.yaml", "bigint.yaml", "fifo", "dir", "link.mcap",
              "hard.mcap", "loop", "missing")), rosbag, Path("/dev/null")]
    fresh = [outs / f"new{k}{ext}" for k, ext in enumerate([".mcap", ".yaml", ".json", ""])]
    refused = [outs / "fifo", outs / "dir", outs / "link", Path("/dev/null")]
    return {"bag": [bag] * 4 + inputs, "cal": [cal] * 4 + inputs, "csv": [csv] * 4 + inputs,
            "out": fresh * 3 + refused + inputs}


def random_argv(rng: np.random.Generator, files: dict[str, list[Path]]
                ) -> tuple[list[str], list[str]]:
    """A command line built from the real subcommands and flags with hostile values, and
    the paths it names as inputs."""
    from strain_comp.offline.rig import SCENARIOS

    def pick(pool: list[Any]) -> str:
        return str(pool[int(rng.integers(0, len(pool)))])

    def maybe(p: float = 0.8) -> bool:
        return bool(rng.random() < p)

    command = pick(list(COMMANDS))
    argv = [command]
    inputs: list[str] = []

    def pick_input(kind: str) -> str:
        inputs.append(pick(files[kind]))
        return inputs[-1]

    if command == "simulate":
        argv += ["--scenario", pick([*SCENARIOS, "nope"])] if maybe(0.9) else []
        argv += ["--out", pick(files["out"])] if maybe(0.9) else []
        argv += ["--seed", pick(NUMBERS)] if maybe(0.5) else []
        argv += ["--duration", pick([*NUMBERS, "5", "30", "1e7"])] if maybe(0.8) else []
        for _ in range(int(rng.integers(0, 3))):
            argv += ["--effect", pick(["drift", "noise", "crosstalk", "adc_bits", "nope"])
                     + "=" + pick(NUMBERS)]
        argv += ["--list"] if maybe(0.05) else []
    elif command == "import-csv":
        argv += [pick_input("csv")]
        argv += ["--out", pick(files["out"])] if maybe(0.9) else []
        argv += ["--sensor", pick(["s1", "a/b", "", "all"])] if maybe(0.9) else []
        argv += ["--format", pick(["generic", "fiber", "cb_pdms", "xls"])] if maybe(0.9) else []
        argv += ["--columns", pick(["time=0,resistance=1,strain=2", "time=t,resistance=r",
                                    "time=9", "x", "time=0,resistance=0"])] if maybe() else []
        argv += ["--gauge-length-mm", pick(NUMBERS)] if maybe(0.3) else []
    elif command == "fit":
        argv += [pick_input("bag") for _ in range(int(rng.integers(1, 3)))]
        model = pick([*MODEL_NAMES, "quintic"])
        argv += ["--model", model] if maybe(0.95) else []
        argv += ["--sensor", pick(["all", "s1", "nope"])] if maybe(0.9) else []
        argv += ["--out", pick(files["out"])] if maybe(0.9) else []
        if model in ("apl", "pl", "mpi"):  # keep a grid search short
            argv += [x for o in FAST_CELLS for x in ("--option", o)]
        for _ in range(int(rng.integers(0, 3))):
            argv += ["--option", pick(OPTION_KEYS) + pick(["=", "=", ""]) + pick(OPTION_VALUES)]
    elif command in ("evaluate", "replay", "diagnose"):
        argv += [pick_input("bag")]
        argv += ["--calibration", pick_input("cal")] if maybe(0.9) else []
        if command == "replay" or (command == "diagnose" and maybe(0.9)):
            argv += ["--out", pick(files["out"])]
        if command != "replay":
            argv += ["--json", pick(files["out"])] if maybe(0.4) else []
            argv += ["--plots", pick(files["out"])] if maybe(0.1) else []
        if command == "diagnose" and maybe(0.3):
            argv += ["--validate", pick_input("bag")]
    if maybe(0.05):
        argv.insert(int(rng.integers(0, len(argv) + 1)), pick(["--bogus", "-x", "--", "-"]))
    return argv, inputs


def _digest(paths: list[str]) -> dict[str, bytes]:
    """The SHA-256 of every regular file among ``paths`` (and inside a directory among them)."""
    import hashlib
    import os

    found: dict[str, bytes] = {}
    for name in paths:
        path = Path(name)
        if not os.path.exists(path):
            continue
        for p in [path, *(sorted(path.rglob("*")) if path.is_dir() else [])]:
            if p.is_file():
                found[str(p)] = hashlib.sha256(p.read_bytes()).digest()
    return found


def _restore(directory: Path, pristine: dict[Path, bytes]) -> None:
    """Put ``directory``'s regular files back as they were (a run may legitimately write
    over a file it does not read) and delete the files it created."""
    for p in directory.rglob("*"):
        if p.is_file() and not p.is_symlink() and p not in pristine:
            p.unlink()
    for p, data in pristine.items():
        if p.read_bytes() != data:
            p.write_bytes(data)


def check_cli(argv: list[str], inputs: list[str]) -> tuple[int, str]:
    """Run ``strain-comp argv`` in this process; (exit code, stderr). AssertionError when
    the contract breaks: an exit code other than 0, 2, 70, 130; an exception out of
    ``main``; more than one error line or a traceback on stderr; an input file changed."""
    import contextlib
    import io

    from strain_comp.cli import main as cli_main

    before = _digest(inputs)  # the files this command reads
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli_main(argv)
    text = err.getvalue()
    errors = [line for line in text.splitlines() if line.startswith("strain-comp: error:")]
    faults = [line for line in text.splitlines()
              if line.startswith("strain-comp: internal error:")]
    assert code in (0, 2, 70, 130), f"exit code {code}"
    assert "Traceback" not in text, text
    assert len(errors) == (1 if code == 2 else 0), text
    assert len(faults) == (1 if code == 70 else 0), text
    assert _digest(inputs) == before, "an input file changed"
    return code, text


@dataclass
class CliStats:
    """Counts of a command-line fuzz run."""

    runs: int = 0
    exits: dict[int, int] = field(default_factory=dict)
    unexpected: list[tuple[list[str], str]] = field(default_factory=list)
    """Runs that ended in a fault of the program (exit 70, one ``internal error`` line):
    the contract held but strain_comp had a bug."""
    crashes: list[tuple[list[str], str]] = field(default_factory=list)

    def line(self) -> str:
        codes = ", ".join(f"exit {k}: {v}" for k, v in sorted(self.exits.items()))
        return (f"cli: {self.runs} command lines ({codes}), {len(self.unexpected)} faults of "
                f"the program (exit 70), {len(self.crashes)} crashes")


def fuzz_cli(fitted: dict[str, SensorCalibration], rng: np.random.Generator, work: Path, *,
             seconds: float | None = None, iterations: int | None = None,
             timeout: float = 60.0) -> CliStats:
    """Random command lines (``random_argv``) over hostile files, checked by ``check_cli``."""
    files = hostile_files(work, fitted)
    pristine = {p: p.read_bytes() for p in (work / "in").rglob("*")
                if p.is_file() and not p.is_symlink()}
    stats = CliStats()
    deadline = time.monotonic() + (seconds if seconds is not None else math.inf)
    previous = signal.signal(signal.SIGALRM, _alarm_base)
    try:
        while time.monotonic() < deadline and (iterations is None or stats.runs < iterations):
            argv, inputs = random_argv(rng, files)
            stats.runs += 1
            signal.setitimer(signal.ITIMER_REAL, timeout)
            try:
                code, text = check_cli(argv, inputs)
            except (Exception, HangBase):
                stats.crashes.append((argv, traceback.format_exc()))
                continue
            finally:
                signal.setitimer(signal.ITIMER_REAL, 0.0)
                _restore(work / "in", pristine)
            stats.exits[code] = stats.exits.get(code, 0) + 1
            if code == 70:
                stats.unexpected.append((argv, text.strip()))
    finally:
        signal.signal(signal.SIGALRM, previous)
    return stats

# ---------------------------------------------------------------- many-bag evaluate

BAG_NAMES = ["a.mcap", "b.mcap", "...mcap", "x.mcap", "run 1.mcap", "bag.mcap", "bag_2.mcap"]


@dataclass
class EvaluateStats:
    """Counts of a many-bag ``evaluate`` fuzz run."""

    runs: int = 0
    exits: dict[int, int] = field(default_factory=dict)
    crashes: list[tuple[list[str], str]] = field(default_factory=list)
    rss_mib: list[float] = field(default_factory=list)
    """The fuzzing process's RSS after each folder (the command runs in it, ``--jobs 2``
    workers apart)."""

    def line(self) -> str:
        codes = ", ".join(f"exit {k}: {v}" for k, v in sorted(self.exits.items()))
        rss = (f"RSS {self.rss_mib[0]:.0f} MiB after the first folder, {self.rss_mib[-1]:.0f} "
               f"at the end, max {max(self.rss_mib):.0f}" if self.rss_mib else "RSS unknown")
        return (f"evaluate: {self.runs} folders ({codes}), {len(self.crashes)} crashes; {rss}; "
                f"RSS growth {rss_growth(self.rss_mib):+.1f} MiB (last quarter vs second)")

    @property
    def failed(self) -> int:
        return len(self.crashes) + (rss_growth(self.rss_mib) > RSS_GROWTH_MIB)


def check_outputs(out: Path, code: int) -> None:
    """What a many-bag ``evaluate`` may leave in ``out``: the table, the JSON and plots
    only under ``plots/``, no temporary file; when it wrote them, a table with a header and
    a JSON that parses, every number in it finite or null."""
    import json

    for p in out.rglob("*"):
        if p.name.endswith(".tmp") or (p.name.startswith(".") and p.is_file()):
            raise AssertionError(f"a temporary file is left: {p}")
        if p.is_file() and p.parent != out and out / "plots" not in p.parents:
            raise AssertionError(f"written outside the plots folder: {p}")
        if p.is_file() and p.parent == out and p.name not in ("out.csv", "out.json"):
            raise AssertionError(f"an unexpected file: {p}")
    if (out / "out.json").exists():
        text = (out / "out.json").read_text()
        if "NaN" in text or "Infinity" in text:
            raise AssertionError("a non-finite number in the JSON")
        json.loads(text)
    if (out / "out.csv").exists() and not (out / "out.csv").read_text().startswith("bag,"):
        raise AssertionError("the table has no header")
    if code == 0 and not (out / "out.json").exists():
        raise AssertionError("exit 0 without its JSON")


def fuzz_evaluate(seeds: list[bytes], calibration: Calibration, rng: np.random.Generator,
                  work: Path, *, seconds: float | None = None, iterations: int | None = None,
                  timeout: float = 120.0) -> EvaluateStats:
    """``evaluate FOLDER --csv --json --plots --jobs 1|2`` over folders of 1 to 5 seed and
    damaged bags (names that repeat, ``...mcap``), checked by ``check_cli`` and
    ``check_outputs``."""
    import shutil

    work.mkdir(parents=True, exist_ok=True)
    cal = work / "cal.yaml"
    save_calibration(calibration, cal)
    stats = EvaluateStats()
    deadline = time.monotonic() + (seconds if seconds is not None else math.inf)
    previous = signal.signal(signal.SIGALRM, _alarm_base)
    try:
        while time.monotonic() < deadline and (iterations is None or stats.runs < iterations):
            folder, out = work / "bags", work / "out"
            for d in (folder, out):
                shutil.rmtree(d, ignore_errors=True)
                d.mkdir()
            names = rng.choice(BAG_NAMES, size=int(rng.integers(1, 6)), replace=False)
            for name in names:
                seed = seeds[int(rng.integers(0, len(seeds)))]
                (folder / str(name)).write_bytes(seed if rng.random() < 0.5
                                                 else mutate_bag(seed, rng))
            argv = ["evaluate", str(folder), "--calibration", str(cal), "--csv",
                    str(out / "out.csv"), "--json", str(out / "out.json"), "--plots",
                    str(out / "plots"), "--jobs", str(int(rng.choice([1, 2]))), "-q"]
            stats.runs += 1
            signal.setitimer(signal.ITIMER_REAL, timeout)
            try:
                code, _ = check_cli(argv, [str(folder), str(cal)])
                check_outputs(out, code)
            except (Exception, HangBase):
                stats.crashes.append((argv, traceback.format_exc()))
                continue
            finally:
                signal.setitimer(signal.ITIMER_REAL, 0.0)
            stats.exits[code] = stats.exits.get(code, 0) + 1
            rss = _rss_mib(os.getpid())
            if rss is not None:
                stats.rss_mib.append(rss)
    finally:
        signal.signal(signal.SIGALRM, previous)
    return stats


# ---------------------------------------------------------------- CSV importer

CSV_HOSTILE = [b"\xef\xbb\xbf", "\u2028".encode(), "\u0085".encode(), b"\r", b"\x0b",
               b"\x00", b'"', b'""', b",,,,", b";", b"\t", b"nan", b"-inf", b"1e308",
               b"-1", b"0", b"1700000000000000000", b"1e-300", b"\xff\xfe", b"x" * 200_000]
CSV_COLUMNS = [0, 1, 2, 3, "0", "2", "600000", "1000000000", "\u00b2", "-1", "time",
               "resistance", "strain", "nope"]


def seed_csv() -> bytes:
    """A generic three-column CSV with a header: time [s], resistance [ohm], strain [%]."""
    t = np.arange(200) * 0.01
    rows = [f"{ti:.2f},{100 + 10 * math.sin(ti):.4f},{20 + 20 * math.sin(ti):.4f}" for ti in t]
    return ("time,resistance,strain\n" + "\n".join(rows) + "\n").encode()


def mutate_csv(data: bytes, rng: np.random.Generator) -> bytes:
    """Byte flips, hostile snippets (a byte-order mark, Unicode line separators, huge
    fields, epoch nanoseconds, NaN), truncations and duplicated spans."""
    buf = bytearray(data)
    for _ in range(int(rng.integers(1, 5))):
        op = int(rng.integers(0, 4))
        pos = int(rng.integers(0, len(buf) + 1))
        if op == 0 and buf:
            buf[min(pos, len(buf) - 1)] ^= 1 << int(rng.integers(0, 8))
        elif op == 1:
            buf[pos:pos] = CSV_HOSTILE[int(rng.integers(0, len(CSV_HOSTILE)))]
        elif op == 2:
            del buf[pos:]
        else:
            end = min(len(buf), pos + int(rng.integers(1, 400)))
            buf[pos:pos] = buf[pos:end] * int(rng.integers(1, 20))
    return bytes(buf)


def check_csv(path: Path, rng: np.random.Generator) -> bool:
    """True if the file imported (consistently) and was written as a bag; False if refused
    with InputError (one line); raises else."""
    from strain_comp.errors import InputError
    from strain_comp.io.bag.schemas import MAX_TIME_S
    from strain_comp.io.csv_import import import_csv
    from strain_comp.io.recording import write_recordings

    columns = {key: CSV_COLUMNS[int(rng.integers(0, len(CSV_COLUMNS)))]
               for key in ("time", "resistance", "strain") if key != "strain" or rng.random() < 0.7}
    scales = {"time": 1e-9} if rng.random() < 0.1 else None
    try:
        rec, report = import_csv(path, fmt="generic", sensor="s1", columns=columns,
                                 scales=scales)
    except InputError as err:
        if "\n" in str(err):
            raise AssertionError(f"error message not one line: {err}") from None
        return False
    t, r = np.asarray(rec.t), np.asarray(rec.r)
    if not (np.isfinite(t).all() and (np.diff(t) > 0).all() and t.min() >= 0
            and t.max() <= MAX_TIME_S and np.isfinite(r).all() and (r > 0).all()):
        raise AssertionError("imported samples that the bag readers would skip")
    if report.kept + sum(report.dropped.values()) != report.rows:
        raise AssertionError("rows lost: kept + dropped != rows")
    write_recordings({rec.name: rec}, path.with_suffix(".mcap"))
    return True


def fuzz_csv(rng: np.random.Generator, work: Path, **limits: Any) -> Stats:
    """Fuzz ``import_csv`` (random column mappings too) and the bag it writes."""
    seed = seed_csv()
    return run_target(Stats("csv"), lambda: mutate_csv(seed, rng),
                      lambda path: check_csv(path, rng), work / "in.csv", **limits)


# ---------------------------------------------------------------- the live node

@dataclass
class NodeStats:
    """What the node fuzzer sent, what came back, and how the node process fared."""

    sent: dict[str, int] = field(default_factory=dict)
    outputs: int = 0
    non_finite: list[str] = field(default_factory=list)
    rss_mib: list[float] = field(default_factory=list)
    alive: bool = True
    tracebacks: list[str] = field(default_factory=list)
    refused_params: int = 0
    clock_modes: dict[str, int] = field(default_factory=dict)
    """How many stretches of ``CLOCK_MODE_SECONDS`` the clock ran, stood still, ran back."""

    @property
    def rss_growth(self) -> float:
        return rss_growth(self.rss_mib)

    def line(self) -> str:
        sent = ", ".join(f"{k} {v}" for k, v in sorted(self.sent.items()))
        modes = ", ".join(f"{k} {v}" for k, v in sorted(self.clock_modes.items()))
        warm = self.rss_mib[min(5, len(self.rss_mib) - 1)] if self.rss_mib else math.nan
        rss = (f"RSS {warm:.0f} MiB at 5 s, {self.rss_mib[-1]:.0f} at the end, max "
               f"{max(self.rss_mib):.0f}" if self.rss_mib else "RSS unknown")
        return (f"node: sent {sum(self.sent.values())} ({sent}); {self.outputs} outputs, "
                f"{len(self.non_finite)} non-finite; {rss}; "
                f"RSS growth {self.rss_growth:+.1f} MiB (last quarter vs second); "
                f"{'alive' if self.alive else 'DIED'}; {len(self.tracebacks)} tracebacks; "
                f"{self.refused_params} parameter sets refused; clock stretches: {modes}")

    @property
    def failed(self) -> bool:
        return bool(self.non_finite or not self.alive or self.tracebacks
                    or self.rss_growth > RSS_GROWTH_MIB)


def rss_growth(samples: list[float]) -> float:
    """MiB the last quarter of the RSS ``samples`` (median) exceeds their second quarter
    (0 with fewer than 8 samples)."""
    n = len(samples)
    if n < 8:
        return 0.0
    return float(np.median(samples[3 * n // 4:]) - np.median(samples[n // 4:n // 2]))


def _rss_mib(pid: int) -> float | None:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        return None
    return None


NODE_VALUES = [15.0, 20.0, 25.0, math.nan, math.inf, -math.inf, 0.0, -5.0, 1e308, 1e-300,
               5e-324, 1e12]
NODE_TEMPERATURES = [20.0, 35.0, 1e308, -1e308, math.nan, math.inf, -300.0, 1000.5]
NODE_PARAMETERS: list[tuple[str, Any]] = [
    ("use_sim_time", False), ("use_sim_time", True), ("deadzone_scale", 2.0),
    ("deadzone_scale", -1.0), ("deadzone_scale", math.nan), ("gap_reset_s", 1e308),
    ("gap_reset_s", "x"), ("stale_after_s", 0.5), ("publish_rate_limit_hz", 1e9),
    ("diagnostics_period_s", 0.01), ("no_such_parameter", 1.0), ("s1.topic", "/elsewhere"),
    ("tare", "auto"), ("deadzone_scale", [1.0, 2.0])]


def _node_params(work: Path) -> Path:
    """Params for one sensor (its calibration with a temperature term) and the 6-sensor
    array of the bundled configs, under sim time."""
    config = Path(__file__).resolve().parent.parent / "config"
    cal = load_calibration(config / "demo_calibration.yaml")
    s1 = cal.sensors["s1"]
    cal.sensors["s1"] = SensorCalibration(**{
        **vars(s1), "rest_resistance": 11.0,
        "effects": [{"name": "t", "kind": "temperature",
                     "params": {"form": "offset", "t_ref": 20.0}, "coef": 0.05}]})
    save_calibration(cal, work / "s1.yaml")
    params = work / "params.yaml"
    params.write_text(
        "compensator:\n  ros__parameters:\n"
        f"    sensors: [s1]\n    s1: {{calibration: {work / 's1.yaml'}}}\n"
        f"    arrays: [array]\n    array: {{sensors: [a1, a2, a3, a4, a5, a6], "
        f"calibration: {config / 'array_calibration.yaml'}}}\n"
        "    diagnostics_period_s: 0.2\n")
    return params


NODE_START_S = 60.0
CLOCK_MODES = ("run", "paused", "backwards")
CLOCK_MODE_SECONDS = 2.0
"""How long the node target keeps one clock mode."""
RSS_GROWTH_MIB = 32.0
"""The RSS (the node's; the evaluate fuzzer's own) over the last quarter of a run may exceed
that of the second quarter (after start-up and the first compilations) by at most this
much: flat."""
"""How long ``fuzz_node`` waits for the node to subscribe before it starts the clock."""


def fuzz_node(rng: np.random.Generator, work: Path, *, seconds: float) -> NodeStats:
    """Start ``compensator`` (sim time) as its own process, then from this process send it
    hostile sensor, temperature and array messages, /clock ticks and parameter sets and
    call its services for ``seconds``; every strain it publishes must be finite, it must
    live, print no traceback, and its RSS is sampled every second."""
    import os
    import subprocess

    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter
    from rclpy.parameter_client import AsyncParameterClient
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import Temperature
    from std_msgs.msg import Float64, Float64MultiArray, MultiArrayDimension
    from std_srvs.srv import Trigger

    work.mkdir(parents=True, exist_ok=True)
    params = _node_params(work)
    log = (work / "node.log").open("w")
    proc = subprocess.Popen(
        [sys.executable, "-c", "import sys; from strain_comp.ros.node import main; "
         "sys.exit(main(sys.argv))", "--ros-args", "--params-file", str(params),
         "-p", "use_sim_time:=true"], stdout=log, stderr=subprocess.STDOUT,
        env={**os.environ, "PYTHONUNBUFFERED": "1"})
    stats = NodeStats()
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    peer = rclpy.create_node("hostile_peer", context=ctx)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(peer)
    pubs = {"s1": peer.create_publisher(Float64, "/s1/resistance", 10),
            "temperature": peer.create_publisher(Temperature, "/s1/temperature", 10),
            "array": peer.create_publisher(Float64MultiArray, "/array/resistance", 10),
            "clock": peer.create_publisher(Clock, "/clock", 10)}

    def got(topic: str, msg: Any) -> None:
        stats.outputs += 1
        values = np.atleast_1d(np.asarray(msg.data, dtype=np.float64))
        if not np.isfinite(values).all():
            stats.non_finite.append(f"{topic}: {values.tolist()[:6]}")

    for topic, kind in (("/s1/strain", Float64), ("/array/strain", Float64MultiArray)):
        peer.create_subscription(kind, topic, lambda m, t=topic: got(t, m), 100)
    client = AsyncParameterClient(peer, "compensator")
    services = {name: peer.create_client(Trigger, f"/compensator/{name}")
                for name in ("tare", "reload_calibration")}
    pending: list[Any] = []
    t_ns = 10**9
    labels = ["a1", "a2", "a3", "a4", "a5", "a6"]

    def count(kind: str) -> None:
        stats.sent[kind] = stats.sent.get(kind, 0) + 1

    ready_by = time.monotonic() + NODE_START_S  # the fuzzing time counts once it listens
    while (pubs["s1"].get_subscription_count() == 0 and proc.poll() is None
           and time.monotonic() < ready_by):
        executor.spin_once(timeout_sec=0.05)
    start = time.monotonic()
    deadline = start + seconds
    next_rss = start
    modes = np.random.default_rng(int(rng.integers(2**63)))  # the seed's alone, not timing's
    next_mode, mode = start + CLOCK_MODE_SECONDS, "run"  # a clock first runs
    stats.clock_modes[mode] = 1
    try:
        while time.monotonic() < deadline and proc.poll() is None:
            if time.monotonic() >= next_mode:  # the clock runs, stands still or runs back
                mode = str(modes.choice(CLOCK_MODES, p=[0.5, 0.25, 0.25]))
                stats.clock_modes[mode] = stats.clock_modes.get(mode, 0) + 1
                next_mode += CLOCK_MODE_SECONDS
            op = int(rng.integers(0, 10))
            if op <= 2 and mode == "paused":  # /clock silent: the inputs keep coming
                op = 3
            if op <= 2:
                step = int(rng.integers(1, 20)) * 10**6
                t_ns = max(10**9, t_ns - step) if mode == "backwards" else t_ns + step
                clock = Clock()
                clock.clock.sec, clock.clock.nanosec = divmod(t_ns, 10**9)
                if rng.random() < 0.2:  # hostile: negative, huge, backwards, odd nanoseconds
                    clock.clock.sec = int(rng.choice([-1, -2**31, 2**31 - 1, 0]))
                    clock.clock.nanosec = int(rng.integers(0, 2**32))
                pubs["clock"].publish(clock)
                count("clock")
            elif op <= 4:
                pubs["s1"].publish(Float64(data=float(rng.choice(NODE_VALUES)
                                                      if rng.random() < 0.4
                                                      else rng.uniform(10.5, 29.0))))
                count("resistance")
            elif op == 5:
                msg = Temperature()
                msg.temperature = float(rng.choice(NODE_TEMPERATURES))
                pubs["temperature"].publish(msg)
                count("temperature")
            elif op <= 7:
                n = int(rng.choice([6, 6, 6, 0, 5, 7, 8, 64]))
                msg = Float64MultiArray()
                msg.data = [float(rng.choice(NODE_VALUES)) if rng.random() < 0.2
                            else float(rng.uniform(12.0, 16.0)) for _ in range(n)]
                if rng.random() < 0.5:
                    order = list(rng.permutation(labels)) if rng.random() < 0.7 else \
                        [*labels[:5], str(rng.choice(["x", "a1", "", "a,b", "é" * 100]))]
                    msg.layout.dim = [MultiArrayDimension(
                        label=",".join(order), size=int(rng.choice([6, 6, 5, 2**32 - 1])),
                        stride=6)]
                    msg.layout.data_offset = int(rng.choice([0, 0, 1, 2**32 - 1]))
                pubs["array"].publish(msg)
                count("array")
            elif op == 8:
                name, value = NODE_PARAMETERS[int(rng.integers(0, len(NODE_PARAMETERS)))]
                try:
                    future = client.set_parameters([Parameter(name, value=value)])
                except (TypeError, ValueError):  # rclpy refuses the value itself
                    continue
                pending.append(future)
                count("set_parameters")
            elif rng.random() < 0.2:
                name = "reload_calibration" if rng.random() < 0.3 else "tare"
                if services[name].service_is_ready():
                    services[name].call_async(Trigger.Request())
                    count(name)
            executor.spin_once(timeout_sec=0.002)
            for future in [f for f in pending if f.done()]:
                pending.remove(future)
                result = future.result()
                stats.refused_params += sum(not r.successful for r in result.results)
            if time.monotonic() >= next_rss:
                rss = _rss_mib(proc.pid)
                if rss is not None:
                    stats.rss_mib.append(rss)
                next_rss += 1.0
    finally:
        stats.alive = proc.poll() is None
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        log.close()
        executor.shutdown(timeout_sec=0.5)
        peer.destroy_node()
        rclpy.try_shutdown(context=ctx)
    text = (work / "node.log").read_text(errors="replace")
    stats.tracebacks = [chunk[:2000] for chunk in text.split("Traceback")[1:]]
    return stats


class HangBase(BaseException):
    """A command line ran past the time limit (a BaseException: the command line's
    last-resort frame must not turn it into an ordinary exit 2)."""


def _alarm_base(signum: int, frame: Any) -> None:
    raise HangBase("time limit exceeded")


def save_crashes(stats: Stats, out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    suffix = {"yaml": ".yaml", "csv": ".csv"}.get(stats.target, ".mcap")
    for k, (data, trace) in enumerate(stats.crashes):
        (out / f"{stats.target}_crash_{k}{suffix}").write_bytes(data)
        (out / f"{stats.target}_crash_{k}.txt").write_text(trace)
        print(f"crash saved to {out / f'{stats.target}_crash_{k}{suffix}'}: "
              f"{trace.strip().splitlines()[-1]}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="total fuzzing time")
    parser.add_argument("--target", choices=("yaml", "bag", "cli", "csv", "node", "evaluate",
                                             "db3", "api", "all"),
                        default="all")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path(tempfile.gettempdir()) / "strain_fuzz")
    parser.add_argument("--replay-every", type=int, default=10)
    parser.add_argument("--timeout", type=float, default=10.0, help="seconds per input")
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    targets = (["yaml", "bag", "cli", "csv", "node", "evaluate", "db3", "api"]
               if args.target == "all"
               else [args.target])
    share = args.seconds / len(targets)
    failures = 0
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        fitted = fit_every_model()
        calibration = seed_calibration(fitted)
        seed_yaml = work / "seed.yaml"
        save_calibration(calibration, seed_yaml)
        check_yaml(seed_yaml)  # the seed itself must load and run
        for target in targets:
            if target == "api":
                api = fuzz_api(rng, seconds=share, timeout=max(args.timeout, 30.0))
                print(api.line(), flush=True)
                for key, calls in sorted(api.internal.items(), key=lambda kv: -len(kv[1])):
                    print(f"  {len(calls)} x {key}\n    e.g. {calls[0][:200]}")
                failures += sum(len(v) for v in api.internal.values())
                if api.traces:
                    args.out.mkdir(parents=True, exist_ok=True)
                    (args.out / "api_internal.txt").write_text("\n".join(api.traces.values()))
                    print(f"  tracebacks saved to {args.out / 'api_internal.txt'}")
                continue
            if target == "db3":
                stats = fuzz_db3(rng, work / "db3", seconds=share, timeout=args.timeout)
                print(stats.line() + f"; RSS {_own_rss():.0f} MiB at the end", flush=True)
                save_crashes(stats, args.out)
                failures += len(stats.crashes)
                continue
            if target == "node":
                node = fuzz_node(rng, work / "node", seconds=share)
                print(node.line(), flush=True)
                for line in node.non_finite[:5] + node.tracebacks[:3]:
                    print("  " + line.strip().replace("\n", "\n  "))
                failures += node.failed
                continue
            if target == "evaluate":
                many = fuzz_evaluate(seed_bags(work), replay_calibration(fitted), rng,
                                     work / "evaluate", seconds=share,
                                     timeout=max(args.timeout, 120.0))
                print(many.line(), flush=True)
                for argv, text in many.crashes:
                    print("  strain-comp " + " ".join(argv) + "\n    " +
                          text.strip().splitlines()[-1])
                failures += many.failed
                continue
            if target == "csv":
                stats = fuzz_csv(rng, work, seconds=share, timeout=args.timeout)
                print(stats.line(), flush=True)
                save_crashes(stats, args.out)
                failures += len(stats.crashes)
                continue
            if target == "cli":
                cli = fuzz_cli(fitted, rng, work / "cli", seconds=share,
                               timeout=max(args.timeout, 60.0))
                print(cli.line(), flush=True)
                for argv, text in cli.unexpected + cli.crashes:
                    print("  strain-comp " + " ".join(argv) + "\n    " +
                          text.strip().splitlines()[-1])
                failures += len(cli.crashes)
                continue
            if target == "yaml":
                stats = fuzz_yaml(seed_yaml.read_bytes(), rng, work, seconds=share,
                                  timeout=args.timeout)
            else:
                stats = fuzz_bag(seed_bags(work), replay_calibration(fitted), rng, work,
                                 seconds=share,
                                 replay_every=args.replay_every, timeout=args.timeout)
            print(stats.line(), flush=True)
            save_crashes(stats, args.out)
            failures += len(stats.crashes)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
