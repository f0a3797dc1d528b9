"""One headless Chromium for the report's screenshot tests, driven over its DevTools pipe.

Started once per test process and reused: each screenshot opens a new tab at the page, sized like the window
``--screenshot --window-size`` gave (a browser started per screenshot took 1.5-2 s of wall each, most of it
the browser's start). ``--remote-debugging-pipe``: the DevTools protocol's JSON messages, each ended by a NUL
byte, on the browser's descriptors 3 (in) and 4 (out); no port, no client library.
"""

from __future__ import annotations

import base64
import json
import os
import select
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CHROMIUM = Path("/usr/bin/chromium")
_ONTO_3_AND_4 = ("import os, sys\n"
                 "os.dup2(int(sys.argv[1]), 3); os.dup2(int(sys.argv[2]), 4)\n"
                 "os.execv(sys.argv[3], sys.argv[3:])\n")
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync")


def chromium_path() -> str | None:
    """The Chromium executable, or None when it is not installed."""
    return shutil.which("chromium") or shutil.which("chromium-browser") or (str(CHROMIUM) if CHROMIUM.exists()
                                                                         else None)


class BrowserError(RuntimeError):
    """The browser ended, answered with an error, or did not answer in time."""


class HeadlessChromium:
    def __init__(self, path: str, timeout_s: float = 120.0):
        self.timeout_s = timeout_s
        self._profile = tempfile.TemporaryDirectory(prefix="payload-agent-chromium-")
        self._log = tempfile.TemporaryFile()  # the browser's stderr, quoted when it fails (a file: never full)
        to_browser_r, self._to_browser = os.pipe()
        self._from_browser, from_browser_w = os.pipe()
        # a small Python step moves the pipe's ends onto descriptors 3 and 4, where the browser looks for them
        # (a shell cannot name descriptors above 9 portably; preexec_fn is unsafe beside threads)
        self._proc = subprocess.Popen(
            [sys.executable, "-c", _ONTO_3_AND_4, str(to_browser_r), str(from_browser_w), path, *FLAGS,
             f"--user-data-dir={self._profile.name}", "--remote-debugging-pipe", "about:blank"],
            pass_fds=(to_browser_r, from_browser_w), stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
            stderr=self._log)
        os.close(to_browser_r)
        os.close(from_browser_w)
        self._buffer = b""
        self._next_id = 0
        self._events: list[dict] = []  # events read while waiting for a command's answer

    # -- the protocol -------------------------------------------------------------------------------
    def _send(self, method: str, params: dict | None = None, session: str | None = None) -> int:
        self._next_id += 1
        message = {"id": self._next_id, "method": method, "params": params or {}}
        if session:
            message["sessionId"] = session
        try:
            os.write(self._to_browser, json.dumps(message).encode() + b"\0")
        except BrokenPipeError:
            raise BrowserError(f"Chromium ended (exit {self._proc.poll()}): {self._stderr()}") from None
        return self._next_id

    def _read(self, deadline: float) -> dict:
        while b"\0" not in self._buffer:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([self._from_browser], [], [], left)[0]:
                raise BrowserError(f"Chromium did not answer within {self.timeout_s:g} s")
            chunk = os.read(self._from_browser, 1 << 20)
            if not chunk:
                raise BrowserError(f"Chromium ended (exit {self._proc.poll()}): {self._stderr()}")
            self._buffer += chunk
        raw, self._buffer = self._buffer.split(b"\0", 1)
        return json.loads(raw)

    def call(self, method: str, params: dict | None = None, session: str | None = None) -> dict:
        """Send a command and return its result (events that come first are kept for ``_wait_event``)."""
        wanted = self._send(method, params, session)
        deadline = time.monotonic() + self.timeout_s
        while True:
            msg = self._read(deadline)
            if msg.get("id") == wanted:
                if "error" in msg:
                    raise BrowserError(f"{method}: {msg['error']}")
                return msg.get("result", {})
            if "method" in msg:
                self._events.append(msg)

    def _wait_event(self, method: str, session: str, deadline: float) -> None:
        seen, self._events = self._events, []
        while True:
            msg = seen.pop(0) if seen else self._read(deadline)
            if msg.get("method") == method and msg.get("sessionId") == session:
                return

    def _stderr(self) -> str:
        self._log.seek(0)
        return self._log.read().decode(errors="replace")[-2000:]

    # -- what the tests use -----------------------------------------------------------------------
    def screenshot(self, url: str, width: int, height: int) -> bytes:
        """A PNG of ``url`` loaded in a new tab of ``width`` x ``height`` CSS pixels at scale 1."""
        target = self.call("Target.createTarget", {"url": "about:blank"})["targetId"]
        try:
            session = self.call("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
            self.call("Emulation.setDeviceMetricsOverride",
                      {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False}, session)
            self.call("Page.enable", {}, session)
            self.call("Page.navigate", {"url": url}, session)
            self._wait_event("Page.loadEventFired", session, time.monotonic() + self.timeout_s)
            shot = self.call("Page.captureScreenshot", {"format": "png"}, session)
            return base64.b64decode(shot["data"])
        finally:
            self.call("Target.closeTarget", {"targetId": target})

    def close(self) -> None:
        try:
            self.call("Browser.close")
        except Exception:
            pass
        try:
            self._proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()
        for fd in (self._to_browser, self._from_browser):
            os.close(fd)
        self._log.close()
        self._profile.cleanup()
