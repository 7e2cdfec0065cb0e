"""Write a session recording: one MCAP file of JSON messages, flushed as it goes.

The MCAP writer collects messages in a chunk and writes the chunk when it is full. A drive that is killed
would lose the whole open chunk, so ``Recorder`` also closes the chunk whenever ``flush_interval_s`` of wall
time has passed since the last one: a killed process loses at most that much (default 0.5 s). Everything
before it is complete chunks that ``read_recording`` (and Foxglove) can read without the file's summary.
"""

from __future__ import annotations

import json
import math
import threading
import time
from pathlib import Path
from typing import IO, Any, Self

from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import CompressionType, Writer

from twin import __version__
from twin.recording.schemas import Channel

RECORDING_NAME = "session.mcap"
DEFAULT_FLUSH_INTERVAL_S = 0.5
CHUNK_SIZE = 256 * 1024  # bytes; a full chunk is written even before the flush interval


# One encoder for all messages: json.dumps with options builds a new encoder on every call (a third slower).
_ENCODER = json.JSONEncoder(separators=(",", ":"), allow_nan=False)


def encode(message: dict[str, Any]) -> bytes:
    """Compact JSON; floats are written with ``repr`` so they read back bit for bit.

    JSON has no NaN or infinity, and Foxglove refuses them, so a non-finite number becomes ``null``.
    """
    try:
        return _ENCODER.encode(message).encode()
    except ValueError:
        return _ENCODER.encode(_finite(message)).encode()


def _finite(value: Any) -> Any:
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {key: _finite(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(item) for item in value]
    return value


def time_ns(seconds: float) -> int:
    return round(seconds * 1e9)


class Recorder:
    """``Recorder(path).write(channel, t, message)``; ``t`` is simulation seconds from the drive's start.

    Message log times are ``epoch_ns`` (the wall clock when the drive started, so Foxglove shows a real
    date) plus the simulation time; the messages themselves carry ``t`` where the replay needs it exactly.
    """

    def __init__(self, path: str | Path, *, flush_interval_s: float = DEFAULT_FLUSH_INTERVAL_S,
                 epoch_ns: int | None = None, compression: CompressionType = CompressionType.ZSTD) -> None:
        self.path = Path(path)
        self.epoch_ns = time.time_ns() if epoch_ns is None else epoch_ns
        self.flush_interval_s = flush_interval_s
        self._file: IO[bytes] = self.path.open("wb")
        self._writer = Writer(self._file, chunk_size=CHUNK_SIZE, compression=compression)
        self._writer.start(profile="", library=f"twin {__version__}")
        self._channel_ids: dict[str, int] = {}
        self._sequence: dict[str, int] = {}
        self._lock = threading.Lock()
        self._last_flush = time.monotonic()
        self._closed = False
        self.messages = 0

    def write(self, channel: Channel, t: float, message: dict[str, Any]) -> None:
        data = encode(message)
        with self._lock:
            if self._closed:
                return
            channel_id = self._channel_ids.get(channel.topic)
            if channel_id is None:
                channel_id = self._register(channel)
            sequence = self._sequence[channel.topic] = self._sequence[channel.topic] + 1
            log_time = self.epoch_ns + time_ns(t)
            self._writer.add_message(channel_id, log_time=log_time, data=data, publish_time=log_time,
                                     sequence=sequence)
            self.messages += 1
            now = time.monotonic()
            if now - self._last_flush >= self.flush_interval_s:
                self._writer.flush()
                self._last_flush = now

    def flush(self) -> None:
        with self._lock:
            if not self._closed:
                self._writer.flush()
                self._last_flush = time.monotonic()

    def close(self) -> None:
        """Write the summary (indexes, statistics) and close the file; safe to call twice."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            try:
                self._writer.finish()
            finally:
                self._file.close()

    def _register(self, channel: Channel) -> int:
        schema_id = self._writer.register_schema(
            name=channel.schema_name, encoding=SchemaEncoding.JSONSchema,
            data=json.dumps(channel.schema).encode(),
        )
        channel_id = self._writer.register_channel(topic=channel.topic, message_encoding=MessageEncoding.JSON,
                                                   schema_id=schema_id)
        self._channel_ids[channel.topic] = channel_id
        self._sequence[channel.topic] = 0
        return channel_id

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()
