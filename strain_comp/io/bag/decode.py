"""Collected messages decoded into a ``BagContents``: fixed layouts in bulk with numpy, the
other types one by one through ``mcap_ros2``'s decoder on the standard definitions
(``schemas.SCHEMAS``), never on the schema text in the bag (docs/reliability.md)."""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import Any

import numpy as np
from mcap.records import Schema
from mcap_ros2.decoder import DecoderFactory

from strain_comp.errors import InputError
from strain_comp.io.bag.records import MAX_LOG_NS, Collector, gather
from strain_comp.io.bag.schemas import SCHEMAS, BagContents, Series, norm_type
from strain_comp.io.multiarray import array_values, label_names

_FIXED_SCALAR = {  # type -> (payload byte offset, numpy little-endian dtype)
    "std_msgs/msg/Float64": (4, "<f8"),
    "std_msgs/msg/Float32": (4, "<f4"),
    "std_msgs/msg/Int8": (4, "i1"),
}

# what the CDR decoder raises on a damaged payload (short reads, bad lengths, bad UTF-8)
_PAYLOAD_ERRORS = (struct.error, ValueError, IndexError, OverflowError, MemoryError)
#: types decoded message by message with their standard definitions
_DECODED_TYPES = ("std_msgs/msg/Float64MultiArray", "sensor_msgs/msg/Temperature",
                  "diagnostic_msgs/msg/DiagnosticArray")
_DECODERS = DecoderFactory()


def _decoder(kind: str) -> Callable[[bytes], Any]:
    schema = Schema(id=_DECODED_TYPES.index(kind) + 1, name=kind, encoding="ros2msg",
                    data=SCHEMAS[kind].encode())
    decoder = _DECODERS.decoder_for("cdr", schema)
    assert decoder is not None  # None only for another encoding than cdr / ros2msg
    return decoder


def decode(col: Collector) -> BagContents:
    """The messages ``col`` located, decoded per topic in log-time order."""
    out = BagContents(problems=col.problems)
    if not col.msg_channel:
        return out
    blob, start, length, log_ns, groups = channel_messages(col, out.problems)
    per_type: dict[tuple[str, str], tuple[Schema, list[np.ndarray]]] = {}
    for topic, schema, idx in groups:
        per_type.setdefault((topic, norm_type(schema.name)), (schema, []))[1].append(idx)
    for topic, kind, schema, parts in _one_type_per_topic(out, per_type):
        out.types[topic] = kind
        idx = np.concatenate(parts)
        idx = idx[np.argsort(log_ns[idx], kind="stable")]
        _decode_topic(out, topic, schema, blob, start[idx], length[idx],
                      log_ns[idx].astype(np.float64) * 1e-9)
    return out


def channel_messages(col: Collector, problems: list[str]
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                list[tuple[str, Schema, np.ndarray]]]:
    """The payloads joined, each message's start, length, log time [ns]; per channel kept."""
    sizes = np.array([b.shape[0] for b in col.blocks], dtype=np.int64)
    blob = np.concatenate(col.blocks) if len(col.blocks) > 1 else col.blocks[0]
    base = np.concatenate(([0], np.cumsum(sizes)[:-1])).astype(np.int64)
    block = np.concatenate(col.msg_block)
    start = np.concatenate(col.msg_start) + base[block]
    length = np.concatenate(col.msg_len)
    log_ns = np.concatenate(col.msg_time)
    late = (log_ns < 0) | (log_ns > MAX_LOG_NS)
    if late.any():
        problems.append(f"{int(np.count_nonzero(late))} messages with a log time beyond "
                        "2^31 s (2038-01-19) skipped")
    # channel ids are per file: key messages by (file, channel id)
    key = np.array(col.block_file, dtype=np.int64)[block] * 65536 + np.concatenate(col.msg_channel)
    valid = np.flatnonzero(~late)
    order = valid[np.argsort(key[valid], kind="stable")]  # grouped by channel in one sort
    keys, first = np.unique(key[order], return_index=True)
    groups = []
    for k, idx in zip(keys.tolist(), np.split(order, first[1:]) if keys.size else [],
                      strict=True):
        f, cid = divmod(k, 65536)
        channel = col.channels.get((f, cid))
        if channel is None:
            problems.append(f"{idx.size} messages on unknown channel id {cid} skipped")
            continue
        if col.topics is not None and channel.topic not in col.topics:
            continue
        schema = col.schemas.get((f, channel.schema_id))
        if schema is None or schema.encoding != "ros2msg" or channel.message_encoding != "cdr":
            problems.append(f"{channel.topic}: no ros2msg schema / cdr encoding; "
                            f"{idx.size} messages skipped")
            continue
        groups.append((channel.topic, schema, idx))
    return blob, start, length, log_ns, groups


