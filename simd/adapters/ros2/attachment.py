"""rmw_zenoh's attachment: the sequence number, source timestamp and GID on every sample, query
and reply, in the format of today's releases and in the one before it.

rmw_zenoh writes it with zenoh-ext's serializer (``src/detail/attachment_helpers.cpp``). Since
jazzy 0.2.4, humble 0.1.2, kilted 0.6.0 and rolling 0.6.0 it is three values, 33 bytes: int64
sequence number, int64 source timestamp (ns, wall clock), the 16-byte GID (a LEB128 length,
16, then the bytes). Jazzy 0.2.0-0.2.3, humble 0.1.0-0.1.1 and rolling 0.3.0-0.5.0 put a
string before each value (``"sequence_number"``, ``"source_timestamp"``, ``"source_gid"``,
each a LEB128 length and the text), 77 bytes. An old release's parser throws on today's format
inside zenoh's callback (jazzy 0.2.3, ``AttachmentData::AttachmentData``), which probably takes
that ROS process down.

The daemon writes the current format on what it publishes. What reaches it (commands, goal
poses, service requests) it reads in either: a command in the old format drives the robot all
the same, and a request is answered in the format it came in, which is what an older client
can read. A :class:`LegacyNotice` says once per sender, in the log, that such a peer cannot read
the daemon's topics and which rmw_zenoh releases can.
"""

from __future__ import annotations

import logging
import struct
import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import zenoh

log = logging.getLogger(__name__)

_CURRENT = struct.Struct("<qqB")
CURRENT_SIZE = _CURRENT.size + 16  # 33
#: the old format: each value after its name (a LEB128 length, the text); the GID's 16 after it
_NAMES = (b"\x0fsequence_number", b"\x10source_timestamp", b"\x0asource_gid\x10")
_LEGACY = struct.Struct(f"<{len(_NAMES[0])}sq{len(_NAMES[1])}sq{len(_NAMES[2])}s16s")  # 77 bytes
#: the releases whose attachments the daemon's own samples are in
CURRENT_RELEASES = "jazzy >= 0.2.4, humble >= 0.1.2, kilted >= 0.6.0, rolling >= 0.6.0"


@dataclass(frozen=True)
class Attachment:
    sequence: int
    stamp_ns: int
    gid: bytes
    #: in the string-keyed format of jazzy 0.2.0-0.2.3, humble 0.1.0-0.1.1, rolling 0.3.0-0.5.0
    legacy: bool = False


def encode(sequence: int, gid16: bytes, stamp_ns: int | None = None) -> bytes:
    """The 33 bytes rmw_zenoh expects on every sample, query and reply."""
    ts = time.time_ns() if stamp_ns is None else stamp_ns
    return _CURRENT.pack(sequence, ts, 16) + gid16


def encode_legacy(sequence: int, gid16: bytes, stamp_ns: int | None = None) -> bytes:
    """The same three values with their names before them, as older rmw_zenoh releases write them."""
    ts = time.time_ns() if stamp_ns is None else stamp_ns
    return _LEGACY.pack(_NAMES[0], sequence, _NAMES[1], ts, _NAMES[2], gid16)


def echo(att: Attachment) -> bytes:
    """A reply's attachment: the request's sequence number and GID, a fresh timestamp, in the
    request's format (what the caller's own release can read)."""
    return (encode_legacy if att.legacy else encode)(att.sequence, att.gid)


def decode(raw: bytes) -> Attachment:
    """Either format, or ValueError saying what the bytes are not."""
    if len(raw) == CURRENT_SIZE and raw[16] == 16:
        seq, ts, _ = _CURRENT.unpack_from(raw)
        return Attachment(seq, ts, bytes(raw[17:]))
    if len(raw) == _LEGACY.size and raw.startswith(_NAMES[0]):
        name1, seq, name2, ts, name3, gid = _LEGACY.unpack(raw)
        if (name1, name2, name3) == _NAMES:
            return Attachment(seq, ts, gid, legacy=True)
    raise ValueError(f"not an rmw_zenoh attachment ({len(raw)} bytes)")


class LegacyNotice:
    """Logs one line per sender (a GID) the first time an old-format attachment comes from it,
    naming what the sender reached and the releases that can read the daemon's topics.
    Thread-safe: zenoh's callbacks call it."""

    #: senders remembered; past this the memory starts again (a line per sender at worst, again)
    MAX_SENDERS = 1024

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._seen: set[bytes] = set()
        self.count = 0

    def note(self, att: Attachment, where: str) -> None:
        if not att.legacy:
            return
        with self._lock:
            self.count += 1
            if att.gid in self._seen:
                return
            if len(self._seen) >= self.MAX_SENDERS:
                self._seen.clear()
            self._seen.add(att.gid)
        log.warning(
            "%s: an older rmw_zenoh (jazzy 0.2.0-0.2.3, humble 0.1.0-0.1.1 or rolling 0.3-0.5; its attachments "
            "are string-keyed) sent this; it is served, but that process cannot read fleetsim's topics and "
            "may crash on them: use rmw_zenoh_cpp %s",
            where,
            CURRENT_RELEASES,
        )

    def check(self, raw: zenoh.ZBytes | None, where: str) -> None:
        """:meth:`note` for a sample's attachment if it is in the old format; anything else is
        left alone (a topic's attachment is the subscriber's to judge, and the daemon's
        subscriptions act on the payload)."""
        data = raw.to_bytes() if raw is not None else b""
        if len(data) != _LEGACY.size:
            return
        try:
            att = decode(data)
        except ValueError:
            return
        self.note(att, where)
