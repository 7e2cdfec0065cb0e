"""Read a session recording back, including one whose writer was killed mid-drive.

The file is read front to back as a stream of records (no summary needed). A recording cut off by a killed
process ends in a partial record; everything before it is returned and ``truncated`` says so.
"""

from __future__ import annotations

import json
import struct
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcap.exceptions import InvalidMagic, McapError
from mcap.records import Channel, Footer, Message, Schema
from mcap.stream_reader import StreamReader

from tavf_mapkit.errors import InputError
from twin.recording.schemas import (
    CONFIG_CHANNEL,
    EGO_STATE_CHANNEL,
    METRICS_CHANNEL,
    UDM_RESPONSE_CHANNEL,
)

# Errors a cut-off tail can raise while being parsed: a short read (EndOfFile or struct.error), a chunk whose
# compressed bytes end early (zstandard's error, a ValueError subclass in lz4) or a garbled length.
_TAIL_ERRORS: tuple[type[BaseException], ...] = (McapError, struct.error, ValueError, EOFError, MemoryError)
try:
    import zstandard

    _TAIL_ERRORS += (zstandard.ZstdError,)
except ImportError:  # pragma: no cover -- mcap's zstd support depends on it
    pass


@dataclass(frozen=True)
class RecordedMessage:
    log_time: int  # nanoseconds, the writer's epoch plus simulation time
    data: dict[str, Any]


@dataclass(frozen=True)
class Recording:
    path: Path
    topics: dict[str, tuple[RecordedMessage, ...]]
    schemas: dict[str, str] = field(default_factory=dict)  # topic -> schema name
    complete: bool = True  # False when the file ends early (no footer): the writer did not finish

    def messages(self, topic: str) -> tuple[RecordedMessage, ...]:
        return self.topics.get(topic, ())

    @property
    def config(self) -> dict[str, Any]:
        config = self.messages(CONFIG_CHANNEL.topic)
        return config[0].data if config else {}

    @property
    def ego_states(self) -> list[dict[str, Any]]:
        return [message.data for message in self.messages(EGO_STATE_CHANNEL.topic)]

    @property
    def udm_responses(self) -> list[dict[str, Any]]:
        return [message.data for message in self.messages(UDM_RESPONSE_CHANNEL.topic)]

    @property
    def metrics(self) -> dict[str, Any] | None:
        metrics = self.messages(METRICS_CHANNEL.topic)
        return metrics[-1].data if metrics else None


def read_recording(path: str | Path, topics: set[str] | None = None) -> Recording:
    """Every JSON message of the recording by topic (only ``topics`` if given), in file order."""
    path = Path(path)
    if not path.is_file():
        raise InputError("the recording does not exist", file=str(path))
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    collected: dict[str, list[RecordedMessage]] = defaultdict(list)
    complete = False
    with path.open("rb") as stream:
        records = StreamReader(stream, record_size_limit=1 << 30).records
        try:
            for record in records:
                if isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel):
                    channels[record.id] = record
                elif isinstance(record, Message):
                    channel = channels.get(record.channel_id)
                    if channel is None:
                        raise InputError(f"message on unknown channel {record.channel_id}", file=str(path))
                    if topics is not None and channel.topic not in topics:
                        continue
                    collected[channel.topic].append(RecordedMessage(record.log_time,
                                                                    _decode(record.data, channel, path)))
                elif isinstance(record, Footer):
                    complete = True
        except InvalidMagic:
            raise InputError("not an MCAP file (bad magic bytes)", file=str(path)) from None
        except _TAIL_ERRORS as error:
            if not schemas and not channels:
                raise InputError(f"not a readable MCAP recording: {type(error).__name__}: {error}",
                                 file=str(path)) from None
            # A cut-off tail: keep what came before it.
    schema_names = {channel.topic: schemas[channel.schema_id].name if channel.schema_id in schemas else ""
                    for channel in channels.values()}
    return Recording(path, {topic: tuple(messages) for topic, messages in collected.items()}, schema_names,
                     complete)


def _decode(data: bytes, channel: Channel, path: Path) -> dict[str, Any]:
    if channel.message_encoding != "json":
        raise InputError(f"topic {channel.topic} is {channel.message_encoding!r}, not JSON; this is not a twin "
                         "recording", file=str(path))
    try:
        value = json.loads(data)
    except (UnicodeDecodeError, json.JSONDecodeError) as error:
        raise InputError(f"topic {channel.topic}: a message is not JSON: {error}", file=str(path)) from None
    if not isinstance(value, dict):
        raise InputError(f"topic {channel.topic}: a message is not a JSON object", file=str(path))
    return value