def _one_type_per_topic(out: BagContents,
                        per_type: dict[tuple[str, str], tuple[Schema, list[np.ndarray]]]
                        ) -> list[tuple[str, str, Schema, list[np.ndarray]]]:
    """Per topic the type with the most messages (first on a tie); the others counted."""
    kept: dict[str, tuple[str, Schema, list[np.ndarray]]] = {}
    for (topic, kind), (schema, parts) in per_type.items():
        n = sum(p.size for p in parts)
        other = kept.get(topic)
        if other is None or n > sum(p.size for p in other[2]):
            kept[topic] = (kind, schema, parts)
    for (topic, kind), (_, parts) in per_type.items():
        if kept[topic][0] != kind:
            out.problems.append(f"{topic}: recorded with two message types; its "
                                f"{sum(p.size for p in parts)} {kind} messages skipped "
                                f"(the topic is read as {kept[topic][0]})")
    return [(topic, kind, schema, parts) for topic, (kind, schema, parts) in kept.items()]


def _decode_topic(out: BagContents, topic: str, schema: Schema, blob: np.ndarray,
                  start: np.ndarray, length: np.ndarray, t: np.ndarray) -> None:
    kind = norm_type(schema.name)
    if kind in _FIXED_SCALAR:
        offset, dtype = _FIXED_SCALAR[kind]
        width = np.dtype(dtype).itemsize
        ok = length >= offset + width
        if not ok.all():
            out.problems.append(f"{topic}: {int((~ok).sum())} malformed {kind} messages skipped")
        start, t = start[ok], t[ok]
        raw = gather(blob, start + offset, width)
        little = (blob[start + 1] & 1) == 1
        values = np.empty(start.shape, np.float64)
        values[little] = raw[little].copy().view(dtype)[:, 0]
        if not little.all():
            values[~little] = raw[~little].copy().view(np.dtype(dtype).newbyteorder(">"))[:, 0]
        out.series[topic] = Series(t, values)
        return
    if kind == "sensor_msgs/msg/JointState":
        return  # the stamped copy of a strain output (``types`` lists it): nothing to read
    if kind not in _DECODED_TYPES:
        out.problems.append(f"{topic}: unsupported message type {schema.name}; "
                            f"{start.size} messages skipped")
        return
    decoder = _decoder(kind)
    if kind == "std_msgs/msg/Float64MultiArray":
        _decode_array(out, topic, decoder, blob, start, length, t)
        return
    temperature = kind == "sensor_msgs/msg/Temperature"
    times: list[float] = []
    items: list[Any] = []
    bad = 0
    for s, n, ti in zip(start.tolist(), length.tolist(), t.tolist(), strict=True):
        try:
            msg = decoder(blob[s:s + n].tobytes())
            items.append(float(msg.temperature) if temperature else
                         [(str(x.name), int(x.level), str(x.message),
                           {str(kv.key): str(kv.value) for kv in x.values})
                          for x in msg.status])
            times.append(ti)
        except _PAYLOAD_ERRORS:  # malformed payload: count it, keep going
            bad += 1
    if bad:
        out.problems.append(f"{topic}: {bad} malformed {kind} messages skipped")
    if temperature:
        out.series[topic] = Series(np.array(times, np.float64), np.array(items, np.float64))
    else:
        out.diagnostics.extend(zip(times, items, strict=True))
        out.diagnostics.sort(key=lambda d: d[0])


