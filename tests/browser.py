"""Headless Chromium for the tests (WebGL2 on SwiftShader), and a loopback HTTP server for pages that load
ES modules (three.js), which Chromium does not load from file URLs."""

from __future__ import annotations

import contextlib
import http.server
import os
import shutil
import socketserver
import tempfile
import threading
import time
from pathlib import Path

import pytest

#: Chromium flags: headless as root, software WebGL2 (SwiftShader through ANGLE), nothing from the network.
CHROMIUM_FLAGS = ["--headless=new", "--no-sandbox", "--disable-gpu", "--use-gl=angle", "--use-angle=swiftshader",
                  "--enable-unsafe-swiftshader", "--disable-background-networking", "--disable-component-update",
                  "--disable-sync", "--no-first-run", "--disable-extensions", "--window-size=1200,900"]


def missing(msg: str):
    """Fail under CI (which installs everything), skip elsewhere."""
    if os.environ.get("CI"):
        pytest.fail(msg)
    pytest.skip(msg)


@contextlib.contextmanager
def chromium():
    """A selenium-driven headless Chromium that records the browser console."""
    try:
        from selenium import webdriver
        from selenium.webdriver.chrome.service import Service
    except ImportError:
        missing("selenium is not installed (pip install selenium; the dev extra)")
    binary = shutil.which("chromium") or shutil.which("chromium-browser")
    driver_exe = shutil.which("chromedriver")
    if not binary or not driver_exe:
        missing("chromium / chromedriver are not installed (Debian chromium chromium-driver; make system-packages)")
    opts = webdriver.ChromeOptions()
    opts.binary_location = binary
    profile = tempfile.mkdtemp(prefix="homofac-chromium-")
    for a in CHROMIUM_FLAGS + [f"--user-data-dir={profile}"]:
        opts.add_argument(a)
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(service=Service(driver_exe), options=opts)
    driver.set_script_timeout(300)
    try:
        yield driver
    finally:
        driver.quit()
        shutil.rmtree(profile, ignore_errors=True)


@contextlib.contextmanager
def serve(roots: dict[str, Path]):
    """An HTTP server on 127.0.0.1 (a free port) serving each ``roots`` prefix ("/" last) from its folder;
    yields its base URL."""
    order = sorted(roots.items(), key=lambda kv: -len(kv[0]))

    class Handler(http.server.SimpleHTTPRequestHandler):
        def translate_path(self, path):
            path = path.split("?", 1)[0].split("#", 1)[0]
            for prefix, folder in order:
                if path.startswith(prefix):
                    rel = Path(path[len(prefix):].lstrip("/"))
                    if ".." in rel.parts:
                        return str(Path(folder) / "__refused__")
                    return str(Path(folder) / rel)
            return str(Path(order[-1][1]) / "__refused__")

        def log_message(self, *args):
            pass

    server = socketserver.ThreadingTCPServer(("127.0.0.1", 0), Handler)
    server.daemon_threads = True
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}"
    finally:
        server.shutdown()
        server.server_close()


def console_problems(log) -> list[str]:
    """Console errors and WebGL warnings about invalid calls (not SwiftShader's ReadPixels performance note,
    nor the favicon a page without one is asked for)."""
    return [e["message"] for e in log if (e["level"] == "SEVERE" and "favicon.ico" not in e["message"])
            or "GL_INVALID" in e["message"] or "WebGL:" in e["message"]]


def wait_for(browser, name: str, tries: int = 600) -> tuple[object, list]:
    """Poll the page's ``window[name]`` every 0.1 s until it is set or the console reports a problem; the
    value (None when it never came) and the console log."""
    log: list = []
    state = None
    for _ in range(tries):
        state = browser.execute_script(f"return window.{name} || null")
        log += browser.get_log("browser")
        if state or console_problems(log):
            break
        time.sleep(0.1)
    return state, log + browser.get_log("browser")

