"""The live 3-D view (issue 15): the Python side of one view update, and the CLI stream's row
round trip with ``--view`` against the same stream without it: nobody watching, a client that
draws elsewhere, and a headless Chromium on this machine (software WebGL: each frame costs it
tens of ms of CPU, on the same 2 cores).

    python benchmarks/view.py [--rows 1000] [--runs 4]

Needs viser, selenium and Debian's chromium + chromium-driver (as the tests do).
"""

from __future__ import annotations

import argparse
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
ROBOT = ROOT / "examples" / "paper_prototype.toml"
sys.path.insert(0, str(ROOT / "tests"))


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def browser(port):
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service
    from test_view import FLAGS, PREFS
    opts = webdriver.ChromeOptions()
    opts.binary_location = "/usr/bin/chromium"
    for f in FLAGS + [f"--user-data-dir={tempfile.mkdtemp()}"]:
        opts.add_argument(f)
    opts.add_experimental_option("prefs", PREFS)
    d = webdriver.Chrome(service=Service(executable_path="/usr/bin/chromedriver"), options=opts)
    d.get(f"http://127.0.0.1:{port}/")
    time.sleep(3)
    return d


class Socket:
    """A client that takes every message of the view and draws nothing: a browser on another
    machine, as seen from this one."""

    def __init__(self, port):
        import viser
        from websockets.sync.client import connect
        import msgspec
        from viser._messages import ViewerCameraMessage
        self.ws = connect(f"ws://127.0.0.1:{port}", subprotocols=[f"viser-v{viser.__version__}"],
                          max_size=None)
        # viser counts a client from its first camera pose (as a browser sends it)
        camera = ViewerCameraMessage((1.0, 0, 0, 0), (0.5, 0.5, 0.5), 1.0, 1e-3, 10.0, 800, 1280,
                                     (0.0, 0.0, 0.0), (0.0, 0.0, 1.0))
        self.ws.send(msgspec.msgpack.encode(camera.as_serializable_dict()))
        self.bytes = 0
        threading.Thread(target=self._drain, daemon=True).start()

    def _drain(self):
        try:
            for msg in self.ws:
                self.bytes += len(msg)
        except Exception:
            pass

    def quit(self):
        self.ws.close()


def round_trips(rows, view: bool, watch: str | None = "chromium"):
    cmd = [sys.executable, "-m", "tendonsense.cli", "estimate", str(ROBOT), "--readings", "-",
           "--unknown", "0.25,0,0,-1"]
    port = free_port()
    if view:
        cmd += ["--view", "--port", str(port)]
    proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, bufsize=1, cwd=ROOT)
    err = []
    threading.Thread(target=lambda: err.extend(proc.stderr), daemon=True).start()
    proc.stdin.write("time,tension_t1,tension_t2,tension_t3,displacement_t1\n")
    proc.stdin.flush()
    proc.stdout.readline()
    driver = None
    if view:
        while not any("view at" in e for e in err):
            time.sleep(0.1)
        driver = {"chromium": browser, "socket": Socket, None: lambda _: None}[watch](port)
    trip = []
    t_start = time.perf_counter()
    for k, (T, y) in enumerate(rows):
        t0 = time.perf_counter()
        proc.stdin.write(f"{t0 - t_start!r},{T!r},0,0,{y!r}\n")
        proc.stdin.flush()
        proc.stdout.readline()
        trip.append(time.perf_counter() - t0)
        time.sleep(0.005)  # a 200 Hz acquisition loop, so that the view redraws between rows
    proc.stdin.close()
    proc.terminate()
    proc.wait()
    if driver is not None:
        driver.quit()
    return np.array(trip[10:])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--rows", type=int, default=1000)
    ap.add_argument("--runs", type=int, default=4, help="runs of each mode, alternated")
    args = ap.parse_args()
    from online import smooth_log  # noqa: E402  (benchmarks/online.py)
    from tendonsense import load_robot
    from tendonsense.forward import solve
    from tendonsense.view import Viewer, ViewProcess

    robot = load_robot(ROBOT)
    n = args.rows
    F, T, Y = smooth_log(robot, n)
    rows = list(zip(T[:, 0].tolist(), Y["t1"].tolist()))

    # 1. the Python side of one view update: the redraw (drawing thread) and push (caller)
    viewer = Viewer(robot, free_port())
    results = [solve(robot, {"t1": float(T[k, 0])}, [(0.25, (0, 0, -float(F[k])))])
               for k in range(0, n, max(n // 50, 1))]
    draw = []
    for k in range(400):
        r = results[k % len(results)]
        shown = viewer._shown(r, None, [(0.25, (0, 0, -1.0))], (), None, "", time.monotonic())
        t0 = time.perf_counter()
        viewer.draw(*shown)
        draw.append(time.perf_counter() - t0)
    viewer.close()
    process, push = ViewProcess(robot, free_port()), []  # as estimate --view pushes
    for k in range(400):
        t0 = time.perf_counter()
        process.push(results[k % len(results)], forces=[(0.25, (0, 0, -1.0))])
        push.append(time.perf_counter() - t0)
        time.sleep(0.005)
    process.close()
    draw, push = np.array(draw[20:]) * 1e3, np.array(push[20:]) * 1e6
    print(f"view update (redraw, Python side): p50 {np.median(draw):.2f} ms, "
          f"p99 {np.percentile(draw, 99):.2f} ms; push at 200 Hz (on the estimator's path): "
          f"p50 {np.median(push):.0f} µs, p99 {np.percentile(push, 99):.0f} µs")

    # 2. the stream's row round trip with and without the view, alternated
    modes = {"without --view": (False, None), "with --view, nobody watching": (True, None),
             "with --view, a client elsewhere (a socket that draws nothing)": (True, "socket"),
             "with --view and a headless Chromium on this machine": (True, "chromium")}
    out = {m: [] for m in modes}
    names = list(modes)
    for k in range(args.runs):  # each mode first in turn
        for m in names[k % len(names):] + names[:k % len(names)]:
            out[m].append(round_trips(rows, *modes[m]) * 1e3)
    # the machine's pace drifts between runs: each run's p99 against the run without the view
    # made in the same round, the median of those ratios
    base = [np.percentile(t, 99) for t in out[names[0]]]
    for m in modes:
        trip, p99 = np.concatenate(out[m]), [np.percentile(t, 99) for t in out[m]]
        print(f"CLI stream row round trip, {m}: p50 {np.median(trip):.2f} ms, "
              f"p99 {np.percentile(trip, 99):.2f} ms; p99 / the same round's without --view: "
              f"median {np.median(np.divide(p99, base)):.2f} "
              f"({', '.join(f'{r:.2f}' for r in np.divide(p99, base))})")


if __name__ == "__main__":
    main()
