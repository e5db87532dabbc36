"""The wander driver: keeps every robot of the fleet moving while the benchmark measures.

A fleet that stands still costs the daemon less than one that drives, so the benchmark drives
all of them, the way a fleet controller would: one publisher per robot, 10 Hz, from one thread;
or, ``batched``, every robot's command of a cycle in one message on ``P/commands``.
"""

from __future__ import annotations

import random
import threading
import time
from collections.abc import Sequence
from typing import Any

from bench.client import Fleet
from bench.numbers import median
from bench.wire import MSGPACK, PREFIX

DRIVE_HZ = 10.0  # a fleet controller's usual command rate


class Driver:
    """Drives every robot: a per-robot forward speed and a turn rate that changes every second,
    published at 10 Hz from one thread, all puts of a cycle back to back."""

    def __init__(
        self, fleet: Fleet, names: Sequence[str], seed: int, rate_hz: float = DRIVE_HZ, batched: bool = False
    ) -> None:
        import msgspec

        from protocol.messages import Twist, Vector3

        self._twist, self._vec = Twist, Vector3
        self._enc = msgspec.msgpack.Encoder()
        self.names = list(names)
        self.batched = batched
        if batched:
            self.pubs = [fleet.session.declare_publisher(f"{PREFIX}/commands", encoding=MSGPACK)]
        else:
            self.pubs = [fleet.session.declare_publisher(f"{PREFIX}/{n}/cmd_vel", encoding=MSGPACK) for n in names]
        self.rng = random.Random(seed)
        self.v = [self.rng.uniform(0.10, 0.22) for _ in names]
        self.period = 1.0 / rate_hz
        self.stop_event = threading.Event()
        self.cycles = 0
        self.late = 0
        self.burst_s: list[float] = []
        self.thread = threading.Thread(target=self._run, name="driver", daemon=True)

    def start(self) -> None:
        self.thread.start()

    def _payloads(self) -> list[bytes]:
        t, v3, enc, rng = self._twist, self._vec, self._enc, self.rng
        if self.batched:
            import numpy as np

            from protocol.control import PackedCommands

            twist = np.array([(v, rng.uniform(-1.2, 1.2)) for v in self.v], dtype="<f8")
            return [enc.encode(PackedCommands(names=self.names, twist=twist.tobytes()))]
        return [enc.encode(t(linear=v3(x=v), angular=v3(z=rng.uniform(-1.2, 1.2)))) for v in self.v]

    def _run(self) -> None:
        per_second = max(1, round(1.0 / self.period))
        payloads: list[bytes] = []
        next_t = time.monotonic()
        k = 0
        while not self.stop_event.wait(max(0.0, next_t - time.monotonic())):
            if k % per_second == 0:
                payloads = self._payloads()
            t0 = time.perf_counter()
            for pub, p in zip(self.pubs, payloads, strict=True):  # back to back: bursts amortise zenoh's wake-ups
                pub.put(p)
            self.burst_s.append(time.perf_counter() - t0)
            self.cycles += 1
            k += 1
            next_t += self.period
            if time.monotonic() - next_t > self.period:
                self.late += 1
                next_t = time.monotonic()

    def stop(self) -> None:
        self.stop_event.set()
        self.thread.join(5.0)

    def stats(self) -> dict[str, Any]:
        return {
            "rate_hz": 1.0 / self.period,
            "robots": len(self.names),
            "batched": self.batched,
            "cycles": self.cycles,
            "late_cycles": self.late,
            "burst_ms_median": (median(self.burst_s) or 0.0) * 1000,
            "burst_ms_max": max(self.burst_s, default=0.0) * 1000,
        }
