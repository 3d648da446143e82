"""The live 3-D view (issue 15) in a real browser: Debian's headless Chromium driven by
selenium with the packages' own driver and browser (nothing downloads a driver). Checks that
the scene is drawn, that it follows a slider and new readings, that the numbers carry units,
and that the page asks nothing of any host but 127.0.0.1.

``TENDONSENSE_SCREENSHOTS=DIR`` keeps the screenshots (the manual's figures)."""

import io
import json
import os
import re
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from urllib.parse import urlparse

import numpy as np
import pytest

from conftest import ROOT

CHROMIUM, DRIVER = "/usr/bin/chromium", "/usr/bin/chromedriver"


def _importable(name):
    try:
        __import__(name)
        return True
    except ImportError:
        return False


REASON = ", ".join(w for w, ok in (("viser", _importable("viser")),
                                   ("selenium", _importable("selenium")),
                                   (CHROMIUM, Path(CHROMIUM).exists()),
                                   (DRIVER, Path(DRIVER).exists())) if not ok)
# CI installs all of them (.ci/run): there a missing one is a failure, not a skip
pytestmark = pytest.mark.skipif(bool(REASON) and not os.environ.get("CI"),
                                reason=f"the browser tests need {REASON}")

FLAGS = ["--headless=new", "--no-sandbox", "--use-angle=swiftshader",
         "--enable-unsafe-swiftshader", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--no-first-run",
         "--window-size=1280,800",
         # Chromium's own background traffic (found with the proxy trap below)
         "--disable-features=AutofillServerCommunication,NetworkTimeServiceQuerying,"
         "OptimizationHints,AimEnabled",
         "--gaia-url=http://127.0.0.1:9", "--component-updater=url-source=http://127.0.0.1:9",
         "--gcm-checkin-url=http://127.0.0.1:9", "--gcm-registration-url=http://127.0.0.1:9",
         "--gcm-mcs-endpoint=http://127.0.0.1:9"]
PREFS = {"session.restore_on_startup": 4, "session.startup_urls": ["about:blank"]}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class ProxyTrap:
    """Chromium's proxy: loopback bypasses it, so any connection here is a request for a host
    other than this machine (workers and websockets included). Nothing is forwarded."""

    def __init__(self):
        self.sock = socket.create_server(("127.0.0.1", 0))
        self.port, self.hits = self.sock.getsockname()[1], []
        threading.Thread(target=self._run, daemon=True).start()

    def _run(self):
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            conn.settimeout(1)
            try:
                self.hits.append(conn.recv(200).split(b"\r\n")[0])
            except OSError:
                self.hits.append(b"?")
            conn.close()


def wait_for(pred, timeout=90.0, every=0.25):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        out = pred()
        if out:
            return out
        time.sleep(every)
    raise AssertionError("timed out")


def backbone_pixels(driver) -> np.ndarray:
    from PIL import Image
    img = Image.open(io.BytesIO(driver.get_screenshot_as_png())).convert("RGB")
    r, g, b = np.asarray(img).astype(int).transpose(2, 0, 1)
    return (r > 190) & (g > 80) & (g < 190) & (b < 110) & (r - g > 50)  # (230, 110, 0) lit


@pytest.fixture
def driver(monkeypatch, tmp_path_factory):
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service
    from selenium.webdriver.common.selenium_manager import SeleniumManager

    def no_manager(*a, **k):
        raise AssertionError("selenium-manager must not run (it would download a driver)")

    monkeypatch.setattr(SeleniumManager, "binary_paths", no_manager)
    trap = ProxyTrap()
    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for f in FLAGS + [f"--user-data-dir={tmp_path_factory.mktemp('chrome')}",
                      f"--proxy-server=http://127.0.0.1:{trap.port}"]:
        opts.add_argument(f)
    opts.add_experimental_option("prefs", PREFS)
    opts.set_capability("goog:loggingPrefs", {"performance": "ALL", "browser": "ALL"})
    d = webdriver.Chrome(service=Service(executable_path=DRIVER), options=opts)
    d.trap = trap
    yield d
    d.quit()
    trap.sock.close()


