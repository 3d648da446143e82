"""Values at run time (issue 8): many robot variants and load positions in one process.

    python benchmarks/values.py [--variants 200] [--positions 40] [--batch 4000]

Each variant is a copy of ``examples/paper_prototype.toml`` with other numbers (E, ν, ρ, μ,
tendon offsets, gravity), written to a file, loaded and solved; then one point force is moved
over off-grid positions; then batched forward solves over varied E, μ and tensions. Prints the
median time per variant past the first five, the growth of the process' memory (RSS and
memory maps) and the batch throughput.
"""

from __future__ import annotations

import argparse
import re
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PROTOTYPE = ROOT / "examples" / "paper_prototype.toml"


def memory():
    rss = int(re.search(r"VmRSS:\s+(\d+)", Path("/proc/self/status").read_text()).group(1))
    maps = sum(1 for _ in open("/proc/self/maps"))
    return rss / 1024, maps


def variant_text(text: str, rng) -> str:
    def scale(key, lo, hi, s):
        return re.sub(rf"^({key}\s*=\s*)([-0-9.e+]+)", lambda m: f"{m.group(1)}"
                      f"{float(m.group(2)) * rng.uniform(lo, hi)!r}", s, flags=re.M)
    text = scale("young_modulus", 0.5, 2.0, text)
    text = scale("density", 0.7, 1.3, text)
    text = scale("friction", 0.5, 1.5, text)
    text = re.sub(r"^(poisson_ratio\s*=\s*)[-0-9.e+]+",
                  lambda m: f"{m.group(1)}{rng.uniform(0.3, 0.5)!r}", text, flags=re.M)
    text = re.sub(r"^(offset_base\s*=\s*\[)([^\]]*)\]", lambda m: m.group(1) + ", ".join(
        repr(float(v) * rng.uniform(0.9, 1.1)) for v in m.group(2).split(",")) + "]",
        text, flags=re.M)
    return text


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--variants", type=int, default=200)
    ap.add_argument("--positions", type=int, default=40)
    ap.add_argument("--batch", type=int, default=4000)
    args = ap.parse_args(argv)

    from tendonsense import load_robot
    from tendonsense.forward import solve

    rng = np.random.default_rng(0)
    text = PROTOTYPE.read_text()
    base = load_robot(PROTOTYPE)
    solve(base, {"t1": 2.0})  # compile / load the cache once
    mem0 = memory()
    times, ok = [], 0
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(args.variants):
            path = Path(tmp) / f"v{k}.toml"
            path.write_text(variant_text(text, rng))
            t0 = time.perf_counter()
            robot = load_robot(path)
            r = solve(robot, {"t1": float(rng.uniform(0.5, 3.0)), "t3": 0.5})
            times.append(time.perf_counter() - t0)
            ok += bool(r.converged)
    mem1 = memory()
    print(f"{args.variants} variants: {ok} converged, median {1e3 * np.median(times[5:]):.1f} ms "
          f"per variant (load + solve) past the first five, first {1e3 * times[0]:.0f} ms")
    ptimes, pok = [], 0
    L = base.rod.length
    for X in rng.uniform(0.02 * L, L, args.positions):
        t0 = time.perf_counter()
        r = solve(base, {"t1": 1.0}, [(float(X), (0.0, 0.05, -0.1))])
        ptimes.append(time.perf_counter() - t0)
        pok += bool(r.converged)
    mem2 = memory()
    print(f"{args.positions} load positions: {pok} converged, median "
          f"{1e3 * np.median(ptimes[3:]):.1f} ms per position past the first three")
    print(f"memory: RSS {mem0[0]:.0f} -> {mem1[0]:.0f} -> {mem2[0]:.0f} MB "
          f"(growth {mem2[0] - mem0[0]:.0f} MB), maps {mem0[1]} -> {mem2[1]}")

    try:
        from tendonsense.tracking import solve_batch
    except ImportError:
        print("batched solves: not available")
        return
    n = args.batch
    E = base.rod.young_modulus * rng.uniform(0.7, 1.5, n)
    mu = rng.uniform(0.2, 0.6, n)
    T = np.zeros((n, 3))
    T[:, 0] = rng.uniform(0.5, 3.0, n)
    T[:, 2] = rng.uniform(0.0, 1.0, n)
    solve_batch(base, T[:8], values={"young_modulus": E[:8], "friction": mu[:8]})  # compile
    t0 = time.perf_counter()
    out = solve_batch(base, T, values={"young_modulus": E, "friction": mu})
    dt = time.perf_counter() - t0
    print(f"batched forward solves over E, mu, T: {n} in {dt:.2f} s = {n / dt:,.0f} solves/s, "
          f"{int(np.sum(out.converged))} converged")


if __name__ == "__main__":
    main()
