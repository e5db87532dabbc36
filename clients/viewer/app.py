"""``fleet-view``: serve a live page of the fleet, or write one PNG snapshot of it.

The page opens a websocket to ``/ws``. The server sends the world once, then a frame at a
fixed rate built for the page's current view (see :mod:`clients.viewer.state` for the
format), each preceded by what changed in the robots' navigation if anything did
(:mod:`clients.viewer.navigation`). The page acknowledges each frame as it takes it in; while ``WINDOW`` frames are
unacknowledged the server skips ticks instead of queueing, so a slow page or link always gets
the latest state, never a backlog.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import signal
import socket
import sys
from pathlib import Path
from types import FrameType

import msgspec
import uvicorn
from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, Response
from starlette.routing import Mount, Route, WebSocketRoute
from starlette.staticfiles import StaticFiles
from starlette.websockets import WebSocket, WebSocketDisconnect

from clients.api import DEFAULT_TIMEOUT, FleetClient
from clients.viewer.decimate import View
from clients.viewer.feed import Feed
from clients.viewer.live_map import LiveMap
from clients.viewer.navigation import NavCursor
from clients.viewer.snapshot import render, take_snapshot
from clients.viewer.state import FleetState
from fleetcommon.zenoh_config import add_zenoh_args, options_from_args
from protocol.errors import FleetError
from protocol.keys import DEFAULT_PREFIX

log = logging.getLogger("fleet-view")

STATIC = Path(__file__).resolve().parent / "static"
DEFAULT_RATE = 15.0
WINDOW = 2  # frames sent but not yet acknowledged by the page before the server skips ticks


class ViewMsg(msgspec.Struct, tag="view", kw_only=True):
    """The page's view: visible world rectangle (x0, y0, x1, y1), toggles, selection."""

    rect: tuple[float, float, float, float] | None = None
    scans: bool = True
    trails: bool = True
    selected: str | None = None

    def to_view(self) -> View:
        if self.rect is None:
            return View(scans=self.scans, trails=self.trails, selected=self.selected)
        x0, y0, x1, y1 = self.rect
        return View(
            min(x0, x1),
            min(y0, y1),
            max(x0, x1),
            max(y0, y1),
            self.scans,
            self.trails,
            self.selected,
        )


class AckMsg(msgspec.Struct, tag="ack", kw_only=True):
    """The page has drawn frame ``seq``."""

    seq: int


_page_decoder = msgspec.json.Decoder(ViewMsg | AckMsg)


class FrameStream:
    """One page's websocket: frames out at ``rate``, view and acks in."""

    def __init__(self, ws: WebSocket, state: FleetState, rate: float) -> None:
        self.ws = ws
        self.state = state
        self.period = 1.0 / rate
        self.view = View()
        self.seq = 0
        self.acked = 0
        self.skipped = 0
        self.meta_version = -1
        self.nav = NavCursor()
        self.world_version = -1
        self.clock_version = -1

    async def run(self) -> None:
        await self.ws.accept()
        receiver = asyncio.create_task(self._receive())
        try:
            await self._send_world()
            await self._send_loop(receiver)
        except (WebSocketDisconnect, RuntimeError, ConnectionError):
            pass
        finally:
            receiver.cancel()
            with contextlib.suppress(asyncio.CancelledError, WebSocketDisconnect, RuntimeError):
                await receiver

    async def _send_world(self) -> None:
        self.world_version = self.state.world_version
        await self.ws.send_text(self.state.world_json().decode())

    async def _receive(self) -> None:
        while True:
            message = await self.ws.receive()
            if message["type"] == "websocket.disconnect":
                raise WebSocketDisconnect(message.get("code", 1000))
            text = message.get("text")
            if text is None:
                continue  # the page only sends text
            try:
                msg = _page_decoder.decode(text)
            except msgspec.DecodeError:
                log.debug("ignored a malformed page message: %.80s", text)
                continue
            match msg:
                case AckMsg(seq=seq):
                    self.acked = max(self.acked, min(seq, self.seq))
                case ViewMsg():
                    self.view = msg.to_view()

    async def _send_loop(self, receiver: asyncio.Task[None]) -> None:
        loop = asyncio.get_running_loop()
        due = loop.time()
        build_ms = 0.0
        while not receiver.done():
            due += self.period
            delay = due - loop.time()
            if delay < -self.period:  # fell behind (busy loop): restart the clock, no burst
                due = loop.time()
            else:
                await asyncio.wait({receiver}, timeout=max(0.0, delay))
            if receiver.done():
                break
            if self.world_version != self.state.world_version:  # a daemon restarted in another world
                await self._send_world()
            if self.seq - self.acked >= WINDOW:
                self.skipped += 1  # the page has not drawn the last frames: drop this tick
                continue
            self.seq += 1
            extra = {"skipped": self.skipped, "build_ms": round(build_ms, 2)}
            head: dict[str, object] = {}
            clock = self.state.clock_update(self.clock_version)
            if clock is not None:  # about once a second: the daemon's clock changed
                self.clock_version, head["clock"] = clock
            version, meta, data, stats = self.state.frame(self.view, self.seq, self.meta_version, extra, head)
            build_ms = stats.build_ms
            if meta is not None:
                await self.ws.send_text(meta.decode())
                self.meta_version = version
            nav = self.state.nav_updates(self.nav)
            if nav is not None:
                await self.ws.send_text(nav.decode())
            await self.ws.send_bytes(data)


