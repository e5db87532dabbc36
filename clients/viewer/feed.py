"""The viewer's feed: a :class:`FleetState` kept current from a daemon over a
:class:`~clients.api.FleetClient` (the world, presence, the fleet topics, navigation, and a
thread that asks for the records of robots that appeared and for the paths they follow, and
one that asks for the clock once a second)."""

from __future__ import annotations

import logging
import threading

from clients.api import FleetClient, Subscription
from clients.viewer.live_map import LiveMap
from clients.viewer.state import FleetState
from protocol.errors import FleetError

log = logging.getLogger(__name__)

#: Seconds between the feed's questions for the daemon's clock (its real-time factor).
CLOCK_PERIOD = 1.0


class Feed:
    """Connects a :class:`FleetState` to a :class:`FleetClient`: the world, presence, odom,
    scan and navigation callbacks, and a thread that fetches the records of robots that
    appeared and then the paths they already follow (queries, so never from a zenoh callback)."""

    def __init__(self, client: FleetClient, state: FleetState) -> None:
        self.client = client
        self.state = state
        self._stop = threading.Event()
        self._subs: list[Subscription] = []
        self._thread = threading.Thread(target=self._records_loop, name="fleet-view-records", daemon=True)
        self._clock_thread = threading.Thread(target=self._clock_loop, name="fleet-view-clock", daemon=True)
        self._live_map: LiveMap | None = None

    def start(self) -> None:
        self.state.set_world(self.client.world())
        self._subs.append(self.client.on_daemons(self.state.on_daemon))
        self._subs.append(self.client.on_presence(self.state.on_presence))
        # the fleet topics: one message a tick for all robots, where the per-robot topics would
        # be 35 000 messages a second at 1 000 robots (each ~10 us of this process's CPU)
        self._subs.append(self.client.on_fleet_odom(self.state.on_fleet_odom))
        self._subs.append(self.client.on_fleet_scans(self.state.on_fleet_scans))
        # navigation: the summary (2 Hz, put only while somebody listens), each path when it is
        # planned and each goal's end; the paths of goals under way are asked for by the thread
        self._subs.append(self.client.on_navigation(self.state.on_navigation))
        self._subs.append(self.client.on_plans(self.state.on_plan))
        self._subs.append(self.client.on_navigation_results(self.state.on_nav_result))
        self._thread.start()
        self._clock_thread.start()

    def add_live_map(self) -> LiveMap:
        """Also build the occupancy map from the scans the feed receives (``fleet-view --map``)."""
        assert self.state.world is not None, "start() first"
        live = LiveMap(self.state.world)
        self._live_map = live
        self._subs.append(self.client.on_fleet_odom(live.on_fleet_odom))
        self._subs.append(self.client.on_fleet_scans(live.on_fleet_scans))
        return live

    def _records_loop(self) -> None:
        wanted = self.state.records_wanted
        while not self._stop.is_set():
            if not wanted.wait(0.25) and not self.state.world_wanted.is_set():
                continue
            wanted.clear()
            self._stop.wait(0.05)  # let a burst of spawns arrive, then ask once
            if self.state.world_wanted.is_set():
                self.state.world_wanted.clear()
                try:
                    self.state.set_world(self.client.world())
                except FleetError as e:  # a daemon's token can come before its queryables answer
                    log.debug("could not ask for the world yet: %s", e)
                    self.state.world_wanted.set()
                    self._stop.wait(0.25)
            try:
                records = self.client.robots()
                self.state.apply_records(records)
                if self._live_map is not None:  # the lidar's mounting offset depends on the model
                    self._live_map.set_models({r.namespace: r.model for r in records})
            except FleetError as e:
                log.warning("could not list robots: %s", e)
                self._stop.wait(0.5)
            else:
                self._fetch_plans()
            if self.state.missing_records():
                self._stop.wait(0.2)
                wanted.set()

    def _fetch_plans(self) -> None:
        """The paths of goals already under way (a viewer opened mid-goal, robots that came)."""
        try:
            self.state.apply_plans(self.client.plans())
        except FleetError as e:
            log.debug("could not ask for the robots' paths: %s", e)

    def _clock_loop(self) -> None:
        """Ask for the clock (``P/clock``) once a second: a query rather than the topic, which
        a daemon publishes at 10 Hz of sim time (10 000 a second at ``--rtf 1000``, and none
        while paused)."""
        while True:
            try:
                self.state.set_clock(self.client.clock())
            except FleetError as e:
                log.debug("could not ask for the clock: %s", e)
                self.state.set_clock(None)
            if self._stop.wait(CLOCK_PERIOD):
                return

    def close(self) -> None:
        self._stop.set()
        for s in self._subs:
            s.close()
        self._subs.clear()
        for t in (self._thread, self._clock_thread):
            if t.is_alive():
                t.join(timeout=5.0)
