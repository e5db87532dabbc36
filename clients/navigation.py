"""A goal sent to a robot, as the client holds it: feedback as it comes, the result once.

``FleetClient.navigate`` returns a :class:`Goal`. It listens to the robot's result and
feedback keys from before the goal is sent, so nothing is missed, and keeps only what is
about its own goal (a goal it preempted ends with ``preempted`` on the same key). While it
waits it also asks the daemon every ``CHECK_EVERY_S`` how the goal stands: a daemon that died
and came back without the goal (no ``--state``), or a goal that ended while the client was
not listening, still gives a result instead of an endless wait.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any, Protocol

import zenoh

from protocol.codec import decode
from protocol.errors import ErrorCode, FleetError
from protocol.keys import Keys
from protocol.messages import Time
from protocol.navigation import NavigateReply, NavigationFeedback, NavigationResult, NavigationState


class Asks(Protocol):
    """What a goal needs of its client (clients.api.FleetClient)."""

    keys: Keys
    session: zenoh.Session

    def navigation_state(self, robot: str) -> NavigationState: ...

    def cancel_goal(self, robot: str, goal_id: str = "") -> NavigationResult: ...


#: while waiting, how often (wall seconds) the daemon is asked how the goal stands
CHECK_EVERY_S = 2.0


class Goal:
    """One goal of one robot (see the module docstring). ``feedback`` is the latest feedback,
    ``result`` the result once the goal ended (then ``done`` is true)."""

    def __init__(self, client: Asks, robot: str) -> None:
        self._client = client
        self.robot = robot
        self.goal_id = ""
        self.accepted: NavigateReply | None = None
        self.feedback: NavigationFeedback | None = None
        self.result: NavigationResult | None = None
        self._cond = threading.Condition()
        self._early: list[NavigationResult] = []  # results heard before the goal id was known
        self._on_feedback: Callable[[NavigationFeedback], None] | None = None
        keys = client.keys
        session = client.session
        self._subs: list[Any] = [
            session.declare_subscriber(keys.navigate_result(robot), self._heard_result),
            session.declare_subscriber(keys.navigate_feedback(robot), self._heard_feedback),
        ]

    # -- zenoh's threads ------------------------------------------------------------------------

    def _heard_result(self, sample: zenoh.Sample) -> None:
        try:
            result = decode(sample.payload.to_bytes(), NavigationResult)
        except FleetError:
            return
        with self._cond:
            if not self.goal_id:
                self._early.append(result)
            elif result.goal_id == self.goal_id and self.result is None:
                self.result = result
            self._cond.notify_all()

    def _heard_feedback(self, sample: zenoh.Sample) -> None:
        try:
            fb = decode(sample.payload.to_bytes(), NavigationFeedback)
        except FleetError:
            return
        callback = None
        with self._cond:
            if fb.goal_id == self.goal_id and self.result is None:
                self.feedback = fb
                callback = self._on_feedback
            self._cond.notify_all()
        if callback is not None:
            callback(fb)

    # -- the caller's thread --------------------------------------------------------------------

    def _accepted(self, reply: NavigateReply) -> None:
        with self._cond:
            self.accepted = reply
            self.goal_id = reply.goal_id
            for result in self._early:
                if result.goal_id == self.goal_id:
                    self.result = result
            self._early.clear()

    @property
    def done(self) -> bool:
        return self.result is not None

    def wait(
        self,
        timeout: float | None = None,
        on_feedback: Callable[[NavigationFeedback], None] | None = None,
    ) -> NavigationResult:
        """Block until the goal ends and return its result (``status`` ``reached`` or
        ``failed`` with a ``reason``); ``on_feedback`` is called with each feedback on zenoh's
        thread. Raises FleetError ``timeout`` after ``timeout`` wall seconds (the goal goes on:
        cancel it if you no longer want it)."""
        self._on_feedback = on_feedback
        deadline = None if timeout is None else time.monotonic() + timeout
        next_check = time.monotonic() + CHECK_EVERY_S
        with self._cond:
            while self.result is None:
                now = time.monotonic()
                if deadline is not None and now >= deadline:
                    raise FleetError(
                        ErrorCode.TIMEOUT, f"goal {self.goal_id} of {self.robot} did not end within {timeout:g} s"
                    )
                if now >= next_check:
                    self._cond.release()
                    try:
                        lost = self._check()
                    finally:
                        self._cond.acquire()
                    if lost is not None and self.result is None:
                        self.result = lost
                        break
                    next_check = time.monotonic() + CHECK_EVERY_S
                wake = next_check if deadline is None else min(deadline, next_check)
                self._cond.wait(max(0.0, wake - time.monotonic()))
        self.close()
        assert self.result is not None
        return self.result

    def _check(self) -> NavigationResult | None:
        """Ask the daemon how the goal stands: its result if it ended unheard, a ``robot_gone``
        result if the daemon no longer knows the robot or the goal, None while it goes on (or
        while no daemon answers: it may be restarting)."""
        try:
            state = self._client.navigation_state(self.robot)
        except FleetError as e:
            if e.code == ErrorCode.NOT_FOUND:
                return self._gone(f"robot {self.robot!r} is gone")
            return None
        if state.goal_id == self.goal_id:
            return state.result if not state.active else None
        if state.result is not None and state.result.goal_id == self.goal_id:
            return state.result
        return self._gone(f"the daemon no longer knows goal {self.goal_id} (was it restarted without --state?)")

    def _gone(self, message: str) -> NavigationResult:
        return NavigationResult(
            goal_id=self.goal_id, robot=self.robot, stamp=Time(), status="failed", reason="robot_gone", message=message
        )

    def cancel(self) -> NavigationResult:
        """Cancel the goal; its result (``cancelled``), or the result it already had."""
        if self.result is not None:
            return self.result
        try:
            result = self._client.cancel_goal(self.robot, self.goal_id)
        except FleetError:
            if self.result is not None:  # it ended meanwhile
                return self.result
            raise
        with self._cond:
            if self.result is None:
                self.result = result
        self.close()
        return self.result

    def close(self) -> None:
        """Stop listening (the goal itself goes on)."""
        subs, self._subs = self._subs, []
        for s in subs:
            try:
                s.undeclare()
            except zenoh.ZError:
                pass

    def __repr__(self) -> str:
        state = self.result.status if self.result else (self.feedback.state if self.feedback else "sent")
        return f"Goal({self.robot!r}, {self.goal_id!r}, {state})"
