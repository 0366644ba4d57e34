"""Screenshot of the live view in a real Foxglove viewer: docs/img/live.png (docs/live.md).

    python tools/live_screenshot.py [--out docs/img/live.png] [--wait 45] [--size 1600x1000]

Runs ``hil run --live 0`` (the paper's circle) and opens it in Foxglove Studio 1.48.0, the last
Foxglove Studio whose web build is published (npm ``@foxglove/studio-base``, MPL-2.0), served
from a local folder to headless Chromium, with the layout docs/live-layout-lichtblick.json.
After ``--wait`` seconds of live data it saves the page through Chromium's DevTools protocol,
then stops Chromium, the run and the file server. Everything stays on 127.0.0.1.

The viewer is fetched once with ``npm pack`` into ``--viewer`` (default
/tmp/hil-foxglove-studio, outside the repository). One line of it is changed: Studio 1.48's
client offers the WebSocket subprotocol ``foxglove.websocket.v1`` and checks the server's
answer against it, while foxglove-sdk 0.30 accepts only the protocol's new name
``foxglove.sdk.v1`` (docs/live.md, *Protocol name*); the messages are the same. Dev tool only:
needs npm and a ``chromium`` binary; no test or CI step runs it.
"""

from __future__ import annotations

import argparse
import base64
import contextlib
import functools
import json
import re
import shutil
import signal
import socket
import subprocess
import sys
import tarfile
import tempfile
import threading
import time
import urllib.request
from collections.abc import Iterator
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import ClassVar

from websockets.sync.client import connect

ROOT = Path(__file__).resolve().parents[1]
LAYOUT = ROOT / "docs" / "live-layout-lichtblick.json"
PACKAGES = ("@foxglove/studio-base@1.48.0", "react@17.0.2", "react-dom@17.0.2")
VIEWER = "Foxglove Studio 1.48.0"
OLD_NAME = 'FoxgloveClient.SUPPORTED_SUBPROTOCOL = "foxglove.websocket.v1";'
NEW_NAME = 'FoxgloveClient.SUPPORTED_SUBPROTOCOL = "foxglove.sdk.v1";'

INDEX_HTML = """<!doctype html>
<html><head><meta charset="utf-8"><title>Foxglove Studio</title>
<style>html, body, #root { height: 100%; margin: 0; }</style></head>
<body><div id="root"></div>
<script src="react.production.min.js"></script>
<script src="react-dom.production.min.js"></script>
<script>window.react = React; window["react-dom"] = ReactDOM;</script>
<script src="assets/index.js"></script>
<script src="main.js"></script>
</body></html>
"""

# Studio's App with an in-memory settings store and a layout store holding layout.json;
# the URL's ds / ds.url / layoutId open the connection and select that layout, as in
# studio.foxglove.dev's own links.
MAIN_JS = """(async () => {
  const layout = await (await fetch("layout.json")).json();
  const settings = new Map(Object.entries({
    colorScheme: "light", timezone: "UTC", "telemetry.telemetryEnabled": false,
    "telemetry.crashReportingEnabled": false, launchPreference: "web",
    hideSignInPrompt: true, "ui.open-dialog-startup": false,
  }));
  const appConfiguration = {
    get: (k) => settings.get(k),
    set: async (k, v) => { settings.set(k, v); },
    addChangeListener() {}, removeChangeListener() {},
  };
  const now = new Date().toISOString();
  const layouts = new Map([["hil-live", {
    id: "hil-live", name: "hil live view", permission: "CREATOR_WRITE",
    baseline: { data: layout, savedAt: now }, working: undefined, syncInfo: undefined,
  }]]);
  const layoutStorage = {
    list: async () => [...layouts.values()],
    get: async (_ns, id) => layouts.get(id),
    put: async (_ns, l) => { layouts.set(l.id, l); return l; },
    delete: async (_ns, id) => { layouts.delete(id); },
    importLayouts: async () => {},
  };
  // The 3D panel's one-time "open settings" hint, as dismissed by a user.
  localStorage.setItem("studio.profile-data",
    JSON.stringify({ onboarding: { settingsTooltipShownForPanelTypes: ["3D"] } }));
  await self.initI18n();
  ReactDOM.render(
    React.createElement(self.App, {
      deepLinks: [location.href], appConfiguration, layoutStorage, extensionLoaders: [],
      dataSources: [new self.FoxgloveWebSocketDataSourceFactory()],
      enableGlobalCss: true, enableLaunchPreferenceScreen: false,
    }),
    document.getElementById("root"),
  );
})();
"""