def create_app(state: FleetState, rate: float = DEFAULT_RATE, live_map: LiveMap | None = None) -> Starlette:
    """The viewer's web app: ``/`` the page, ``/ws`` its frames, ``/snapshot.png`` a PNG of
    the current state (``?size=N``), ``/api/counts`` how many robots it knows, and with a live
    map ``/map.png`` (404 without one)."""

    async def index(request: Request) -> FileResponse:
        return FileResponse(STATIC / "index.html")

    async def frames(ws: WebSocket) -> None:
        await FrameStream(ws, state, rate).run()

    async def snapshot_png(request: Request) -> Response:
        try:
            size = min(4096, max(64, int(request.query_params.get("size", "1024"))))
        except ValueError:
            return Response("size must be an integer", status_code=400)

        def draw() -> bytes:
            import io

            img, _ = render(state.world, state.robots(), size, state.sim_time)
            buf = io.BytesIO()
            img.save(buf, format="PNG")
            return buf.getvalue()

        return Response(await run_in_threadpool(draw), media_type="image/png")

    async def counts(request: Request) -> JSONResponse:
        return JSONResponse(state.counts())

    async def map_png(request: Request) -> Response:
        if live_map is None:
            return Response("no map layer: start fleet-view with --map", status_code=404)
        data, headers = await run_in_threadpool(live_map.png)
        return Response(data, media_type="image/png", headers=headers)

    return Starlette(
        routes=[
            Route("/", index),
            WebSocketRoute("/ws", frames),
            Route("/snapshot.png", snapshot_png),
            Route("/api/counts", counts),
            Route("/map.png", map_png),
            Mount("/static", StaticFiles(directory=STATIC), name="static"),
        ]
    )


def serve(client: FleetClient, host: str, port: int, rate: float, with_map: bool = False) -> None:
    """Run the web server until Ctrl-C or SIGTERM."""
    state = FleetState()
    feed = Feed(client, state)
    feed.start()
    live_map = feed.add_live_map() if with_map else None
    try:
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        sock = socket.socket(family, socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind((host, port))
        except OSError as e:
            sock.close()
            raise OSError(e.errno, f"cannot listen on {host}:{port}: {e.strerror}") from None
        url_host = f"[{host}]" if family == socket.AF_INET6 else host
        print(f"fleet-view: http://{url_host}:{sock.getsockname()[1]}/  (Ctrl-C to stop)", flush=True)
        config = uvicorn.Config(
            create_app(state, rate, live_map),
            log_level="warning",
            ws="websockets-sansio",
            lifespan="off",
            timeout_graceful_shutdown=2,
        )
        uvicorn.Server(config).run(sockets=[sock])
    finally:
        feed.close()


def _exit_on_sigterm(signum: int, frame: FrameType | None) -> None:
    raise SystemExit(0)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="fleet-view",
        description="See the fleet live in a browser, or write a PNG snapshot of it.",
        epilog="Example: fleet-view -e tcp/127.0.0.1:7447, then open the printed URL.",
    )
    p.add_argument("--prefix", default=DEFAULT_PREFIX, help="the daemon's key prefix (default: %(default)s)")
    p.add_argument("--host", default="127.0.0.1", help="address to serve the page on (default: %(default)s)")
    p.add_argument(
        "--port",
        type=int,
        default=8765,
        help="port to serve on, 0 for any free one (default: %(default)s)",
    )
    p.add_argument(
        "--rate",
        type=float,
        default=DEFAULT_RATE,
        help="frames per second pushed to each page (default: %(default)s)",
    )
    p.add_argument("--snapshot", type=Path, metavar="OUT.png", help="write one PNG snapshot and exit")
    p.add_argument(
        "--map",
        action="store_true",
        help="build the occupancy map from the robots' scans and draw it under them, live (as fleet-map)",
    )
    p.add_argument(
        "--size",
        type=int,
        default=1024,
        help="snapshot width and height in pixels (default: %(default)s)",
    )
    p.add_argument(
        "--timeout",
        type=float,
        default=5.0,
        help="snapshot: seconds to wait for each robot's odometry and scan (default: %(default)s)",
    )
    p.add_argument("--log-level", choices=("debug", "info", "warning", "error"), default="warning")
    add_zenoh_args(p, server=False)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=args.log_level.upper(), format="fleet-view: %(message)s")
    if not 0 < args.rate <= 60:
        print("fleet-view: --rate must be in (0, 60]", file=sys.stderr)
        return 2
    if not 64 <= args.size <= 8192:
        print("fleet-view: --size must be within 64..8192", file=sys.stderr)
        return 2
    signal.signal(signal.SIGTERM, _exit_on_sigterm)
    try:
        client = FleetClient(
            options=options_from_args(args, server=False),
            prefix=args.prefix,
            timeout=DEFAULT_TIMEOUT,
        )
    except (FleetError, ValueError) as e:
        if isinstance(e, FleetError) and e.field == "connect":  # a bad -e, -c or --cfg
            print(f"fleet-view: error: {e.message}", file=sys.stderr)
            return 2
        print(f"fleet-view: {e}", file=sys.stderr)
        return 1
    try:
        if args.snapshot is not None:
            n = take_snapshot(client, args.snapshot, args.size, args.timeout)
            print(f"fleet-view: wrote {args.snapshot} ({n} robot{'s' if n != 1 else ''})", flush=True)
            return 0
        serve(client, args.host, args.port, args.rate, with_map=args.map)
        return 0
    except KeyboardInterrupt:
        return 0
    except FleetError as e:
        print(f"fleet-view: {e}", file=sys.stderr)
        return 1
    except OSError as e:
        print(f"fleet-view: {e.strerror or e}", file=sys.stderr)
        return 1
    finally:
        client.close()


if __name__ == "__main__":
    sys.exit(main())
