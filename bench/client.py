"""The benchmark's own zenoh session with the daemon: queries, the clock, batched spawns.

The clock subscription here is what the real-time factor is computed from; the queries time
spawn, delete and clock requests as a client over the network sees them.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

from bench.wire import MSGPACK, PREFIX, zenoh_config


class Fleet:
    """The benchmark's own zenoh client session: queries, the clock, cmd_vel."""

    def __init__(self, endpoint: str, connect_timeout: float = 30.0) -> None:
        import msgspec
        import zenoh

        from protocol.control import Clock

        self.zenoh = zenoh
        self.session = zenoh.open(zenoh_config(endpoint, connect_timeout))
        self._clock_dec = msgspec.msgpack.Decoder(Clock)
        self.clock_samples: list[tuple[float, int, float]] = []  # (monotonic, tick, rtf) at 10 Hz sim time
        self.session.declare_subscriber(f"{PREFIX}/clock", self._on_clock)

    def _on_clock(self, sample: Any) -> None:
        try:
            c = self._clock_dec.decode(sample.payload.to_bytes())
        except Exception:
            return
        self.clock_samples.append((time.monotonic(), c.tick, c.real_time_factor))

    def close(self) -> None:
        self.session.close()

    def query(self, key: str, request: object | None, timeout: float) -> tuple[bool, Any, float]:
        """(ok, reply payload bytes or error text, seconds)."""
        from protocol.codec import encode

        payload = encode(request) if request is not None else None
        t0 = time.perf_counter()
        replies = self.session.get(f"{key}?format=msgpack", payload=payload, encoding=MSGPACK, timeout=timeout)
        for reply in replies:
            dt = time.perf_counter() - t0
            if reply.ok is not None:
                return True, reply.ok.payload.to_bytes(), dt
            err = reply.err
            return False, _error_text(err.payload.to_bytes() if err is not None else b""), dt
        return False, "no daemon answered", time.perf_counter() - t0

    def robot_lists(self, timeout: float, every_daemon: bool = False) -> list[Any]:
        """The robot list (``RobotList``), or with ``every_daemon`` each daemon's of a shared
        fleet (each answers with its own robots)."""
        from protocol.codec import MAX_REPLY_BYTES, decode
        from protocol.control import RobotList

        if not every_daemon:
            ok, data, _ = self.query(f"{PREFIX}/robots", None, timeout)
            if not ok:
                raise RuntimeError(f"robot list failed: {data}")
            lists = [data]
        else:
            lists = [reply.ok.payload.to_bytes()
                     for reply in self.session.get(f"{PREFIX}/robots?format=msgpack", timeout=timeout,
                                                   target=self.zenoh.QueryTarget.ALL,
                                                   consolidation=self.zenoh.ConsolidationMode.NONE)
                     if reply.ok is not None]  # fmt: skip
        return [decode(data, RobotList, max_bytes=MAX_REPLY_BYTES) for data in lists]  # 16 MB at 20 000

    def moving(self, timeout: float, every_daemon: bool = False) -> int:
        """How many robots of the fleet are moving now (as the robot list says: faster than
        1 cm/s, or turning faster than 0.01 rad/s, as a driven robot pushing against a wall or
        another robot still does): whether a driver's commands reach the robots, which a benchmark
        of a driven fleet must check (a zenoh publisher drops what is put on it until it is
        matched, and at 10 000 publishers that took ~20 s)."""
        return sum(
            abs(r.linear_velocity) > 0.01 or abs(r.angular_velocity) > 0.01
            for one in self.robot_lists(timeout, every_daemon)
            for r in one.robots
        )

    def clock(self, timeout: float = 10.0) -> Any:
        from protocol.codec import decode
        from protocol.control import Clock

        ok, data, _ = self.query(f"{PREFIX}/clock", None, timeout)
        if not ok:
            raise RuntimeError(f"clock query failed: {data}")
        return decode(data, Clock)

    def wait_for_daemon(self, timeout: float) -> None:
        """Until the daemon answers its clock: a session just opened may not know the daemon's
        queryables yet (a query then has no reply at once)."""
        deadline = time.monotonic() + timeout
        while True:
            try:
                self.clock(timeout=2.0)
                return
            except RuntimeError:
                if time.monotonic() > deadline:
                    raise RuntimeError(f"simd did not answer within {timeout:g} s") from None
                time.sleep(0.1)

    def spawn_batch(
        self,
        requests: Sequence[Any],
        concurrency: int,
        timeout: float,
        on_progress: Callable[[int, int], None] | None = None,
    ) -> tuple[list[tuple[float, bool, str]], float]:
        """Spawn concurrently, at most ``concurrency`` in flight. Returns per request
        (latency, ok, error) and the total wall time."""
        from protocol.codec import encode

        zenoh = self.zenoh
        sem = threading.Semaphore(concurrency)
        results: list[tuple[float, bool, str] | None] = [None] * len(requests)
        lock = threading.Lock()
        left = [len(requests)]
        all_done = threading.Event()
        if not requests:
            return [], 0.0

        def finish(i: int, t0: float, ok: bool, err: str) -> None:
            results[i] = (time.perf_counter() - t0, ok, err)
            sem.release()
            with lock:
                left[0] -= 1
                if left[0] == 0:
                    all_done.set()

        start = time.perf_counter()
        deadline = time.monotonic() + timeout
        for i, req in enumerate(requests):
            if not sem.acquire(timeout=max(0.0, deadline - time.monotonic())):
                break
            state: dict[str, Any] = {}
            t0 = time.perf_counter()

            def on_reply(reply: Any, state: dict[str, Any] = state) -> None:
                if reply.ok is not None:
                    state["ok"] = True
                else:
                    state["err"] = _error_text(reply.err.payload.to_bytes())

            def on_done(i: int = i, t0: float = t0, state: dict[str, Any] = state) -> None:
                finish(i, t0, bool(state.get("ok")), state.get("err", "" if state.get("ok") else "no reply"))

            try:
                self.session.get(
                    f"{PREFIX}/spawn?format=msgpack",
                    zenoh.handlers.Callback(on_reply, on_done),
                    payload=encode(req),
                    encoding=MSGPACK,
                    timeout=10.0,
                )
            except zenoh.ZError as e:
                finish(i, t0, False, f"get failed: {e}")
            if on_progress is not None and (i + 1) % 10 == 0:
                on_progress(i + 1, len(requests))
        all_done.wait(max(0.1, deadline - time.monotonic()))
        total = time.perf_counter() - start
        out = [r if r is not None else (float("nan"), False, "not issued or no reply in time") for r in results]
        return out, total


def _error_text(raw: bytes) -> str:
    import msgspec

    if raw == b"Timeout":
        return "timeout"
    try:
        d = msgspec.msgpack.decode(raw)
        if isinstance(d, dict):
            return f"{d.get('code')}: {d.get('message')}"
    except Exception:
        pass
    return raw.decode("utf-8", "replace")[:200]


def spawn_request(name: str, x: float, y: float, yaw: float) -> Any:
    """A request for the daemon's ``spawn`` queryable: one robot, at a pose."""
    from protocol.control import SpawnRequest

    return SpawnRequest(name=name, x=x, y=y, yaw=yaw)
