"""Requests served on the caller's thread: an engine that no thread runs (a local fleet,
simd/engine/local.py) answers each request at once, a step to its last tick.

The serving is the engine's own (its handlers, its step jobs, its ticks), so a step here and
a step of ``simd --lockstep`` are the same code; what is left out is only the queue between
threads, the reply callback and, for a step with its commands as arrays, the bytes of packed
commands (a learner sends them every step). :class:`ServedHere` is a part of
:class:`~simd.engine.engine.Engine`, kept apart because a daemon never uses it.
"""

from __future__ import annotations

import collections
from typing import TYPE_CHECKING

from protocol.control import Request, StepRequest
from protocol.errors import ErrorCode, FleetError
from simd.core.sim import Simulation
from simd.core.snapshot import RobotState
from simd.engine.ports import PlaceRequest, Reply, Result, StepResult
from simd.engine.stepping import StepJob, StepPlanner

if TYPE_CHECKING:
    from fleetcommon.arrays import F64
    from protocol.navigation import NavigationRequest
    from simd.engine.at_once import Call


class ServedHere:
    """The engine's requests answered on the calling thread (a part of ``Engine``)."""

    # the engine's, which these methods drive
    sim: Simulation
    paused: bool
    _steps: collections.deque[StepJob]
    _planner: StepPlanner

    def _serve_call(self, request: Request | NavigationRequest | PlaceRequest, reply: Reply) -> None:
        raise NotImplementedError

    def _run_slice(self) -> None:
        raise NotImplementedError

    def _gather_commands(self) -> dict[str, tuple[float, float]]:
        raise NotImplementedError

    def _deleted(self, gone: list[RobotState]) -> None:
        raise NotImplementedError

    def _make_known(self, served: Call | None = None) -> None:
        raise NotImplementedError

    def delete_many_here(self, names: list[str]) -> tuple[list[RobotState], FleetError | None]:
        """Delete these robots at once, as that many delete requests served in this order would
        (a name not found, or a robot named again, is refused and the others deleted), with the
        table re-indexed once instead of once a robot (a learning environment clearing a
        thousand robots at every reset). The robots deleted, and the first refusal, naming its
        robot."""
        chosen: list[str] = []
        seen: set[int] = set()
        refusal: FleetError | None = None
        for name in names:
            robot = self.sim.robots.find(name)
            if robot is None or robot.rid in seen:
                if refusal is None:
                    refusal = FleetError(ErrorCode.NOT_FOUND, f"{name}: Entity [{name}] does not exist", "name")
                continue
            seen.add(robot.rid)
            chosen.append(name)
        gone = self.sim.delete_many(chosen) if chosen else []
        if gone:
            self._deleted(gone)
            self._make_known()
        return gone, refusal

    def serve_here(self, request: Request | NavigationRequest | PlaceRequest) -> Result | FleetError:
        """Serve one request on the calling thread, a step to its last tick, and return its answer."""
        answers: list[Result | FleetError] = []
        self._serve_call(request, answers.append)
        while self._steps:
            self._run_slice()
        return answers[0]

    def step_here(self, req: StepRequest, names: list[str], values: F64) -> StepResult:
        """Run a step on the calling thread to its last tick and return its answer, its
        commands (``names`` at the (v, w) rows of ``values``, an (n, 2) array) given apart
        from ``req``, whose own are not read. The checks, ticks and answer are those of
        ``req`` with these commands; a refusal raises FleetError."""
        answers: list[Result | FleetError] = []
        self._gather_commands()
        self._steps.append(self._step_job(req, answers.append, (names, values)))
        while self._steps:
            self._run_slice()
        answer = answers[0]
        assert isinstance(answer, StepResult)
        return answer

    def _step_job(self, req: StepRequest, reply: Reply, given: tuple[list[str], F64] | None = None) -> StepJob:
        """A step request checked (FleetError if refused) and ready to run."""
        if not self.paused:
            raise FleetError(
                ErrorCode.NOT_ALLOWED,
                "step needs a paused simulation or --lockstep (pause it first with sim/pause)",
            )
        return self._planner.job(self.sim, req, reply, given)
