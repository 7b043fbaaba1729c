"""A real-time IMU stream through a pty with 1e-4 byte corruption (issue 4).

The test ``tests/test_drivers_pty_imu.py::test_60s_stream_with_1e4_corruption_loses_only_crc_failures``
pushes the 60 s of frames as fast as the pty takes them; here the twin paces them at the IMU's own
rate, as a real unit sends them, for ``--seconds`` at 200 Hz and at 1000 Hz. The same checks as the
test (every accepted frame is one the twin sent intact; frames lost exactly where a fault hit;
every byte counted) and the cost of reading: the process CPU time as a share of the wall time.

    python benchmarks/bench_imu_stream.py [--seconds 60]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from test_drivers_pty_imu import _arrays, _expected_loss, _run  # noqa: E402  (the test's own oracle)

from drivers.twins.base import Faults  # noqa: E402
from drivers.twins.imu import ImuTwin  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    a = ap.parse_args()
    for rate in (200.0, 1000.0):
        n = int(a.seconds * rate)
        t, w, f = _arrays(n, rate)
        twin = ImuTwin(t, w, f, imu_type=26, rate_hz=rate, realtime=True,
                       faults=Faults(corrupt_rate=1e-4, seed=7))
        c0, t0 = time.process_time(), time.perf_counter()
        link, fr, st = _run(twin, rate, timeout_s=a.seconds + 30.0)
        cpu, wall = time.process_time() - c0, time.perf_counter() - t0
        hit, sync_hit = _expected_loss(twin.injector, n)
        good = np.array(sorted(set(range(n)) - hit))
        intact = (len(fr) == len(good) == st.frames_ok and np.array_equal(fr.gyro_counts, twin.gyro_counts[good])
                  and np.array_equal(fr.accel_counts, twin.accel_counts[good]))
        counted = st.bytes_in == twin.bytes_sent
        print(f"{rate:.0f} Hz x {a.seconds:g} s paced: {n} frames, {len(twin.injector.corrupted)} bytes corrupted, "
              f"{len(hit)} frames hit, {st.frames_ok} accepted, bad CRC {st.bad_checksum} "
              f"(expected {len(hit - sync_hit)}), frames_missing {st.extra['frames_missing']}, "
              f"accepted frames intact: {intact}, bytes balanced: {st.balanced() and counted}; "
              f"wall {wall:.1f} s, CPU {cpu:.2f} s = {100 * cpu / wall:.1f} % of one core (twin + reader)")


if __name__ == "__main__":
    main()
