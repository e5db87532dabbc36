"""A packed step answered by several daemons reads as one daemon's reply would."""

from __future__ import annotations

import numpy as np
import pytest

from clients.api import _merge_steps, observed_arrays
from protocol.codec import decode, encode
from protocol.control import PackedObservations, StepReply
from protocol.messages import Time


def _reply(names: list[str], first: float, ticks_run: int = 6) -> StepReply:
    """One daemon's answer as the client decodes it off the wire."""
    n = len(names)
    odom = np.arange(n * 6, dtype="<f8").reshape(n, 6) + first
    scan_time = np.full(n, first)
    ranges = np.full((n, 4), first, dtype="<f4")
    ranges[0, 1] = np.nan  # a beam with no return, which must not make equal replies unequal
    packed = PackedObservations(names=names, samples=4, odom=odom.data, scan_time=scan_time.data, ranges=ranges.data)
    reply = StepReply(
        clock=Time(sec=0, nanosec=200_000_000), tick=6, dt=1 / 30, paused=True, lockstep=True, real_time_factor=0.0,
        target_real_time_factor=0.0, robots=n, ticks_run=ticks_run, packed=packed,
    )  # fmt: skip
    return decode(encode(reply), StepReply)


def test_a_merged_packed_reply_holds_read_only_bytes_in_the_order_asked() -> None:
    a, b = _reply(["a1", "a2"], 100.0), _reply(["b1"], 200.0, ticks_run=5)
    merged = _merge_steps([a, b], ["b1", "a2", "a1"])
    p = merged.packed
    assert p is not None and p.names == ["b1", "a2", "a1"] and merged.ticks_run == 5
    for field in (p.odom, p.scan_time, p.ranges):  # as a decoded reply's: flat bytes, read-only
        assert field.format == "B" and field.ndim == 1 and field.readonly
    assert len(p.ranges) == 3 * 4 * 4
    seen = observed_arrays(p)
    assert seen.odom[:, 0].tolist() == [200.0, 106.0, 100.0]
    assert seen.scan_time.tolist() == [200.0, 100.0, 100.0]
    assert not seen.ranges.flags.writeable
    with pytest.raises(ValueError):
        seen.ranges[0, 0] = 1.0
    again = _merge_steps([a, b], ["b1", "a2", "a1"])
    assert again == merged  # NaN beams compare as bytes
    assert bytes(merged.packed.ranges) == bytes(again.packed.ranges)  # type: ignore[union-attr]