def start(args, stdin=None):
    port = free_port()
    p = subprocess.Popen([sys.executable, "-m", "tendonsense.cli", *args, "--port", str(port)],
                         stdin=stdin, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         text=True, cwd=ROOT)
    err = []
    threading.Thread(target=lambda: err.extend(p.stderr), daemon=True).start()
    wait_for(lambda: any("view at http://127.0.0.1" in line for line in err)
             or p.poll() is not None)
    assert p.poll() is None, "".join(err)
    return p, port, err


def open_page(d, port):
    from selenium.webdriver.common.by import By
    d.get(f"http://127.0.0.1:{port}/")
    wait_for(lambda: backbone_pixels(d).sum() > 300)
    for b in d.find_elements(By.CSS_SELECTOR, ".mantine-Notification-closeButton"):
        b.click()  # "software WebGL rendering" notice
    time.sleep(0.5)


def text(d) -> str:
    from selenium.webdriver.common.by import By
    return d.find_element(By.TAG_NAME, "body").text


def keep(d, name):
    folder = os.environ.get("TENDONSENSE_SCREENSHOTS")
    if folder:
        d.save_screenshot(str(Path(folder) / name))


def only_this_machine(d, port):
    urls = []
    for e in d.get_log("performance"):
        msg = json.loads(e["message"])["message"]
        if msg["method"] in ("Network.requestWillBeSent", "Network.webSocketCreated"):
            urls.append(msg["params"].get("request", {}).get("url") or msg["params"]["url"])
    net = [u for u in urls if urlparse(u).scheme in ("http", "https", "ws", "wss")]
    assert net and all(urlparse(u).hostname == "127.0.0.1" for u in net), net
    console = " ".join(e["message"] for e in d.get_log("browser"))
    assert f"ws://127.0.0.1:{port}" in console  # the websocket, opened in a web worker
    assert d.trap.hits == [], d.trap.hits


def test_view_explores_forward_statics(driver):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.keys import Keys
    p, port, err = start(["view", "examples/paper_prototype.toml"])
    try:
        open_page(driver, port)
        wait_for(lambda: re.search(r"tip: -?\d+\.\d, -?\d+\.\d, -?\d+\.\d mm", text(driver)))
        assert "t1 0.000 N" in text(driver)
        time.sleep(0.5)
        before = backbone_pixels(driver)
        thumb = driver.find_elements(By.CSS_SELECTOR, "[role=slider]")[0]  # tension t1
        driver.execute_script("arguments[0].focus()", thumb)
        thumb.send_keys(Keys.END)
        wait_for(lambda: "t1 5.000 N" in text(driver))
        after = wait_for(lambda: (m := backbone_pixels(driver)).sum() > 300
                         and (m != before).sum() > 300 and [m])
        assert re.search(r"length changes: t1 -\d+\.\d+ mm", text(driver))
        keep(driver, "view_explore.png")
        assert after
        only_this_machine(driver, port)
    finally:
        p.terminate()
        p.wait(timeout=30)


