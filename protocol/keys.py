"""The key space. ``P`` is the daemon's prefix (``fleet`` by default).

=====================  ==========================  ==========  ======================================
key                    declared by simd as         payload     reply / notes
=====================  ==========================  ==========  ======================================
``P/spawn``            queryable                   SpawnRequest   RobotRecord
``P/delete``           queryable                   DeleteRequest  RobotRecord of the removed robot
``P/robots``           queryable                   (none)      RobotList
``P/world``            queryable                   (none)      WorldInfo
``P/clock``            publisher 10 Hz + queryable (none)      Clock
``P/sim/pause``        queryable                   (none)      Clock
``P/sim/resume``       queryable                   (none)      Clock
``P/sim/reset``        queryable                   ResetRequest   Clock
``P/sim/step``         queryable                   StepRequest    StepReply, after the ticks ran
``P/<ns>/cmd_vel``     subscriber                  Twist
``P/commands``         subscriber                  PackedCommands  many robots' cmd_vel in one message
``P/<ns>/odom``        publisher 30 Hz + queryable Odometry    a get returns the latest message
``P/<ns>/scan``        publisher 5 Hz + queryable  LaserScan   a get returns the latest message
``P/<ns>/alive``       liveliness token            --          present while the robot lives
``P/<ns>/navigate``    queryable                   NavigateRequest  NavigateReply (protocol/navigation.py)
``P/<ns>/navigate/cancel`` queryable               CancelRequest  NavigationResult of the ended goal
``P/<ns>/navigate/state``  queryable               (none)      NavigationState
``P/<ns>/navigate/feedback`` publisher 5 Hz        NavigationFeedback  while a goal is active
``P/<ns>/navigate/result`` publisher               NavigationResult  once per goal
``P/<ns>/plan``        publisher + queryable       NavigationPath  each time the robot plans
``P/navigation``       publisher 2 Hz, on demand   FleetNavigation  every navigating robot
``P/odometry``         publisher 30 Hz, on demand  FleetOdometry  every robot's odometry of a tick
``P/scans``            publisher, on demand        FleetScans  the scans of a tick (the group due)
``P/daemons``          queryable                   (none)      DaemonInfo, one reply a daemon
``P/daemons/<id>``     liveliness token            --          present while daemon ``<id>`` runs
``P/daemons/<id>/tick`` publisher, stepping only   DaemonTick  a shared fleet's daemons before each stepped tick
``P/daemons/<id>/clock`` queryable                 (none)      Clock of daemon ``<id>`` alone (its healthcheck)
``P/daemons/<id>/ros2/..`` liveliness token         --          on the ROS 2 session (below)
=====================  ==========================  ==========  ======================================

``P/daemons/<id>/ros2/<domain>/<distro>/<since>`` (``simd --join --ros2``): daemon ``<id>``
serves ROS 2 domain ``<domain>`` for ``<distro>`` since ``<since>`` (ns of the Unix epoch),
declared on its ROS 2 session. Of the daemons that serve one domain, the earliest speaks for
the fleet: it alone publishes ``/clock`` and declares the ROS services (docs/ros2.md).
"""

from __future__ import annotations

from dataclasses import dataclass

from protocol.names import check_prefix

DEFAULT_PREFIX = "fleet"


