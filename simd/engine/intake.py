"""The adapters' commands (cmd_vel) taken in by the simulation thread.

An adapter keeps the commands that arrive in a buffer of its own (the fleet adapter's zenoh
ring) and decodes them when asked, so no command costs the simulation's thread a callback.
At 8 000 robots driven at 10 Hz that is 80 000 commands a second, too many to decode in one go
while requests wait: before a tick they are decoded a chunk at a time with the requests that
came meanwhile served in between (the tick takes what is left), and while time stands still
they are still drained once a tick period, so a paused daemon's buffers never fill.

:class:`CommandIntake` is a part of :class:`~simd.engine.engine.Engine`.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

from simd.core.sim import Simulation
from simd.engine.ports import Adapter

#: cmd_vel samples an adapter decodes at a time before the requests that came meanwhile are
#: served (8 000 robots driven at 10 Hz send 80 000 a second: ~2 us each, more under load).
DRAIN_CHUNK = 1000
#: Chunks decoded before a tick at most (the tick takes the rest): commands arriving as fast as
#: they are decoded never hold a tick back (the fleet adapter's ring holds 65 536).
DRAIN_CHUNKS = 64


class CommandIntake:
    """The adapters' commands, drained (a part of ``Engine``; the module docstring)."""

    # the engine's, which these methods use
    sim: Simulation
    adapters: list[Adapter]
    stop_event: threading.Event
    _wall: Callable[[], float]
    _pending_commands: dict[str, tuple[float, float]]
    _drain_at: float

    def _next_call(self, timeout: float) -> Any:
        raise NotImplementedError

    def _serve(self, call: Any) -> None:
        raise NotImplementedError

    def _gather_commands(self) -> dict[str, tuple[float, float]]:
        """Every adapter's newest command for each robot, on top of those not yet applied."""
        cmds = self._pending_commands
        for a in self.adapters:
            cmds.update(a.take_commands())
        return cmds

    def _drain_while_paused(self) -> float:
        """Keep the adapters' command buffers drained while time stands still, once a tick
        period of wall time as when running, however many requests keep the loop busy; the
        wait until the next drain. (Drained only when no request came for 0.25 s, a paused
        daemon under a soak's steady requests let 5 s of 1 000 robots' cmd_vel pile up in the
        ring, ~50 000 samples: the allocator kept the 8 MB they took, docs/robustness.md.)"""
        now = self._wall()
        if now >= self._drain_at:
            self._gather_commands()
            self._drain_at = now + self.sim.config.dt
        return max(0.0, self._drain_at - now)

    def _drain_chunk(self) -> bool:
        """Let each adapter decode up to DRAIN_CHUNK of its waiting commands (those with a
        ``drain_commands`` method: simd/adapters/fleet/adapter.py); whether any had more waiting."""
        more = False
        for a in self.adapters:
            drain = getattr(a, "drain_commands", None)
            if drain is not None and drain(DRAIN_CHUNK):
                more = True
        return more

    def _drain_commands(self) -> bool:
        """Before a tick: decode the waiting commands a chunk at a time with the requests that
        come meanwhile served in between, so that none waits for all of them (the tick takes
        what is left). False if a request was served: the loop looks again before ticking."""
        served = False
        for _ in range(DRAIN_CHUNKS):
            if not self._drain_chunk() or self.stop_event.is_set():
                break
            while (call := self._next_call(0.0)) is not None:
                self._serve(call)
                served = True
        return not served