# The sidebar's Topics tab (Studio opens Problems by itself when a channel has one).
SHOW_TOPICS = """[...document.querySelectorAll('[role=tab]')]
  .filter((tab) => tab.innerText.trim() === 'Topics').forEach((tab) => tab.click())"""


def prepare_viewer(folder: Path) -> None:
    """Studio's web bundle, React 17 and the page above in ``folder`` (npm once)."""
    bundle = folder / "assets" / "index.js"
    if not bundle.exists():
        npm = shutil.which("npm") or sys.exit("needs npm")
        with tempfile.TemporaryDirectory() as tmp:
            subprocess.run([npm, "pack", "--silent", *PACKAGES], cwd=tmp, check=True,
                           stdout=subprocess.DEVNULL)  # fmt: skip
            for tgz in Path(tmp).glob("*.tgz"):
                with tarfile.open(tgz) as tar:
                    tar.extractall(Path(tmp) / tgz.stem, filter="data")
            pkg = {p.name: p / "package" for p in Path(tmp).iterdir() if p.is_dir()}
            folder.mkdir(parents=True, exist_ok=True)
            shutil.copytree(pkg["foxglove-studio-base-1.48.0"] / "assets", folder / "assets",
                            dirs_exist_ok=True)  # fmt: skip
            for name in ("react", "react-dom"):
                umd = pkg[f"{name}-17.0.2"] / "umd" / f"{name}.production.min.js"
                shutil.copy(umd, folder)
    text = bundle.read_text()
    if text.count(OLD_NAME) == 1:
        bundle.write_text(text.replace(OLD_NAME, NEW_NAME))
    elif text.count(NEW_NAME) != 1:
        sys.exit(f"{bundle}: the client's subprotocol line is not where it was")
    (folder / "index.html").write_text(INDEX_HTML)
    (folder / "main.js").write_text(MAIN_JS)
    shutil.copy(LAYOUT, folder / "layout.json")


@contextlib.contextmanager
def serve(folder: Path) -> Iterator[int]:
    """A static file server for ``folder`` on 127.0.0.1; yields its port."""
    handler = functools.partial(_Quiet, directory=str(folder))
    server = ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield server.server_address[1]
    finally:
        server.shutdown()
        server.server_close()
        thread.join()


class _Quiet(SimpleHTTPRequestHandler):
    extensions_map: ClassVar[dict[str, str]] = {
        **SimpleHTTPRequestHandler.extensions_map,
        ".wasm": "application/wasm",
    }

    def log_message(self, format: str, *args: object) -> None:
        pass


@contextlib.contextmanager
def live_run(folder: Path, port: int, duration: float) -> Iterator[str]:
    """``hil run --live PORT`` in ``folder``; yields the ws:// address, stops the run by PID."""
    cmd = [sys.executable, "-m", "hil", "run", "--live", str(port), "--duration",
           f"{duration:g}", "--quiet", "--no-report", "--out", str(folder / "run")]  # fmt: skip
    err = (folder / "run.stderr").open("w+")
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err, cwd=ROOT)
    try:
        deadline = time.monotonic() + 120
        while (url := _url_in(folder / "run.stderr")) is None:
            if proc.poll() is not None or time.monotonic() > deadline:
                sys.exit("hil run --live did not start: " + (folder / "run.stderr").read_text())
            time.sleep(0.2)
        yield url
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        err.close()


def _url_in(log: Path) -> str | None:
    found = re.search(r"live view: (ws://127\.0\.0\.1:\d+)", log.read_text())
    return found.group(1) if found else None


