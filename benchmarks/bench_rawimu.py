"""RAWIMUSXB parsing throughput: vectorised numpy parser vs floors measured in the same run.

Prints frames per second of ``drivers.novatel.parse_rawimusxb_buffer`` on a buffer of N frames
(1e-4 byte corruption and garbage bursts in it, so the resync path is exercised), and its time
as a ratio against two floors over the same buffer: ``np.frombuffer(...).copy()`` (touching every
byte once) and a ``bytes.find`` scan for every sync (the cheapest possible frame finder), plus a
byte-at-a-time Python CRC over a small sample for contrast.

    /work/venv/bin/python benchmarks/bench_rawimu.py [N_FRAMES]
"""
from __future__ import annotations

import sys
import time

import numpy as np

from drivers import novatel as nv


def _best(fn, repeat: int = 5) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def _find_all(buf: bytes) -> int:
    n, i = 0, buf.find(nv.SYNC_SHORT)
    while i >= 0:
        n += 1
        i = buf.find(nv.SYNC_SHORT, i + 1)
    return n


def main(n: int = 200_000) -> None:
    rng = np.random.default_rng(0)
    g = rng.integers(-2**30, 2**30, (n, 3))
    a = rng.integers(-2**30, 2**30, (n, 3))
    clean = nv.encode_rawimusxb(2300, 1000.0 + np.arange(n) / 200.0, g, a)
    b = np.frombuffer(clean, np.uint8).copy()
    hit = np.flatnonzero(rng.random(b.size) < 1e-4)
    b[hit] ^= rng.integers(1, 256, hit.size).astype(np.uint8)
    buf = b.tobytes()

    res = nv.parse_rawimusxb_buffer(buf)
    t_parse = _best(lambda: nv.parse_rawimusxb_buffer(buf))
    t_copy = _best(lambda: np.frombuffer(buf, np.uint8).copy())
    t_find = _best(lambda: _find_all(buf), repeat=3)
    k = 2000
    t_scalar = _best(lambda: [nv.crc32(buf[i * 56: i * 56 + 52]) for i in range(k)], repeat=3) * n / k

    print(f"buffer: {n} frames, {len(buf) / 1e6:.1f} MB, {hit.size} corrupted bytes")
    print(f"accepted {len(res.rows)} frames, bad CRC {res.bad_crc}")
    print(f"vectorised parse:           {t_parse * 1e3:8.1f} ms  -> {n / t_parse:,.0f} frames/s "
          f"({len(buf) / t_parse / 1e6:.0f} MB/s)  goal >= 200,000 frames/s: {'met' if n / t_parse >= 2e5 else 'NOT met'}")
    print(f"floor np.frombuffer copy:   {t_copy * 1e3:8.2f} ms  ratio parse/floor = {t_parse / t_copy:8.1f}")
    print(f"floor bytes.find all syncs: {t_find * 1e3:8.1f} ms  ratio parse/floor = {t_parse / t_find:8.2f}")
    print(f"byte-loop Python CRC only (extrapolated): {t_scalar * 1e3:8.0f} ms  "
          f"-> {n / t_scalar:,.0f} frames/s; vectorised is {t_scalar / t_parse:.0f}x faster")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 200_000)
