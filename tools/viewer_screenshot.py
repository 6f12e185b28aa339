"""Open `lumos3d view` in headless Chromium and save a screenshot (for the docs; not a test).

Starts the viewer on a free port, drives Chromium through the DevTools protocol (navigate, wait
for the splats to load and sort, capture), then stops both. WebGL runs on SwiftShader, Chromium's
CPU renderer, so no GPU or display is needed (Debian: `apt-get install chromium`).

    .venv/bin/python tools/viewer_screenshot.py /tmp/viewdemo -o docs/images/viewer.jpg
    .venv/bin/python tools/viewer_screenshot.py scene.ply -o shot.png --size 1600x1000 --wait 300
"""

from __future__ import annotations

import argparse
import json
import shutil
import socket
import subprocess
import tempfile
import time
import urllib.request
from base64 import b64decode
from pathlib import Path

import cv2
import numpy as np
from websockets.sync.client import connect

from lumos3d_cli.viewer.server import start_viewer

# Headless without a GPU, sandbox or network side traffic; a fresh profile per run.
_CHROMIUM_FLAGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    # WebGL through SwiftShader. Chromium 156 falls back to it by itself (checked: WebGL2 on
    # "SwiftShader Device" with or without these flags); they keep working once that implicit
    # fallback is removed, as Chromium has announced.
    "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
]


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def _page_socket_url(debug_port: int, timeout: float = 30.0) -> str:
    """The DevTools websocket of Chromium's first page, once Chromium answers."""
    deadline = time.time() + timeout
    while True:
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{debug_port}/json", timeout=5) as response:
                pages = [t for t in json.load(response) if t.get("type") == "page"]
            if pages:
                return pages[0]["webSocketDebuggerUrl"]
        except OSError:
            pass
        if time.time() > deadline:
            raise RuntimeError(f"Chromium's DevTools did not answer on port {debug_port} within {timeout} s")
        time.sleep(0.5)


class DevTools:
    """A minimal DevTools protocol client: one call at a time, events skipped."""

    def __init__(self, url: str) -> None:
        self.socket = connect(url, max_size=None)
        self.next_id = 0

    def call(self, method: str, **params) -> dict:
        self.next_id += 1
        self.socket.send(json.dumps({"id": self.next_id, "method": method, "params": params}))
        while True:
            reply = json.loads(self.socket.recv(timeout=120))
            if reply.get("id") == self.next_id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply.get("result", {})

    def close(self) -> None:
        self.socket.close()


def _capture(tools: DevTools) -> np.ndarray:
    data = tools.call("Page.captureScreenshot", format="png")["data"]
    return cv2.imdecode(np.frombuffer(b64decode(data), np.uint8), cv2.IMREAD_COLOR)


def screenshot(url: str, size: tuple[int, int], wait: float, chromium: str) -> np.ndarray:
    """[H, W, 3] uint8 BGR screenshot of `url` once two captures 10 s apart agree (SwiftShader
    needs a minute or more to fade in and sort a few hundred thousand splats), or after `wait` s."""
    debug_port = _free_port()
    profile = tempfile.mkdtemp(prefix="lumos3d-chromium-")
    try:
        process = subprocess.Popen(
            [chromium, *_CHROMIUM_FLAGS, f"--user-data-dir={profile}", f"--remote-debugging-port={debug_port}",
             f"--window-size={size[0]},{size[1]}", "about:blank"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )
    except OSError:  # no such browser: its profile folder goes with the run
        shutil.rmtree(profile, ignore_errors=True)
        raise
    try:
        tools = DevTools(_page_socket_url(debug_port))
        try:
            tools.call("Emulation.setDeviceMetricsOverride", width=size[0], height=size[1], deviceScaleFactor=1, mobile=False)
            tools.call("Page.navigate", url=url)
            started, previous = time.time(), None
            while True:
                time.sleep(10)
                # The page warns that WebGL runs in software (SwiftShader): true here, not for users.
                tools.call("Runtime.evaluate", expression="document.querySelectorAll('[class*=Notification-root]')"
                           ".forEach(element => element.remove())")
                image = _capture(tools)
                settled = previous is not None and np.abs(image.astype(np.int16) - previous).mean() < 0.5
                if settled or time.time() - started > wait:
                    break
                previous = image
        finally:
            tools.close()
    finally:
        process.terminate()
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
        shutil.rmtree(profile, ignore_errors=True)
    return image


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene", type=Path, help="restore output folder or .ply")
    parser.add_argument("-o", "--output", type=Path, required=True, help=".png or .jpg")
    parser.add_argument("--size", default="1280x800", help="window size WxH")
    parser.add_argument("--wait", type=float, default=180.0, help="at most this many seconds for the page to settle")
    parser.add_argument("--max-splats", type=int, default=1_000_000)
    parser.add_argument("--chromium", default="chromium", help="Chromium executable")
    parser.add_argument("--jpeg-quality", type=int, default=85)
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.lower().split("x"))
    viewer = start_viewer(args.scene, port=0, max_splats=args.max_splats)
    try:
        image = screenshot(viewer.url, (width, height), args.wait, args.chromium)
    finally:
        viewer.stop()
    args.output.parent.mkdir(parents=True, exist_ok=True)
    options = [cv2.IMWRITE_JPEG_QUALITY, args.jpeg_quality] if args.output.suffix.lower() in (".jpg", ".jpeg") else []
    cv2.imwrite(str(args.output), image, options)
    print(f"wrote {args.output} ({image.shape[1]}x{image.shape[0]}, {args.output.stat().st_size // 1024} KB)")


if __name__ == "__main__":
    main()
