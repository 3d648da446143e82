"""Replay a readings log on standard output at its own pace, as a data-acquisition program
would send it: ``python examples/tutorial/replay.py examples/tutorial/readings.csv``.
Option ``--speed S`` plays S times faster (default 1; 0 = as fast as possible)."""

import argparse
import sys
import time

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("log", help="a readings CSV file with a time column")
parser.add_argument("--speed", type=float, default=1.0, help="playback speed (0: no waiting)")
args = parser.parse_args()

with open(args.log) as fh:
    header = fh.readline()
    sys.stdout.write(header)
    sys.stdout.flush()
    column = header.strip().split(",").index("time")
    start = time.monotonic()
    for line in fh:
        t = float(line.split(",")[column])
        if args.speed > 0:
            time.sleep(max(0.0, start + t / args.speed - time.monotonic()))
        try:
            sys.stdout.write(line)
            sys.stdout.flush()
        except BrokenPipeError:
            break