def test_estimate_view_follows_a_live_stream(driver):
    p, port, err = start(["estimate", "examples/paper_prototype.toml", "--readings", "-",
                          "--unknown", "0.25,0,0,-1", "--view"], stdin=subprocess.PIPE)
    out = []
    threading.Thread(target=lambda: out.extend(p.stdout), daemon=True).start()
    try:
        p.stdin.write("time,tension_t1,tension_t2,tension_t3,displacement_t1\n"
                      "0.0,1.0,0,0,-0.001\n")
        p.stdin.flush()
        wait_for(lambda: len(out) >= 2)
        open_page(driver, port)
        wait_for(lambda: re.search(r"F1 = \d+\.\d+ ± \d+\.\d+ N at X = 250\.0 mm",
                                   text(driver)))
        assert "the last 10 s" not in text(driver)  # one sample: no empty time plot
        keep(driver, "view_first_sample.png")
        before = backbone_pixels(driver)
        p.stdin.write("0.1,3.0,0,0,-0.006\n")
        p.stdin.flush()
        wait_for(lambda: len(out) >= 3)
        wait_for(lambda: "t1 3.000 N" in text(driver))
        wait_for(lambda: (backbone_pixels(driver) != before).sum() > 300)
        assert "samples/s" in text(driver)
        wait_for(lambda: "the last 10 s" in text(driver))
        keep(driver, "view_estimate.png")
        p.stdin.write("0.2,-1.0,0,0,-0.006\n")  # a tendon cannot push: refused, and shown so
        p.stdin.flush()
        wait_for(lambda: "SAMPLE REFUSED" in text(driver) and "negative" in text(driver))
        p.stdin.write("0.3,2.0,0,0,-0.004\n")  # the next one is drawn, the refusal still marked
        p.stdin.flush()
        wait_for(lambda: "t1 2.000 N" in text(driver))
        assert re.search(r"s ago a sample was refused or did not converge: .*negative",
                         text(driver))
        assert out[0].startswith("row,time,magnitude_1") and "skipped" in out[-2]
        only_this_machine(driver, port)
    finally:
        p.stdin.close()
        p.terminate()
        p.wait(timeout=30)


def test_a_taken_port_is_refused_clearly():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        r = subprocess.run([sys.executable, "-m", "tendonsense.cli", "view",
                            "examples/paper_prototype.toml", "--port", str(port)],
                           capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert r.returncode == 1 and not r.stdout
    assert f"cannot serve the view on 127.0.0.1:{port}" in r.stderr


def test_a_host_that_cannot_be_served_is_one_line():
    """An address that is no host: its error alone (a warning that the view was served to
    the network came first)."""
    r = subprocess.run([sys.executable, "-m", "tendonsense.cli", "view",
                        "examples/paper_prototype.toml", "--host", "999.1.1.1"],
                       capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert r.returncode == 1 and not r.stdout
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(
        "tendonsense view: error: cannot serve the view on 999.1.1.1:8080: "), r.stderr


def test_a_tendons_colour_follows_its_tension_along_it():
    """Each segment of a tendon in the scene takes its own tension (eq. 10, as the shape
    figures): pulled in the colour fades from the actuator's (the reddest) toward the anchor,
    paid out it grows, stuck it is one colour; the anchor's segment at T exp(∓μψ)."""
    from tendonsense import load_robot
    from tendonsense.forward import solve
    from tendonsense.tendons import turning_along
    from tendonsense.view import Shown, Viewer
    robot = load_robot(ROOT / "examples" / "paper_prototype.toml")
    result = solve(robot, {"t1": 2.0})
    viewer = Viewer(robot, 0)
    try:
        shown = viewer._shown(result, None, (), (), None, "", time.monotonic())[0]
        for sign in (1.0, -1.0, 0.0):
            viewer.draw(Shown(shown.q, shown.tensions, signs=np.array([sign, 1.0, 1.0])))
            red = viewer.tendons[0].colors[:, 0, 0].astype(float)
            path = viewer.tendons[0].points
            psi = turning_along(np.concatenate([path[:, 0], path[-1:, 1]]),
                                path[0, 1] - path[0, 0])
            share = np.exp(-sign * robot.tendons[0].friction * (psi - psi.max() * (sign < 0)))
            assert np.allclose(red, (40 + 215 * share).astype(int), atol=1), (sign, red)
            if sign:
                assert np.all(np.sign(np.diff(red)) * sign <= 0) and np.ptp(red) > 30
            else:
                assert np.ptp(red) == 0
    finally:
        viewer.close()
