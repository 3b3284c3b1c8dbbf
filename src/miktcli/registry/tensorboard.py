"""TensorBoard event files, written without TensorFlow or protobuf: scalars only, which is all a run logs.

An event file is a sequence of TFRecords (length, masked CRC-32C of the length, the bytes, masked CRC-32C of
the bytes); each record is a serialized `tensorflow.Event` protocol buffer. The few fields used here are
encoded by hand: Event{wall_time = 1 (double), step = 2 (int64), file_version = 3 (string), summary = 5},
Summary{value = 1 (repeated)}, Summary.Value{tag = 1 (string), simple_value = 2 (float)}. metrics.jsonl stays
the source of truth; these files are a view of it for `tensorboard --logdir`.
"""

from __future__ import annotations

import math
import struct
import time
from collections.abc import Iterator
from pathlib import Path

from miktcli.methods.mixing import is_mixing_key

_CRC32C_POLY = 0x82F63B78  # Castagnoli, reflected


def _crc32c_table() -> list[int]:
    table = []
    for n in range(256):
        c = n
        for _ in range(8):
            c = (c >> 1) ^ _CRC32C_POLY if c & 1 else c >> 1
        table.append(c)
    return table


_TABLE = _crc32c_table()


def crc32c(data: bytes) -> int:
    crc = 0xFFFFFFFF
    for byte in data:
        crc = _TABLE[(crc ^ byte) & 0xFF] ^ (crc >> 8)
    return crc ^ 0xFFFFFFFF


def _masked(crc: int) -> int:
    return (((crc >> 15) | (crc << 17)) + 0xA282EAD8) & 0xFFFFFFFF


def _varint(value: int) -> bytes:
    out = bytearray()
    value &= (1 << 64) - 1  # int64 as protobuf encodes it
    while True:
        bits, value = value & 0x7F, value >> 7
        out.append(bits | (0x80 if value else 0))
        if not value:
            return bytes(out)


def _field_bytes(number: int, payload: bytes) -> bytes:
    return _varint(number << 3 | 2) + _varint(len(payload)) + payload


def encode_event(wall_time: float, step: int, scalars: dict[str, float] | None = None,
                 file_version: str | None = None) -> bytes:
    event = _varint(1 << 3 | 1) + struct.pack("<d", wall_time) + _varint(2 << 3) + _varint(step)
    if file_version is not None:
        event += _field_bytes(3, file_version.encode())
    if scalars:
        values = b"".join(
            _field_bytes(1, _field_bytes(1, tag.encode()) + _varint(2 << 3 | 5) + struct.pack("<f", value))
            for tag, value in scalars.items()
        )
        event += _field_bytes(5, values)
    return event


def record(data: bytes) -> bytes:
    length = struct.pack("<Q", len(data))
    return length + struct.pack("<I", _masked(crc32c(length))) + data + struct.pack("<I", _masked(crc32c(data)))


EVENTS_FILE = "events.out.tfevents.0.mikt"  # one stable name per folder: rewritten whole, then appended to
_SKIP = {"iteration", "steps", "episodes"}


def tag_for(key: str) -> str:
    """TensorBoard groups tags by their prefix: returns, losses, PPO's diagnostics, MIKT's mixing, time."""
    if key.startswith("loss_"):
        return f"loss/{key[5:]}"
    if is_mixing_key(key):  # the student's weights and, with several teachers, the teachers'
        return f"mixing/{key}"
    if key in ("coupling_scale", "teacher_active"):
        return f"mikt/{key}"
    if key in ("return_mean", "length_mean", "episode_return_iter", "episodes_finished"):
        return f"episode/{key}"
    if key == "steps_per_sec" or key.startswith("time_"):
        return f"time/{key}"
    return f"ppo/{key}"


_FLOAT32_MAX = 3.4028234663852886e38


def _float32(value: object) -> float | None:
    """The value as TensorBoard's float32 `simple_value`, or None where it has none: not a number, NaN, ±inf, or
    finite beyond float32 (a reward of −8.7e300), which struct would refuse. metrics.jsonl keeps those exactly."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        return None
    try:
        number = float(value)
    except OverflowError:  # an int past float64
        return None
    return number if math.isfinite(number) and abs(number) <= _FLOAT32_MAX else None


def scalars_of(metrics: dict) -> dict[str, float]:
    """The scalars of a metrics row TensorBoard can show; the view leaves out what it cannot (never fails)."""
    out = {}
    for key, value in metrics.items():
        number = None if key in _SKIP else _float32(value)
        if number is not None:
            out[tag_for(key)] = number
    return out


def event_records(rows: list[dict], wall_time: float | None = None) -> bytes:
    """A whole event file for metrics rows (each with `steps`): the version header, then one event per row."""
    now = time.time() if wall_time is None else wall_time
    parts = [record(encode_event(now, 0, file_version="brain.Event:2"))]
    parts += [record(encode_event(now, int(r["steps"]), scalars_of(r))) for r in rows]
    return b"".join(parts)


def append_event(path: Path, metrics: dict) -> None:
    """One event for one iteration, in one write (a crash loses at most the event it cut)."""
    header = b"" if path.exists() else record(encode_event(time.time(), 0, file_version="brain.Event:2"))
    with open(path, "ab") as f:
        f.write(header + record(encode_event(time.time(), int(metrics["steps"]), scalars_of(metrics))))


# --- reading back (for tests and for tools without TensorBoard) ----------------------------------------

def _read_varint(data: bytes, i: int) -> tuple[int, int]:
    shift = value = 0
    while True:
        byte = data[i]
        i += 1
        value |= (byte & 0x7F) << shift
        shift += 7
        if not byte & 0x80:
            return value, i


def _fields(data: bytes) -> Iterator[tuple[int, int, object]]:
    i = 0
    while i < len(data):
        key, i = _read_varint(data, i)
        number, wire = key >> 3, key & 7
        if wire == 0:
            value, i = _read_varint(data, i)
        elif wire == 1:
            value, i = struct.unpack_from("<d", data, i)[0], i + 8
        elif wire == 5:
            value, i = struct.unpack_from("<f", data, i)[0], i + 4
        elif wire == 2:
            length, i = _read_varint(data, i)
            value, i = data[i:i + length], i + length
        else:
            raise ValueError(f"unsupported protobuf wire type {wire}")
        yield number, wire, value


def read_scalars(path: Path) -> list[tuple[int, str, float]]:
    """(step, tag, value) of every scalar in an event file, checking every record's CRCs."""
    data, out, i = Path(path).read_bytes(), [], 0
    while i < len(data):
        length_bytes = data[i:i + 8]
        (length,) = struct.unpack("<Q", length_bytes)
        if struct.unpack("<I", data[i + 8:i + 12])[0] != _masked(crc32c(length_bytes)):
            raise ValueError(f"{path}: bad length checksum at byte {i}")
        payload = data[i + 12:i + 12 + length]
        if struct.unpack("<I", data[i + 12 + length:i + 16 + length])[0] != _masked(crc32c(payload)):
            raise ValueError(f"{path}: bad data checksum at byte {i}")
        i += 16 + length
        fields = list(_fields(payload))
        step = next((v for n, _, v in fields if n == 2), 0)
        for number, _, summary in fields:
            if number != 5:
                continue
            for _, _, value in _fields(summary):
                parts = {n: v for n, _, v in _fields(value)}
                out.append((step, parts[1].decode(), parts[2]))
    return out
