"""One decoder per input, accepting MessagePack or JSON; encoders for both.

The daemon's inputs must decode from JSON too, so that a person can drive the simulation
with zenoh's own CLI. The two are told apart by the first byte: a JSON object starts with
``{`` (after optional whitespace), which as MessagePack would be the integer 123 and never
a valid message. An empty payload decodes as ``{}`` (every field defaulted), so that
``zenoh get -s fleet/sim/pause`` works with no body.
"""

from __future__ import annotations

from typing import Any, Literal, TypeVar

import msgspec

from protocol.errors import ErrorCode, ErrorReply, FleetError

T = TypeVar("T")
Format = Literal["msgpack", "json"]

MSGPACK = "application/msgpack"
JSON = "application/json"

_msgpack_encoder = msgspec.msgpack.Encoder()
_json_encoder = msgspec.json.Encoder()
_decoders: dict[type[Any], tuple[msgspec.msgpack.Decoder[Any], msgspec.json.Decoder[Any]]] = {}

_JSON_START = frozenset(b" \t\r\n{")


def sniff_format(payload: bytes) -> Format:
    """``json`` if the payload looks like a JSON object, else ``msgpack``."""
    return "json" if payload[:1] and payload[0] in _JSON_START else "msgpack"


def _pair(type_: type[T]) -> tuple[msgspec.msgpack.Decoder[T], msgspec.json.Decoder[T]]:
    pair = _decoders.get(type_)
    if pair is None:
        pair = (msgspec.msgpack.Decoder(type_), msgspec.json.Decoder(type_))
        _decoders[type_] = pair
    return pair


#: The largest payload any key takes (a step with commands for 5 000 robots is ~0.5 MB).
MAX_PAYLOAD_BYTES = 4 << 20
#: The largest reply a client takes to a query it sent: what a daemon answers grows with its
#: fleet (a robot list is ~760 bytes a robot, 4.6 MB at 6 000; a packed step's scans 1.4 kB a
#: robot), so the requests' limit would refuse a large fleet's own list.
MAX_REPLY_BYTES = 256 << 20


def decode(payload: bytes, type_: type[T], max_bytes: int = MAX_PAYLOAD_BYTES) -> T:
    """Decode ``payload`` (MessagePack or JSON) into ``type_``.

    Whatever the bytes, the outcome is the value or a ``FleetError``: ``too_large`` beyond
    ``max_bytes``, ``malformed`` for anything that does not decode (nesting deeper than
    msgspec recurses, invalid UTF-8 and every other decoder failure included), so that no
    input reaches a caller as an unexpected exception.
    """
    if len(payload) > max_bytes:
        raise FleetError(
            ErrorCode.TOO_LARGE, f"a {type_.__name__} of {len(payload)} bytes exceeds the limit of {max_bytes} bytes"
        )
    mp, js = _pair(type_)
    fmt = sniff_format(payload) if payload else "json"
    try:
        if fmt == "json":
            return js.decode(payload if payload.strip() else b"{}")
        return mp.decode(payload)
    except msgspec.ValidationError as e:
        field = _field_of(str(e))
        raise FleetError(ErrorCode.MALFORMED, f"invalid {type_.__name__}: {e}", field) from None
    except msgspec.DecodeError as e:
        raise FleetError(ErrorCode.MALFORMED, f"payload is not valid {fmt} for {type_.__name__}: {e}") from None
    except RecursionError:
        raise FleetError(ErrorCode.MALFORMED, f"payload nests too deeply for a {type_.__name__}") from None
    except UnicodeDecodeError as e:
        why = f"payload is not valid UTF-8 {fmt}: {e.reason} at byte {e.start}"
        raise FleetError(ErrorCode.MALFORMED, why) from None
    except Exception as e:  # anything else msgspec may raise on hostile bytes is still bad input
        why = f"payload does not decode as {type_.__name__}: {type(e).__name__}"
        raise FleetError(ErrorCode.MALFORMED, why) from None


def _field_of(message: str) -> str | None:
    """msgspec says ``... - at `$.name```; return ``name``."""
    marker = "at `$."
    i = message.rfind(marker)
    if i < 0:
        missing = "missing required field `"
        j = message.find(missing)
        return message[j + len(missing) :].split("`")[0] if j >= 0 else None
    return message[i + len(marker) :].rstrip("`")


def encode(obj: Any, fmt: Format = "msgpack") -> bytes:
    return _json_encoder.encode(obj) if fmt == "json" else _msgpack_encoder.encode(obj)


def media_type(fmt: Format) -> str:
    return JSON if fmt == "json" else MSGPACK


def reply_error(raw: bytes, timeout_message: str) -> FleetError:
    """The error a query's error reply carries: zenoh's own ``Timeout`` (told as
    ``timeout_message``), a daemon's structured refusal, or anything else as malformed."""
    if raw == b"Timeout":
        return FleetError(ErrorCode.TIMEOUT, timeout_message)
    try:
        return FleetError.from_reply(decode(raw, ErrorReply))
    except FleetError:
        return FleetError(ErrorCode.MALFORMED, raw.decode("utf-8", "replace"))