def _decode_array(out: BagContents, topic: str, decoder: Any, blob: np.ndarray,
                  start: np.ndarray, length: np.ndarray, t: np.ndarray) -> None:
    """Float64MultiArray as the node reads it (``array_values``); k from the first good one."""
    # in bulk: the messages byte-identical to a plain first one (offset 0, k values) but values
    first = None
    for i in range(start.size):
        try:  # the first message that decodes into a well-formed array fixes the layout
            msg = decoder(blob[start[i]:start[i] + length[i]].tobytes())
            sizes = [int(d.size) for d in msg.layout.dim]
            offset = int(msg.layout.data_offset)
            k = sizes[0] if sizes else len(msg.data) - offset
            if k <= 0:  # an empty array cannot fix the layout
                continue
            array_values(msg.data, offset, sizes, k)
            first = (msg, k, offset)
            break
        except (*_PAYLOAD_ERRORS, InputError):  # find the first decodable message
            continue
    if first is None:
        out.problems.append(f"{topic}: no decodable Float64MultiArray message; skipped")
        return
    msg, k, offset = first
    n0 = int(length[i])
    prefix_len = n0 - 8 * k
    ref = blob[start[i]:start[i] + prefix_len]
    same = length == n0
    if same.any() and prefix_len > 0:
        same[same] = (gather(blob, start[same], prefix_len) == ref).all(axis=1)
    label0 = label_names(str(msg.layout.dim[0].label) if msg.layout.dim else "")
    names = label0 if len(set(label0)) == len(label0) == k else _first_names(
        decoder, blob, start[~same], length[~same], k)
    if names is not None:
        out.labels[topic] = names
    values = np.full((start.size, k), np.nan)
    if offset == 0 and len(msg.data) == k and (not label0 or label0 == names):
        raw = gather(blob, start[same] + prefix_len, 8 * k).reshape(-1, k, 8)
        dtype = "<f8" if ref[1] & 1 else ">f8"
        values[same] = raw.copy().view(dtype)[..., 0]
    else:
        same[:] = False
    keep = same.copy()
    bad = mismatched = 0
    for j in np.flatnonzero(~same):
        try:
            msg = decoder(blob[start[j]:start[j] + length[j]].tobytes())
            label = str(msg.layout.dim[0].label) if msg.layout.dim else ""
            given = label_names(label)
            if given and sorted(given) != sorted(names or []):
                mismatched += 1
                continue
            values[j] = array_values(msg.data, int(msg.layout.data_offset),
                                     [int(d.size) for d in msg.layout.dim], k, label, names)
        except (*_PAYLOAD_ERRORS, InputError):  # malformed payload: count it, keep going
            bad += 1
            continue
        keep[j] = True
    if bad:
        out.problems.append(f"{topic}: {bad} malformed or wrong-size arrays skipped")
    if mismatched:
        out.problems.append(f"{topic}: {mismatched} arrays whose dim[0].label does not name "
                            + (f"the sensors {','.join(names)}" if names else
                               f"one sensor for each of the {k} values") + " skipped")
    out.series[topic] = Series(t[keep], values[keep])


def _first_names(decoder: Any, blob: np.ndarray, start: np.ndarray, length: np.ndarray,
                 k: int) -> list[str] | None:
    """The first ``dim[0].label`` among these messages that names k distinct sensors."""
    for s, n in zip(start.tolist(), length.tolist(), strict=True):
        try:
            msg = decoder(blob[s:s + n].tobytes())
            names = label_names(str(msg.layout.dim[0].label) if msg.layout.dim else "")
        except _PAYLOAD_ERRORS:
            continue
        if len(set(names)) == len(names) == k:
            return names
    return None
