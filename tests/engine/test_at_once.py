"""What a running engine answers without waiting for its tick: a pause answered at once names the
last tick there will be, and commands are decoded in chunks with requests served between them.
The engine runs on its own thread with an injected wall clock that is always past the next
deadline (ticks back to back, as in an overloaded daemon); the tests wait for conditions."""

from __future__ import annotations

import threading
from collections.abc import Callable

import pytest

from protocol import control
from protocol.control import Clock
from simd.core.snapshot import TickSnapshot
from simd.engine import Engine, intake
from tests.engine.test_engine import Recorder, engine


class Rushing:
    """A wall clock that moves on by a tenth of a second whenever it is read: every tick is due."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        self.now += 0.1
        return self.now


def _run_until(e: Engine, done: Callable[[], bool]) -> None:
    thread = threading.Thread(target=e.run)
    thread.start()
    try:
        for _ in range(1000):
            if done():
                break
            threading.Event().wait(0.01)
    finally:
        e.stop()
        thread.join(10)
    assert done() and not thread.is_alive()


def _running(r: Recorder | None = None) -> tuple[Engine, Recorder]:
    e, rec = engine(lockstep=False, clock=Rushing())  # type: ignore[arg-type]
    e.submit(control.SpawnRequest(name="a"), rec.reply("spawned"))
    e.serve_pending()
    return e, rec


@pytest.mark.parametrize("when", ["during a tick", "between ticks"])
def test_a_pause_is_answered_at_once_and_no_tick_follows_the_one_it_names(when: str) -> None:
    e, r = _running()
    answers: list[object] = []

    def ask() -> None:
        answers.append(e.answer_at_once(control.PauseRequest()))
        answers.append(e.answer_at_once(control.ClockRequest()))

    take, on_tick = r.take_commands, r.on_tick

    def take_commands() -> dict[str, tuple[float, float]]:  # at the start of every tick
        if when == "during a tick" and e.sim.tick == 4 and not answers:
            ask()  # tick 5 is being computed
        return dict(take())

    def on_tick_(snapshot: TickSnapshot) -> None:  # after the tick is known
        on_tick(snapshot)
        if when == "between ticks" and snapshot.tick == 4 and not answers:
            ask()

    r.take_commands = take_commands  # type: ignore[method-assign]
    r.on_tick = on_tick_  # type: ignore[method-assign]
    _run_until(e, lambda: e.paused)
    named = 5 if when == "during a tick" else 4
    paused, clock = answers
    assert isinstance(paused, Clock) and paused.paused and paused.tick == named
    assert paused.clock.to_seconds() == pytest.approx(named * e.sim.config.dt)
    assert paused.real_time_factor == 0.0 and not paused.falling_behind
    assert isinstance(clock, Clock) and clock.paused and clock.tick == named  # what it says, the clock says
    ticks = [s.tick for k, s in r.log if k == "tick"]  # type: ignore[attr-defined]
    assert ticks[-1] == named and e.sim.tick == named  # no tick after the one named
    topic = [v for k, v in r.log if k == "clock"][-1]
    assert isinstance(topic, Clock) and topic.paused and topic.tick == named  # the clock topic is told
    assert "pause" not in r.kinds()  # the simulation thread's own reply is not sent again
    after = e.answer_at_once(control.ClockRequest())
    assert isinstance(after, Clock) and after.paused and after.tick == named


def test_a_pause_while_paused_is_left_to_the_simulation_thread() -> None:
    e, _ = engine(lockstep=False)
    e.submit(control.PauseRequest(), lambda res: None)
    e.serve_pending()
    assert e.paused and e.answer_at_once(control.PauseRequest()) is None


def test_a_resume_asked_after_a_pause_answered_at_once_is_served_after_it() -> None:
    e, r = _running()
    order: list[str] = []

    def on_tick_(snapshot: TickSnapshot) -> None:
        if snapshot.tick == 3 and not order:
            paused = e.answer_at_once(control.PauseRequest())
            assert isinstance(paused, Clock) and paused.paused
            order.append("paused")
            e.submit(control.ResumeRequest(), lambda res: order.append(f"resumed {res.paused}"))  # type: ignore[union-attr]

    r.on_tick = on_tick_  # type: ignore[method-assign]
    _run_until(e, lambda: len(order) == 2 and e.sim.tick > 3)
    assert order == ["paused", "resumed False"] and not e.paused


class Draining(Recorder):
    """An adapter with ``waiting`` cmd_vel samples to decode; it logs every chunk."""

    def __init__(self, waiting: float) -> None:
        super().__init__()
        self.waiting = waiting
        self.on_first_chunk: Callable[[], None] = lambda: None

    def drain_commands(self, most: int) -> bool:
        n = min(most, self.waiting)
        self.waiting -= n
        self.log.append(("chunk", n))
        if len([k for k, _ in self.log if k == "chunk"]) == 1:
            self.on_first_chunk()
        return n == most


def _draining(waiting: float) -> tuple[Engine, Draining]:
    e, _ = engine(lockstep=False, clock=Rushing())  # type: ignore[arg-type]
    e.adapters.clear()
    d = Draining(waiting)
    e.attach(d)
    return e, d


def test_commands_are_decoded_in_chunks_before_a_tick_with_requests_served_between() -> None:
    chunk = intake.DRAIN_CHUNK
    e, d = _draining(2.5 * chunk)
    d.on_first_chunk = lambda: e.submit(control.SpawnRequest(name="b"), d.reply("spawned"))
    _run_until(e, lambda: any(k == "tick" for k, _ in d.log))
    kinds = [k for k, _ in d.log if k != "clock"]
    first_tick = kinds.index("tick")
    # the spawn is served after the first chunk; the loop looks again before the tick (none left)
    assert kinds[:first_tick] == ["chunk", "event", "spawned", "chunk", "chunk", "chunk"]
    assert [n for k, n in d.log if k == "chunk"][:4] == [chunk, chunk, chunk / 2, 0]
    tick = next(v for k, v in d.log if k == "tick")
    assert isinstance(tick, TickSnapshot) and tick.namespaces == ["b"]


def test_commands_that_never_stop_coming_do_not_hold_a_tick_back() -> None:
    e, d = _draining(float("inf"))
    _run_until(e, lambda: any(k == "tick" for k, _ in d.log))
    kinds = [k for k, _ in d.log if k != "clock"]
    assert kinds.index("tick") == intake.DRAIN_CHUNKS
