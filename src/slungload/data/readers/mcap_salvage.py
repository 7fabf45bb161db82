"""An MCAP file cut short (a recorder killed before it wrote its summary and footer), read up
to the damage.

An indexed reader (``rosbags``) needs the summary and footer that a clean close writes.
``salvage`` reads the file's records in order with the ``mcap`` package's ``StreamReader``
until the damage, and writes its schemas, channels, messages (with their log and publish
times), attachments and metadata into a new file with ``mcap``'s ``Writer``, which closes it
with a summary and indexes. A chunk cut in the middle keeps its whole messages when it is
uncompressed (as ``rosbags`` and ``ros2 bag record`` write by default); a compressed one is
lost whole. ``Salvage`` says what was kept and what was lost, for a note. ``mcap`` is imported
only for a cut file: ``is_cut`` needs nothing.
"""

from __future__ import annotations

import io
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, BinaryIO

from .logs import LogError

if TYPE_CHECKING:
    from mcap.records import Header, McapRecord

MAGIC = b"\x89MCAP0\r\n"


@dataclass(frozen=True)
class Salvage:
    """What ``salvage`` kept of a damaged MCAP file."""

    size: int  # bytes in the damaged file
    intact: int  # bytes from the start up to the end of the last whole record kept
    messages: int  # messages kept (in whole chunks, outside chunks and from the cut chunk)
    last_ns: int | None  # the latest log time kept, ns (None: no message)
    cut_chunk: str  # "" or what became of a chunk cut in the middle

    def describe(self, path: Path) -> str:
        lost = self.size - self.intact
        last = "no message" if self.last_ns is None else f"bag time {self.last_ns * 1e-9:.3f} s"
        return (
            f"{path}: the MCAP file ends without its summary and footer (a recorder killed "
            f"before closing it?): read up to byte {self.intact} of {self.size}, its messages "
            f"to {last}; the last {lost} bytes are lost{self.cut_chunk}"
        )


def is_cut(path: Path) -> bool:
    """Whether an MCAP file lacks its closing magic (a clean close writes it last)."""
    with path.open("rb") as f:
        head = f.read(len(MAGIC))
        if head != MAGIC:
            return False  # not MCAP at all: the reader says so
        f.seek(0, 2)
        if f.tell() < 2 * len(MAGIC):
            return True
        f.seek(-len(MAGIC), 2)
        return f.read() != MAGIC


class _Whole:
    """A binary file whose short read is the damage. ``mcap``'s ``StreamReader`` stops only
    where a read gives nothing: a record cut in its middle would come back shortened (a message
    with part of its data, a chunk with part of its records), so a read that gets less than it
    asks raises ``mcap``'s ``EndOfFile`` here."""

    def __init__(self, f: BinaryIO) -> None:
        self.f = f

    def read(self, size: int) -> bytes:
        from mcap.exceptions import EndOfFile

        data = self.f.read(size)
        if len(data) < size:
            raise EndOfFile()
        return data

    def tell(self) -> int:
        return self.f.tell()


def salvage(path: Path, out: Path) -> Salvage:
    """Write the whole records of the damaged MCAP ``path`` into ``out``, a closed MCAP file
    (``mcap``'s ``Writer``); what was kept."""
    from mcap.exceptions import EndOfFile, McapError
    from mcap.opcode import Opcode
    from mcap.records import Chunk, DataEnd, Footer, Header
    from mcap.stream_reader import StreamReader, breakup_chunk

    size = path.stat().st_size
    with path.open("rb") as f:
        stream = _Whole(f)
        records = StreamReader(stream, emit_chunks=True).records  # chunks whole, not opened
        try:
            header = next(records)
        except McapError:
            header = None
        if not isinstance(header, Header):
            raise LogError(f"{path}: an MCAP file cut before its header ends: nothing to read")
        with out.open("wb") as o:
            copy = _Copy(o, header)
            intact, cut = stream.tell(), ""
            try:
                for record in records:
                    if isinstance(record, (DataEnd, Footer)):  # the data section is whole
                        intact = size
                        break
                    for inner in breakup_chunk(record) if isinstance(record, Chunk) else [record]:
                        copy.add(inner)
                    intact = stream.tell()
            except EndOfFile:  # a record cut short: it starts at ``intact``
                f.seek(intact)
                if f.read(1) == bytes([Opcode.CHUNK]):
                    intact, cut = _cut_chunk(f, intact, copy)
            copy.finish()
    if copy.last is None:
        raise LogError(
            f"{path}: an MCAP file cut before its first whole message ({size} bytes, a "
            "recorder killed at once?): nothing to read"
        )
    return Salvage(size, intact, copy.messages, copy.last, cut)


