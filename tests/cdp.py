"""A small headless-Chromium driver over the Chrome DevTools Protocol (no extra dependency:
the ``websockets`` sync client). Enough for page tests: navigate, evaluate, wait, screenshot.

    with Chromium(tmp_path / "profile") as browser:
        browser.navigate("http://127.0.0.1:8765/")
        browser.wait_for("window.viewerStats && viewerStats.robots === 4")
        png = browser.screenshot()
"""

from __future__ import annotations

import base64
import contextlib
import json
import shutil
import subprocess
import time
from pathlib import Path
from typing import Any

from websockets.sync.client import ClientConnection, connect

CHROMIUM = shutil.which("chromium")


class CDPError(RuntimeError):
    pass


class Chromium:
    """A headless Chromium process and a CDP session attached to its page."""

    def __init__(self, profile: Path, width: int = 1280, height: int = 800, start_timeout: float = 20.0) -> None:
        if CHROMIUM is None:
            raise CDPError("chromium is not installed")
        profile.mkdir(parents=True, exist_ok=True)
        self.proc = subprocess.Popen(
            [
                CHROMIUM,
                "--headless",
                "--no-sandbox",
                "--disable-gpu",
                "--disable-quic",
                "--no-first-run",
                "--no-default-browser-check",
                "--disable-background-networking",
                "--disable-component-update",
                "--disable-sync",
                "--disable-extensions",
                "--disable-background-timer-throttling",
                "--disable-renderer-backgrounding",
                "--disable-backgrounding-occluded-windows",
                "--hide-scrollbars",
                "--mute-audio",
                "--remote-debugging-port=0",
                f"--user-data-dir={profile}",
                f"--window-size={width},{height}",
                "about:blank",
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        self._next_id = 0
        self._ws: ClientConnection | None = None
        self._stack = contextlib.ExitStack()
        self._session = ""
        try:
            port_file = profile / "DevToolsActivePort"
            deadline = time.monotonic() + start_timeout
            while True:
                lines = port_file.read_text().split() if port_file.exists() else []
                if len(lines) >= 2:
                    break
                if self.proc.poll() is not None or time.monotonic() > deadline:
                    raise CDPError(f"chromium did not start (exit code {self.proc.poll()})")
                time.sleep(0.05)
            url = f"ws://127.0.0.1:{lines[0]}{lines[1]}"
            self._ws = self._stack.enter_context(connect(url, max_size=None, open_timeout=10))
            targets = self.call("Target.getTargets", session=False)["targetInfos"]
            page = next(t for t in targets if t["type"] == "page")
            self._session = self.call(
                "Target.attachToTarget", {"targetId": page["targetId"], "flatten": True}, session=False
            )["sessionId"]
            self.call("Page.enable")
            self.call(
                "Emulation.setDeviceMetricsOverride",
                {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False},
            )
        except BaseException:
            self.close()
            raise

    def call(
        self, method: str, params: dict[str, Any] | None = None, *, session: bool = True, timeout: float = 15.0
    ) -> Any:
        """Send one CDP command and return its result (events in between are dropped)."""
        assert self._ws is not None
        self._next_id += 1
        msg: dict[str, Any] = {"id": self._next_id, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = self._session
        self._ws.send(json.dumps(msg))
        deadline = time.monotonic() + timeout
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise CDPError(f"{method}: no answer within {timeout} s")
            reply = json.loads(self._ws.recv(timeout=left))
            if reply.get("id") == self._next_id:
                if "error" in reply:
                    raise CDPError(f"{method}: {reply['error']}")
                return reply.get("result", {})

    def navigate(self, url: str, timeout: float = 15.0) -> None:
        self.call("Page.navigate", {"url": url})
        self.wait_for(f"location.href === {json.dumps(url)} && document.readyState === 'complete'", timeout)

    def evaluate(self, expression: str) -> Any:
        """Evaluate JavaScript in the page and return its value (JSON-serialisable)."""
        res = self.call("Runtime.evaluate", {"expression": expression, "returnByValue": True, "awaitPromise": True})
        if "exceptionDetails" in res:
            details = res["exceptionDetails"]
            text = details.get("exception", {}).get("description") or details.get("text")
            raise CDPError(f"{expression!r} raised: {text}")
        return res["result"].get("value")

    def wait_for(self, expression: str, timeout: float = 10.0, interval: float = 0.05) -> Any:
        """Poll ``expression`` until it is truthy; return its value."""
        deadline = time.monotonic() + timeout
        while True:
            value = self.evaluate(expression)
            if value:
                return value
            if time.monotonic() > deadline:
                raise CDPError(f"timed out after {timeout} s waiting for {expression!r} (last: {value!r})")
            time.sleep(interval)

    def click(self, x: float, y: float) -> None:
        """A left click at page CSS pixel (x, y)."""
        for kind in ("mouseMoved", "mousePressed", "mouseReleased"):
            self.call(
                "Input.dispatchMouseEvent",
                {"type": kind, "x": x, "y": y, "button": "left", "buttons": 1 if kind == "mousePressed" else 0,
                 "clickCount": 1},
            )  # fmt: skip

    def screenshot(self) -> bytes:
        """A PNG of the viewport."""
        return base64.b64decode(self.call("Page.captureScreenshot", {"format": "png"})["data"])

    def close(self) -> None:
        if self._ws is not None:
            try:
                self.call("Browser.close", session=False, timeout=5)
            except Exception:
                pass
            self._stack.close()
            self._ws = None
        try:
            self.proc.wait(5)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()

    def __enter__(self) -> Chromium:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
