"""Look at a recording the way a user does: Rerun's web viewer in headless Chromium, saved as PNGs.

    python scripts/view_in_browser.py airimu-demo/demo.rrd --out /tmp/shots
    python scripts/view_in_browser.py demo.rrd --out /tmp/shots --click 1200,60 --click 1300,60

A manual check, not part of the tests (CI has no Chromium): serves the recording with ``rerun --serve-web`` bound
to 127.0.0.1, opens the viewer in Debian's ``chromium`` (``apt-get install chromium``) in headless mode with
software rendering, waits in real time until the wasm viewer has loaded and drawn (about 40 s in software;
``chromium --screenshot`` runs on virtual time and never finishes loading it), and saves screenshots through
Chrome's remote-debugging protocol: ``viewer.png`` after ``--wait`` seconds, then one ``click<i>.png`` after each
``--click X,Y`` (CSS pixels). Both processes are stopped by their PID at the end. Needs nothing outside the
standard library and the installed rerun-sdk (the DevTools websocket is spoken here directly).
"""

from __future__ import annotations

import argparse
import base64
import importlib.util
import json
import os
import shutil
import socket
import struct
import subprocess
import sys
import tempfile
import time
import urllib.parse
import urllib.request
from pathlib import Path

HOST = "127.0.0.1"
# pointer move, press and release in one JavaScript task, so that the viewer sees them in one frame: a software-
# rendered frame takes longer than egui's longest click, and DevTools' input events arrive a frame apart
CLICK_JS = """(() => {
  const canvas = document.querySelector("canvas");
  const at = {clientX: %f, clientY: %f, pointerId: 1, pointerType: "mouse", isPrimary: true, bubbles: true};
  canvas.dispatchEvent(new PointerEvent("pointermove", at));
  canvas.dispatchEvent(new PointerEvent("pointerdown", {...at, button: 0, buttons: 1}));
  canvas.dispatchEvent(new PointerEvent("pointerup", {...at, button: 0, buttons: 0}));
})()"""
CHROMIUM_FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--enable-unsafe-swiftshader",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--hide-scrollbars",
    "--disable-background-timer-throttling",
    "--disable-renderer-backgrounding",
)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording", type=Path, help="an .rrd file")
    parser.add_argument("--out", type=Path, required=True, help="folder for the screenshots")
    parser.add_argument("--wait", type=float, default=60.0, help="seconds to let the viewer load and draw")
    parser.add_argument("--size", default="1600x1000", help="window size in CSS pixels, WxH")
    parser.add_argument("--click", action="append", default=[], help="X,Y to click after loading (repeatable)")
    parser.add_argument("--web-port", type=int, default=0, help="web viewer port (0: a free one)")
    parser.add_argument("--grpc-port", type=int, default=0, help="rerun gRPC port (0: a free one)")
    parser.add_argument("--chromium", default=shutil.which("chromium") or "/usr/bin/chromium")
    args = parser.parse_args()
    if not args.recording.is_file():
        parser.error(f"{args.recording}: no such recording")
    args.out.mkdir(parents=True, exist_ok=True)
    width, height = (int(v) for v in args.size.lower().split("x"))
    web, grpc, debug = args.web_port or _free_port(), args.grpc_port or _free_port(), _free_port()
    server = browser = None
    profile = tempfile.mkdtemp(prefix="airimu-chromium-")
    try:
        server = subprocess.Popen(
            [
                _rerun_binary(),
                "--serve-web",
                "--bind",
                HOST,
                "--web-viewer-port",
                str(web),
                "--port",
                str(grpc),
                "--hide-welcome-screen",
                str(args.recording),
            ],
            stdout=subprocess.DEVNULL,
            stderr=(args.out / "rerun.log").open("w"),
        )
        _wait_for_port(web, 30.0)
        proxy = urllib.parse.quote(f"rerun+http://{HOST}:{grpc}/proxy", safe="")
        url = f"http://{HOST}:{web}/?url={proxy}"
        print(f"rerun (pid {server.pid}) serves {url}")
        browser = subprocess.Popen(
            [
                args.chromium,
                *CHROMIUM_FLAGS,
                f"--user-data-dir={profile}",
                f"--remote-debugging-port={debug}",
                f"--window-size={width},{height}",
                url,
            ],
            stdout=subprocess.DEVNULL,
            stderr=(args.out / "chromium.log").open("w"),
        )
        print(f"chromium (pid {browser.pid}) is loading the viewer; waiting {args.wait:.0f} s")
        page = _DevTools(_page_socket(debug, 30.0))
        page.call("Emulation.setDeviceMetricsOverride", width=width, height=height, deviceScaleFactor=1, mobile=False)
        time.sleep(args.wait)
        shots = [_shot(page, args.out / "viewer.png")]
        for i, xy in enumerate(args.click):
            x, y = (float(v) for v in xy.split(","))
            page.call("Runtime.evaluate", expression=CLICK_JS % (x, y))
            time.sleep(4.0)
            shots.append(_shot(page, args.out / f"click{i + 1}.png"))
        page.close()
        _close_browser(debug)
        for shot in shots:
            print(f"written: {shot}")
        return 0
    finally:
        for name, proc, grace in (("chromium", browser, 10.0), ("rerun", server, 0.0)):
            if proc is not None:
                _stop(proc, name, grace)  # Chromium quits by itself after Browser.close
        shutil.rmtree(profile, ignore_errors=True)