@contextlib.contextmanager
def chromium(folder: Path, width: int, height: int) -> Iterator[str]:
    """Headless Chromium with software WebGL (the 3D panel); yields its DevTools address."""
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    if browser is None:
        sys.exit("no chromium binary (Debian: apt install chromium)")
    profile = folder / "profile"
    # niced: the bench's services come first on this machine, as on a user's bench host
    cmd = ["nice", "-n", "10", browser, "--headless", "--no-sandbox", "--use-angle=swiftshader",
           "--enable-unsafe-swiftshader", "--hide-scrollbars", "--remote-debugging-port=0",
           "--remote-debugging-address=127.0.0.1", f"--user-data-dir={profile}",
           f"--window-size={width},{height}", "about:blank"]  # fmt: skip
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        active = profile / "DevToolsActivePort"
        deadline = time.monotonic() + 60
        while not (active.exists() and active.read_text().count("\n") >= 1):
            if proc.poll() is not None or time.monotonic() > deadline:
                sys.exit("chromium did not start")
            time.sleep(0.2)
        yield f"127.0.0.1:{active.read_text().split()[0]}"
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


class Page:
    """One tab driven over the DevTools protocol."""

    def __init__(self, devtools: str) -> None:
        with urllib.request.urlopen(f"http://{devtools}/json/list", timeout=10) as resp:
            tab = next(t for t in json.load(resp) if t["type"] == "page")
        self._ws = connect(
            tab["webSocketDebuggerUrl"], max_size=None, open_timeout=10, ping_interval=None
        )
        self._ws.__enter__()  # closed by close()
        self._next = 0

    def call(self, method: str, **params: object) -> dict:
        self._next += 1
        self._ws.send(json.dumps({"id": self._next, "method": method, "params": params}))
        while True:
            reply = json.loads(self._ws.recv(timeout=60))
            if reply.get("id") == self._next:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply.get("result", {})

    def wait_for(self, expression: str, timeout: float) -> None:
        """Until the JavaScript ``expression`` is true in the page."""
        deadline = time.monotonic() + timeout
        while not self.call("Runtime.evaluate", expression=expression)["result"].get("value"):
            if time.monotonic() > deadline:
                sys.exit(f"the viewer did not load within {timeout:g} s ({expression})")
            time.sleep(0.5)

    def close(self) -> None:
        self._ws.close()


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def shoot(out: Path, viewer: Path, wait: float, width: int, height: int) -> str:
    """Runs everything above and writes ``out``; returns the viewer's URL.

    The viewer loads first (its 56 MB bundle would otherwise compete with the starting run),
    retrying the connection every 3 s as it does; then the run starts on the port it tries."""
    prepare_viewer(viewer)
    port = free_port()
    with (
        tempfile.TemporaryDirectory(prefix="hil-shot-") as tmp,
        serve(viewer) as http_port,
        chromium(Path(tmp), width, height) as devtools,
    ):
        url = (f"http://127.0.0.1:{http_port}/index.html?ds=foxglove-websocket"
               f"&ds.url=ws://127.0.0.1:{port}&layoutId=hil-live")  # fmt: skip
        page = Page(devtools)
        try:
            page.call("Emulation.setDeviceMetricsOverride", width=width, height=height,
                      deviceScaleFactor=1, mobile=False)  # fmt: skip
            page.call("Page.enable")
            page.call("Page.navigate", url=url)
            page.wait_for("document.body.innerText.includes('Data source')", 120)
            time.sleep(5)
            with live_run(Path(tmp), port, duration=wait + 120):
                time.sleep(wait)
                page.call("Runtime.evaluate", expression=SHOW_TOPICS)
                time.sleep(3)  # the topics' rates, measured anew
                shot = page.call("Page.captureScreenshot", format="png")
        finally:
            page.close()
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_bytes(base64.b64decode(shot["data"]))
    return url


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=ROOT / "docs" / "img" / "live.png")
    p.add_argument("--viewer", type=Path, default=Path("/tmp/hil-foxglove-studio"))
    p.add_argument("--wait", type=float, default=45.0, help="s of live data before the shot")
    p.add_argument("--size", default="1600x1000", help="window WIDTHxHEIGHT in px")
    a = p.parse_args(argv)
    width, height = (int(v) for v in a.size.split("x"))
    url = shoot(a.out, a.viewer, a.wait, width, height)
    print(f"{a.out}: {VIEWER} at {url}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
