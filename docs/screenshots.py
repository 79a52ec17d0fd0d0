"""Screenshots of recordings in the real Rerun web viewer, taken in headless Chromium (docs/screenshots/).

    python docs/screenshots.py OUT/recording.rrd docs/screenshots/NAME.png [--wait 40]
    python docs/screenshots.py VIDEO docs/screenshots/live.png --live [--wait 40]

Serves the recording with `moseg view --web` (free ports), or with `--live` runs `moseg live VIDEO
--realtime --serve` and shots it while it runs; opens the printed address in headless Chromium
(software WebGL: SwiftShader) driven over the DevTools protocol on a pipe (no extra packages), waits in
real time for the viewer to load and draw, and saves a PNG of the page. Needs Debian's `chromium` (or
`--chromium PATH`); it is a documentation tool, not part of the package or the tests.
"""

from __future__ import annotations

import argparse
import base64
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any


class DevTools:
    """Chromium's DevTools protocol over `--remote-debugging-pipe` (fd 3 in, fd 4 out, NUL-terminated JSON)."""

    def __init__(self, chromium: str, width: int, height: int) -> None:
        to_child_r, self._to_child = os.pipe()
        self._from_child, from_child_w = os.pipe()

        def move_pipes() -> None:  # in the child: the pipe ends at the fds Chromium reads and writes
            r, w = os.dup(to_child_r), os.dup(from_child_w)  # above 4 (0-4 are taken), so no overwriting
            os.dup2(r, 3)
            os.dup2(w, 4)

        self.proc = subprocess.Popen(
            [
                chromium,
                "--headless=new",
                "--remote-debugging-pipe",
                "--no-sandbox",
                "--no-first-run",
                "--use-angle=swiftshader",
                "--enable-unsafe-swiftshader",
                "--ignore-gpu-blocklist",
                f"--window-size={width},{height}",
                "--hide-scrollbars",
                "about:blank",
            ],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            preexec_fn=move_pipes,
            close_fds=False,  # the fds closing runs after preexec_fn and would close 3 and 4
        )
        os.close(to_child_r)
        os.close(from_child_w)
        self._buffer = b""
        self._next_id = 0

    def call(self, method: str, session: str | None = None, **params: Any) -> dict[str, Any]:
        self._next_id += 1
        message: dict[str, Any] = {"id": self._next_id, "method": method, "params": params}
        if session is not None:
            message["sessionId"] = session
        os.write(self._to_child, json.dumps(message).encode() + b"\0")
        while True:
            while b"\0" not in self._buffer:
                chunk = os.read(self._from_child, 1 << 20)
                if not chunk:
                    raise RuntimeError(f"Chromium closed the DevTools pipe during {method}")
                self._buffer += chunk
            raw, self._buffer = self._buffer.split(b"\0", 1)
            reply = json.loads(raw)
            if reply.get("id") == self._next_id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return dict(reply.get("result", {}))

    def close(self) -> None:
        self.proc.terminate()
        self.proc.wait(timeout=10)


def screenshot(url: str, out: Path, wait_s: float, chromium: str, width: int, height: int) -> None:
    tools = DevTools(chromium, width, height)
    try:
        target = tools.call("Target.createTarget", url="about:blank")["targetId"]
        session = tools.call("Target.attachToTarget", targetId=target, flatten=True)["sessionId"]
        tools.call(
            "Emulation.setDeviceMetricsOverride", session, width=width, height=height, deviceScaleFactor=1, mobile=False
        )
        tools.call("Page.enable", session)
        tools.call("Page.navigate", session, url=url)
        time.sleep(wait_s)  # the viewer loads its wasm, fetches the data and draws: real time, not virtual time
        data = tools.call("Page.captureScreenshot", session, format="png")["data"]
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_bytes(base64.b64decode(data))
    finally:
        tools.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("recording", type=Path, help="a .rrd file, or with --live a video played in real time")
    parser.add_argument("png", type=Path)
    parser.add_argument("--wait", type=float, default=40.0, help="seconds to let the viewer load and draw")
    parser.add_argument("--live", action="store_true", help="run `moseg live RECORDING --realtime --serve`")
    parser.add_argument("--chromium", default="chromium")
    parser.add_argument("--size", default="1600x1000", help="page size, WIDTHxHEIGHT")
    parser.add_argument("--renderer", default="webgl", help="the viewer's renderer (webgl under SwiftShader)")
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.split("x"))
    if args.live:
        command = ["moseg", "live", str(args.recording), "--realtime", "--serve"]
    else:
        command = ["moseg", "view", "--web", "--web-port", "0", str(args.recording)]
    viewer = subprocess.Popen(
        command,
        stdout=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    try:
        assert viewer.stdout is not None
        found = None
        for line in viewer.stdout:  # moseg live prints a line or two before the address
            found = re.search(r"(http://\S+/\?url=\S+)", line)
            if found is not None:
                break
        if found is None:
            sys.exit(f"{' '.join(command[:2])} ended without printing an address")
        url = f"{found.group(1)}&renderer={args.renderer}"
        screenshot(url, args.png, args.wait, args.chromium, width, height)
        print(f"{args.png}: {url}")
    finally:
        os.killpg(viewer.pid, signal.SIGTERM)
        viewer.wait(timeout=10)


if __name__ == "__main__":
    main()
