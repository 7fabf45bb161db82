"""An MCAP file cut short (a recorder killed before it wrote its summary and footer), read up
to the damage.

MCAP is a magic, then records (opcode u8, length u64, content) and, at a clean close, a
summary and a footer that an indexed reader (``rosbags``) needs. ``salvage`` copies the
whole records before the damage into a new file that ends with an empty summary (a DataEnd
and a footer whose summary offset is 0), which ``rosbags`` then reads by scanning, as it
reads any unindexed MCAP. A chunk cut in the middle keeps its whole inner records when it is
uncompressed (as ``rosbags`` and ``ros2 bag record`` write by default); a compressed one is
lost whole. ``Salvage`` says what was kept and what was lost, for a note.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

from .logs import LogError

MAGIC = b"\x89MCAP0\r\n"
HEADER, FOOTER, MESSAGE, CHUNK, DATA_END = 0x01, 0x02, 0x05, 0x06, 0x0F
_KEEP = (0x03, 0x04, MESSAGE, CHUNK, 0x09, 0x0C)  # schema, channel, message, chunk, attachment,
# metadata: the data section's records (indexes and the summary are rebuilt by scanning)


@dataclass(frozen=True)
class Salvage:
    """What ``salvage`` kept of a damaged MCAP file."""

    size: int  # bytes in the damaged file
    intact: int  # bytes from the start up to the end of the last whole record kept
    messages: int  # messages kept outside chunks and from the cut chunk
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


def salvage(path: Path, out: Path) -> Salvage:
    """Write the whole records of the damaged MCAP ``path`` into ``out``, closed with an empty
    summary; what was kept."""
    data = path.read_bytes()
    pos = len(MAGIC)
    if len(data) < pos + 9 or data[pos] != HEADER:
        raise LogError(f"{path}: an MCAP file cut before its header ends: nothing to read")
    pos += 9 + struct.unpack_from("<Q", data, pos + 1)[0]
    if pos > len(data):
        raise LogError(f"{path}: an MCAP file cut before its header ends: nothing to read")
    kept = [data[:pos]]
    messages, last = 0, None
    cut = ""
    while pos + 9 <= len(data):
        op = data[pos]
        (size,) = struct.unpack_from("<Q", data, pos + 1)
        end = pos + 9 + size
        if op in (DATA_END, FOOTER):  # the data section is whole; the summary is cut
            pos = len(data)
            break
        if end > len(data):
            if op == CHUNK:
                records, used, n, t, cut = _cut_chunk(data[pos + 9 :])
                kept.append(records)
                messages += n
                last = t if last is None or (t is not None and t > last) else last
                pos += 9 + used
            break
        if op == MESSAGE:
            messages += 1
            t = struct.unpack_from("<Q", data, pos + 9 + 6)[0]
            last = t if last is None else max(last, t)
        elif op == CHUNK:
            t = struct.unpack_from("<Q", data, pos + 9 + 8)[0]  # message_end_time
            last = t if last is None else max(last, t)
        if op in _KEEP:
            kept.append(data[pos:end])
        pos = end
    intact = min(pos, len(data))
    if last is None:
        raise LogError(
            f"{path}: an MCAP file cut before its first whole message ({len(data)} bytes, a "
            "recorder killed at once?): nothing to read"
        )
    body = b"".join(kept)
    closing = bytes([DATA_END]) + struct.pack("<QI", 4, 0)
    closing += bytes([FOOTER]) + struct.pack("<QQQI", 20, 0, 0, 0) + MAGIC
    out.write_bytes(body + closing)
    return Salvage(len(data), intact, messages, last, cut)


def _cut_chunk(content: bytes) -> tuple[bytes, int, int, int | None, str]:
    """The whole inner records of a chunk cut short (uncompressed only), the bytes of
    ``content`` they end at, their messages and latest log time, and a phrase for the note."""
    fixed = 8 + 8 + 8 + 4
    if len(content) < fixed + 4:
        return b"", 0, 0, None, " (a chunk cut in its header)"
    (length,) = struct.unpack_from("<I", content, fixed)
    compression = content[fixed + 4 : fixed + 4 + length].decode("utf-8", "replace")
    start = fixed + 4 + length + 8  # the records' byte-array length, then the records
    if compression:
        return b"", 0, 0, None, f" (a {compression}-compressed chunk cut short: its messages)"
    inner = content[start:]
    pos, kept, messages, last = 0, [], 0, None
    while pos + 9 <= len(inner):
        op = inner[pos]
        (size,) = struct.unpack_from("<Q", inner, pos + 1)
        end = pos + 9 + size
        if end > len(inner):
            break
        if op == MESSAGE:
            messages += 1
            t = struct.unpack_from("<Q", inner, pos + 9 + 6)[0]
            last = t if last is None else max(last, t)
        kept.append(inner[pos:end])
        pos = end
    return (
        b"".join(kept),
        start + pos,
        messages,
        last,
        (f" (a chunk cut short: {messages} of its messages kept, the rest lost)"),
    )