def _rerun_binary() -> str:
    """The viewer binary rerun-sdk installs (``python -m rerun`` would run it as a child that outlives a stopped
    parent), or ``$RERUN_CLI_PATH`` as rerun_cli honours it."""
    if "RERUN_CLI_PATH" in os.environ:
        return os.environ["RERUN_CLI_PATH"]
    spec = importlib.util.find_spec("rerun_cli")
    if spec is None or spec.origin is None:
        raise FileNotFoundError("rerun_cli is not installed: pip install rerun-sdk")
    return str(Path(spec.origin).with_name("rerun"))


def _shot(page: _DevTools, path: Path) -> Path:
    data = page.call("Page.captureScreenshot", format="png")["data"]
    path.write_bytes(base64.b64decode(data))
    return path


def _close_browser(port: int) -> None:
    """Ask Chromium to quit (``Browser.close``), so that it ends its own child processes."""
    with urllib.request.urlopen(f"http://{HOST}:{port}/json/version", timeout=5.0) as response:
        browser = _DevTools(json.load(response)["webSocketDebuggerUrl"])
    try:
        browser.call("Browser.close")
    except ConnectionError:
        pass  # it closed the socket while quitting
    browser.close()


def _stop(proc: subprocess.Popen, name: str, grace: float = 0.0) -> None:
    """Let one process end within ``grace`` s, else terminate it by its PID (killed if still there after 10 s)."""
    try:
        proc.wait(grace)
    except subprocess.TimeoutExpired:
        proc.terminate()
        try:
            proc.wait(10.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    print(f"stopped {name} (pid {proc.pid})")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind((HOST, 0))
        return s.getsockname()[1]


def _wait_for_port(port: int, timeout: float) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        try:
            socket.create_connection((HOST, port), timeout=1.0).close()
            return
        except OSError:
            time.sleep(0.2)
    raise TimeoutError(f"nothing listens on {HOST}:{port} after {timeout:.0f} s")


def _page_socket(port: int, timeout: float) -> str:
    """The DevTools websocket URL of the browser's first page."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        try:
            with urllib.request.urlopen(f"http://{HOST}:{port}/json/list", timeout=2.0) as response:
                pages = [t for t in json.load(response) if t.get("type") == "page"]
            if pages:
                return pages[0]["webSocketDebuggerUrl"]
        except OSError:
            pass
        time.sleep(0.3)
    raise TimeoutError(f"no page on Chromium's debugging port {port} after {timeout:.0f} s")


class _DevTools:
    """A minimal websocket client (RFC 6455: text frames, client-masked) for Chrome's DevTools protocol."""

    def __init__(self, url: str):
        parts = urllib.parse.urlsplit(url)
        self.sock = socket.create_connection((parts.hostname, parts.port), timeout=60.0)
        key = base64.b64encode(os.urandom(16)).decode()
        request = (
            f"GET {parts.path} HTTP/1.1\r\nHost: {parts.hostname}:{parts.port}\r\nUpgrade: websocket\r\n"
            f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n"
        )
        self.sock.sendall(request.encode())
        head = b""
        while b"\r\n\r\n" not in head:
            head += self.sock.recv(1)
        if b" 101 " not in head.split(b"\r\n")[0]:
            raise ConnectionError(f"DevTools refused the websocket: {head.decode(errors='replace')}")
        self.next_id = 0

    def call(self, method: str, **params) -> dict:
        self.next_id += 1
        self._send(json.dumps({"id": self.next_id, "method": method, "params": params}).encode())
        while True:  # events arrive in between; keep the answer to this call
            message = json.loads(self._receive())
            if message.get("id") == self.next_id:
                if "error" in message:
                    raise RuntimeError(f"{method}: {message['error']}")
                return message.get("result", {})

    def close(self) -> None:
        self.sock.close()

    def _send(self, payload: bytes) -> None:
        mask = os.urandom(4)
        n = len(payload)
        header = bytes([0x81]) + (
            bytes([0x80 | n])
            if n < 126
            else bytes([0x80 | 126]) + struct.pack(">H", n)
            if n < 65536
            else bytes([0x80 | 127]) + struct.pack(">Q", n)
        )
        self.sock.sendall(header + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(payload)))

    def _receive(self) -> bytes:
        message = b""
        while True:
            first, second = self._exactly(2)
            n = second & 0x7F
            if n == 126:
                n = struct.unpack(">H", self._exactly(2))[0]
            elif n == 127:
                n = struct.unpack(">Q", self._exactly(8))[0]
            payload = self._exactly(n)
            if first & 0x0F in (0x8, 0x9, 0xA):  # close, ping, pong: nothing to keep
                if first & 0x0F == 0x8:
                    raise ConnectionError("DevTools closed the websocket")
                continue
            message += payload
            if first & 0x80:  # FIN
                return message

    def _exactly(self, n: int) -> bytes:
        data = b""
        while len(data) < n:
            chunk = self.sock.recv(n - len(data))
            if not chunk:
                raise ConnectionError("DevTools websocket closed")
            data += chunk
        return data


if __name__ == "__main__":
    sys.exit(main())
