"""The MAVLink telemetry log (.tlog) as MAVProxy and QGroundControl write it: every message's
bytes as sent on the wire, each preceded by its time, a 64-bit big-endian count of
microseconds since the Unix epoch. pymavlink reads it back (``mavutil.mavlink_connection``
on the file; ``data.readers.tlog`` for ``slungload import``)."""

from __future__ import annotations

import struct
from pathlib import Path


class TlogWriter:
    """Appends messages to a .tlog as they pass; flushed every ``flush_every`` messages so
    that a flight cut short (a crash, a kill) keeps nearly all it wrote."""

    def __init__(self, path: str | Path, flush_every: int = 100) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.file = open(self.path, "wb")  # noqa: SIM115 (closed by ``close``)
        self.flush_every = flush_every
        self.count = 0
        self.last_usec = 0

    def write(self, msg, time_usec: int) -> None:
        """One message (a pymavlink message that was packed: received, or sent) at
        ``time_usec`` microseconds since the epoch (held non-decreasing)."""
        self.last_usec = max(int(time_usec), self.last_usec)
        self.file.write(struct.pack(">Q", self.last_usec) + bytes(msg.get_msgbuf()))
        self.count += 1
        if self.count % self.flush_every == 0:
            self.file.flush()

    def close(self) -> None:
        self.file.close()
