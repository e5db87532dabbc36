"""The navigation requests (a goal, its cancel, a robot's navigation state), as the engine
serves them on the simulation thread.

The navigator (simd/nav) drives the robots that have a goal; these handlers only check that
navigation is on and the robot exists, hand the request to the navigator, and pass on what it
said (a preempted goal's result goes out before the new goal's reply).
"""

from __future__ import annotations

from collections.abc import Callable

from protocol.errors import ErrorCode, FleetError
from protocol.navigation import CancelRequest, NavigateRequest, NavigationStateRequest
from simd.core.sim import Simulation
from simd.engine.ports import Event, Navigation, Reply, Result
from simd.nav.navigator import Navigator


class NavigationRequests:
    """Serves the navigation requests for one engine; ``event`` tells the adapters,
    ``changed`` says the fleet's state (its goals) changed."""

    def __init__(
        self, sim: Simulation, navigator: Navigator | None, event: Callable[[Event], None], changed: Callable[[], None]
    ) -> None:
        self.sim = sim
        self.navigator = navigator
        self._event = event
        self._changed = changed

    def _nav(self, robot: str) -> tuple[Navigator, str]:
        """The navigator and the robot's namespace, or the error that refuses the request."""
        if self.navigator is None:
            raise FleetError(ErrorCode.NOT_ALLOWED, "navigation is off on this daemon (it was started with --no-nav)")
        found = self.sim.find(robot)
        if found is None:
            raise FleetError(ErrorCode.NOT_FOUND, f"no robot called {robot!r}", "robot")
        return self.navigator, found.namespace

    def navigate(self, req: NavigateRequest, reply: Reply) -> Result:
        nav, ns = self._nav(req.robot)
        robot = self.sim.find(ns)
        assert robot is not None
        accepted = nav.goal(ns, robot.model, req, self.sim.time)
        self.tell()  # the preempted goal's result goes before this reply
        self._changed()
        return accepted

    def cancel(self, req: CancelRequest, reply: Reply) -> Result:
        nav, ns = self._nav(req.robot)
        result = nav.cancel(ns, req.goal_id, self.sim.time)
        self.tell()
        self._changed()
        return result

    def state(self, req: NavigationStateRequest, reply: Reply) -> Result:
        nav, ns = self._nav(req.robot)
        return nav.state(ns)

    def tell(self) -> None:
        """Pass on what the navigator said since it was last asked."""
        assert self.navigator is not None
        said = self.navigator.take_events()
        if said:
            self._event(Navigation(said))
