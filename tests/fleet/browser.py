"""A real headless Chromium for the tests: open a page as a person would, and say what it showed.

Chromium is driven over the DevTools protocol on a pipe (`--remote-debugging-pipe`: commands on
its fd 3, answers on its fd 4, each a JSON text ended by a NUL byte), so the standard library is
enough: no websocket client, no driver binary. Unlike `--enable-logging=stderr`, whose CONSOLE
lines carry no level in this Chromium (156), the protocol says what each console message's level
is, which exceptions were thrown, which requests the page made and which failed, and takes the
screenshot. PNG decoding is matplotlib's (a test dependency).
"""

from __future__ import annotations

import base64
import fcntl
import json
import os
import select
import shutil
import subprocess
import tempfile
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

CHROMIUM = ("chromium", "chromium-browser", "/usr/bin/chromium")


def find_chromium() -> str | None:
    """The Chromium binary, or None when it is not installed (`make system-deps` installs it)."""
    for name in CHROMIUM:
        found = shutil.which(name)
        if found:
            return found
    return None


class BrowserError(RuntimeError):
    """Chromium did not start, answer or load the page in time."""


@dataclass(frozen=True)
class Visit:
    png: bytes  # the screenshot of the viewport
    console: list[tuple[str, str]]  # (level: "log", "warning", "error", ..., text)
    exceptions: list[str]  # uncaught exceptions' descriptions
    log: list[tuple[str, str, str]]  # the browser's own log: (level, url, text), e.g. a failed load
    requests: list[str]  # every URL the page asked for, the page's own first
    failed: list[str]  # requests that failed: "url: reason"
    values: dict[str, Any] = field(default_factory=dict)  # what each evaluated expression gave

    @property
    def errors(self) -> list[str]:
        """Everything a person would see in the console as an error."""
        out = [f"console.{level}: {text}" for level, text in self.console if level in ("error", "assert")]
        out += [f"exception: {text}" for text in self.exceptions]
        out += [f"log {level}: {url}: {text}" for level, url, text in self.log if level == "error"]
        return out + [f"failed request: {f}" for f in self.failed]


class _Pipe:
    def __init__(self, write_fd: int, read_fd: int, deadline: float) -> None:
        self.write_fd, self.read_fd, self.deadline = write_fd, read_fd, deadline
        self.buffer = b""
        self.next_id = 0
        self.events: list[dict[str, Any]] = []

    def _message(self) -> dict[str, Any]:
        while b"\0" not in self.buffer:
            remaining = self.deadline - time.monotonic()
            if remaining <= 0:
                raise BrowserError("Chromium did not answer in time")
            ready, _, _ = select.select([self.read_fd], [], [], remaining)
            if not ready:
                continue
            chunk = os.read(self.read_fd, 1 << 20)
            if not chunk:
                raise BrowserError("Chromium closed its DevTools pipe")
            self.buffer += chunk
        raw, self.buffer = self.buffer.split(b"\0", 1)
        return json.loads(raw)

    def call(self, method: str, params: Mapping[str, Any] | None = None, session: str | None = None) -> dict[str, Any]:
        self.next_id += 1
        request: dict[str, Any] = {"id": self.next_id, "method": method, "params": dict(params or {})}
        if session:
            request["sessionId"] = session
        os.write(self.write_fd, json.dumps(request).encode() + b"\0")
        while True:
            message = self._message()
            if message.get("id") == self.next_id:
                if "error" in message:
                    raise BrowserError(f"{method}: {message['error'].get('message')}")
                return message.get("result", {})
            if "method" in message:
                self.events.append(message)

    def wait_for(self, method: str) -> None:
        if any(e["method"] == method for e in self.events):
            return
        while True:
            message = self._message()
            if "method" in message:
                self.events.append(message)
                if message["method"] == method:
                    return


def _high_fd(fd: int) -> int:
    # Above 4, so that placing the child's ends at 3 and 4 cannot overwrite one with the other.
    moved = fcntl.fcntl(fd, fcntl.F_DUPFD_CLOEXEC, 10)
    os.close(fd)
    return moved