def _cut_chunk(f: BinaryIO, start: int, copy: _Copy) -> tuple[int, str]:
    """Add the whole records of the chunk cut short at byte ``start`` of ``f`` to ``copy``
    (uncompressed only); the byte they end at and a phrase for the note.

    ``mcap`` reads no chunk without its whole data, so the chunk's fields are read here with
    its ``Chunk.read`` on a plain stream (which returns the data there is) and its records with
    a ``StreamReader`` of them until the damage: the one piece ``mcap`` does not do alone."""
    from mcap.data_stream import ReadDataStream
    from mcap.exceptions import EndOfFile
    from mcap.records import Channel, Chunk, Message, Schema
    from mcap.stream_reader import StreamReader

    f.seek(start + 9)  # after the opcode and the length
    fields = ReadDataStream(f)
    try:
        chunk = Chunk.read(fields)
    except (EndOfFile, struct.error):  # cut in a field
        return start, " (a chunk cut in its header)"
    if chunk.compression:
        return start, f" (a {chunk.compression}-compressed chunk cut short: its messages)"
    inner = _Whole(io.BytesIO(chunk.data))
    used, messages = 0, copy.messages
    try:
        for record in StreamReader(inner, skip_magic=True).records:
            if isinstance(record, (Schema, Channel, Message)):
                copy.add(record)
            used = inner.tell()
    except EndOfFile:
        pass
    kept = copy.messages - messages
    at = start + 9 + fields.count - len(chunk.data) + used
    return at, f" (a chunk cut short: {kept} of its messages kept, the rest lost)"


class _Copy:
    """The records kept, written as they come by ``mcap``'s ``Writer`` (uncompressed: the copy
    is read once), which numbers schemas and channels anew."""

    def __init__(self, f: BinaryIO, header: Header) -> None:
        from mcap.writer import CompressionType, Writer

        self.writer = Writer(f, compression=CompressionType.NONE)
        self.writer.start(header.profile, header.library)
        self.schemas: dict[int, int] = {0: 0}  # ids in the damaged file -> in the copy
        self.channels: dict[int, int] = {}
        self.messages = 0
        self.last: int | None = None

    def add(self, r: McapRecord) -> None:
        from mcap.records import Attachment, Channel, Message, Metadata, Schema

        w = self.writer
        if isinstance(r, Schema) and r.id not in self.schemas:
            self.schemas[r.id] = w.register_schema(r.name, r.encoding, r.data)
        elif isinstance(r, Channel) and r.id not in self.channels and r.schema_id in self.schemas:
            schema = self.schemas[r.schema_id]
            self.channels[r.id] = w.register_channel(
                r.topic, r.message_encoding, schema, r.metadata
            )
        elif isinstance(r, Message) and r.channel_id in self.channels:
            w.add_message(
                self.channels[r.channel_id], r.log_time, r.data, r.publish_time, r.sequence
            )
            self.messages += 1
            self.last = r.log_time if self.last is None else max(self.last, r.log_time)
        elif isinstance(r, Attachment):
            w.add_attachment(r.create_time, r.log_time, r.name, r.media_type, r.data)
        elif isinstance(r, Metadata):
            w.add_metadata(r.name, r.metadata)

    def finish(self) -> None:
        self.writer.finish()