@dataclass(frozen=True)
class Keys:
    """Key expressions under one prefix."""

    prefix: str = DEFAULT_PREFIX

    def __post_init__(self) -> None:
        check_prefix(self.prefix)

    def _k(self, *chunks: str) -> str:
        return "/".join((self.prefix, *chunks))

    @property
    def spawn(self) -> str:
        return self._k("spawn")

    @property
    def delete(self) -> str:
        return self._k("delete")

    @property
    def robots(self) -> str:
        return self._k("robots")

    @property
    def world(self) -> str:
        return self._k("world")

    @property
    def clock(self) -> str:
        return self._k("clock")

    @property
    def pause(self) -> str:
        return self._k("sim", "pause")

    @property
    def resume(self) -> str:
        return self._k("sim", "resume")

    @property
    def reset(self) -> str:
        return self._k("sim", "reset")

    @property
    def step(self) -> str:
        return self._k("sim", "step")

    @property
    def fleet_odom(self) -> str:
        """Every robot's odometry of one tick in one message; published while someone listens."""
        return self._k("odometry")

    @property
    def fleet_scan(self) -> str:
        """The scans of one tick in one message; published while someone listens."""
        return self._k("scans")

    @property
    def daemons(self) -> str:
        """Every daemon of the fleet answers here with its :class:`~protocol.control.DaemonInfo`."""
        return self._k("daemons")

    def daemon(self, daemon_id: str) -> str:
        """The liveliness token of daemon ``daemon_id``."""
        return self._k("daemons", daemon_id)

    def daemon_clock(self, daemon_id: str) -> str:
        """The clock of daemon ``daemon_id`` alone (``P/clock`` is answered by any daemon of a
        shared fleet): whether that daemon, its session and its tick loop are up."""
        return self._k("daemons", daemon_id, "clock")

    def daemon_tick(self, daemon_id: str) -> str:
        """Where daemon ``daemon_id`` of a shared fleet puts its robots before each tick it
        steps (``*`` for every daemon's): the one clock of docs/scale-out.md."""
        return self._k("daemons", daemon_id, "tick")

    def daemon_ros2(self, daemon_id: str, domain: int | str, distro: str, since: int | str) -> str:
        """The liveliness token by which daemon ``daemon_id`` of a shared fleet says it serves ROS 2
        domain ``domain`` for ``distro`` since ``since`` (ns of the Unix epoch); ``*`` in any
        chunk for a pattern."""
        return self._k("daemons", daemon_id, "ros2", str(domain), distro, str(since))

    def cmd_vel(self, ns: str) -> str:
        return self._k(ns, "cmd_vel")

    def commands(self) -> str:
        """Many robots' commands in one message (``PackedCommands``): what a program driving a
        big fleet puts instead of one ``cmd_vel`` per robot."""
        return self._k("commands")

    def odom(self, ns: str) -> str:
        return self._k(ns, "odom")

    def scan(self, ns: str) -> str:
        return self._k(ns, "scan")

    def alive(self, ns: str) -> str:
        return self._k(ns, "alive")

    def navigate(self, ns: str) -> str:
        """Send robot ``ns`` a goal (queryable; ``*`` for every robot's)."""
        return self._k(ns, "navigate")

    def navigate_cancel(self, ns: str) -> str:
        return self._k(ns, "navigate", "cancel")

    def navigate_state(self, ns: str) -> str:
        return self._k(ns, "navigate", "state")

    def navigate_feedback(self, ns: str) -> str:
        return self._k(ns, "navigate", "feedback")

    def navigate_result(self, ns: str) -> str:
        return self._k(ns, "navigate", "result")

    def plan(self, ns: str) -> str:
        """The path robot ``ns`` follows, put each time it is planned."""
        return self._k(ns, "plan")

    @property
    def fleet_navigation(self) -> str:
        """Every navigating robot's state and goal in one message, at 2 Hz while someone listens."""
        return self._k("navigation")

    def robot_of(self, key: str, *tail: str) -> str | None:
        """The ``<ns>`` of a concrete key ``P/<ns>/<tail...>`` (None for another shape or a
        wildcard), e.g. ``robot_of(key, "navigate", "cancel")``."""
        head = self.prefix + "/"
        if not key.startswith(head) or "*" in key:
            return None
        rest = key[len(head) :].split("/")
        if len(rest) != 1 + len(tail) or tuple(rest[1:]) != tail or not rest[0]:
            return None
        return rest[0]

    def namespace_of(self, key: str) -> str | None:
        """The ``<ns>`` chunk of ``P/<ns>/<topic>``, or None if ``key`` has another shape."""
        head = self.prefix + "/"
        if not key.startswith(head):
            return None
        rest = key[len(head) :].split("/")
        if len(rest) != 2:
            return None
        return rest[0]