def visit(url: str, *, width: int = 1400, height: int = 2000, evaluate: Mapping[str, str] | None = None, timeout_s: float = 30.0) -> Visit:
    """Open url in a fresh headless Chromium, wait for its load event, evaluate the given
    expressions (name -> JavaScript, returned by value), take a screenshot and close the browser."""
    binary = find_chromium()
    if binary is None:
        raise BrowserError("chromium is not installed")
    deadline = time.monotonic() + timeout_s
    to_child_r, to_child_w = (_high_fd(fd) for fd in os.pipe())
    from_child_r, from_child_w = (_high_fd(fd) for fd in os.pipe())

    def child_fds() -> None:
        os.dup2(to_child_r, 3)  # dup2 leaves the copies inheritable: Chromium gets them
        os.dup2(from_child_w, 4)

    with tempfile.TemporaryDirectory(prefix="bogiemon-chromium-") as profile:
        args = [
            binary,
            "--headless",
            "--no-sandbox",  # root in a container: the sandbox cannot start
            "--disable-gpu",
            "--hide-scrollbars",
            "--no-first-run",
            "--no-default-browser-check",
            "--remote-debugging-pipe",
            f"--user-data-dir={profile}",
            f"--window-size={width},{height}",
            "about:blank",
        ]
        proc = subprocess.Popen(
            args, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, close_fds=False, preexec_fn=child_fds
        )
        os.close(to_child_r)
        os.close(from_child_w)
        pipe = _Pipe(to_child_w, from_child_r, deadline)
        try:
            target = pipe.call("Target.createTarget", {"url": "about:blank"})["targetId"]
            session = pipe.call("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
            for domain in ("Page", "Runtime", "Log", "Network"):
                pipe.call(f"{domain}.enable", session=session)
            pipe.call("Emulation.setDeviceMetricsOverride", {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False}, session)
            pipe.events.clear()  # what about:blank did is not the page's
            pipe.call("Page.navigate", {"url": url}, session)
            pipe.wait_for("Page.loadEventFired")
            values = {}
            for name, expression in (evaluate or {}).items():
                result = pipe.call("Runtime.evaluate", {"expression": expression, "returnByValue": True}, session)
                if "exceptionDetails" in result:
                    raise BrowserError(f"{name}: {result['exceptionDetails'].get('text')}")
                values[name] = result["result"].get("value")
            png = base64.b64decode(pipe.call("Page.captureScreenshot", {"format": "png"}, session)["data"])
            try:
                pipe.call("Browser.close")
            except BrowserError:
                pass  # it may close the pipe before it answers
        finally:
            os.close(to_child_w)
            os.close(from_child_r)
            try:
                proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
    return _visit(png, pipe.events, values)


def _visit(png: bytes, events: list[dict[str, Any]], values: dict[str, Any]) -> Visit:
    console, exceptions, log, requests, failed = [], [], [], [], []
    urls: dict[str, str] = {}
    for e in events:
        method, p = e["method"], e.get("params", {})
        if method == "Runtime.consoleAPICalled":
            text = " ".join(str(a.get("value", a.get("description", ""))) for a in p.get("args", []))
            console.append((p.get("type", ""), text))
        elif method == "Runtime.exceptionThrown":
            details = p.get("exceptionDetails", {})
            exceptions.append(details.get("exception", {}).get("description") or details.get("text", ""))
        elif method == "Log.entryAdded":
            entry = p.get("entry", {})
            log.append((entry.get("level", ""), entry.get("url", ""), entry.get("text", "")))
        elif method == "Network.requestWillBeSent":
            urls[p.get("requestId", "")] = p["request"]["url"]
            requests.append(p["request"]["url"])
        elif method == "Network.loadingFailed":
            failed.append(f"{urls.get(p.get('requestId', ''), '?')}: {p.get('errorText', '')}")
    return Visit(png=png, console=console, exceptions=exceptions, log=log, requests=requests, failed=failed, values=values)


def read_png(png: bytes) -> Any:
    """The screenshot as an (height, width, 3) array of 0..255 integers."""
    import io

    import numpy as np
    from matplotlib import image

    pixels = image.imread(io.BytesIO(png), format="png")
    if pixels.dtype != np.uint8:
        pixels = np.rint(pixels * 255).astype(np.int32)
    return np.asarray(pixels[..., :3], dtype=np.int32)


def count_colour(pixels: Any, rgb: str, box: tuple[float, float, float, float] | None = None, tolerance: int = 24) -> int:
    """How many pixels (within box: left, top, width, height in CSS pixels) are within tolerance of rgb ("#rrggbb")."""
    import numpy as np

    target = np.array([int(rgb[i : i + 2], 16) for i in (1, 3, 5)])
    region = pixels
    if box is not None:
        left, top, w, h = (int(round(v)) for v in box)
        region = pixels[max(top, 0) : max(top + h, 0), max(left, 0) : max(left + w, 0)]
    return int(np.count_nonzero(np.all(np.abs(region - target) <= tolerance, axis=-1)))
