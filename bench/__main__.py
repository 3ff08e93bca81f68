"""``make bench``: every benchmark, in turn, each against plain OpenCV in the same run.

    python -m bench            # the full set (about 80 minutes on 2 cores, 45 of them
                               # bench.solve_time)
    python -m bench --quick    # smaller versions of each (a few minutes)

The figures go to stdout as tables; docs/benchmarks.md records a full run.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench", description=__doc__)
    parser.add_argument("--quick", action="store_true", help="smaller versions of each benchmark")
    args = parser.parse_args(argv)
    quick = ["--quick"] if args.quick else []
    steps = [
        ("detection", ["bench.detection", *quick]),
        ("exposure sweep", ["bench.exposure", *quick]),
        ("other boards", ["bench.boards", *quick]),
        ("speed", ["bench.speed", *quick]),
        ("image conversion", ["bench.conversion", *quick]),
        ("calibration", ["bench.calibration", *quick]),
        ("tone curve and edge shift", ["bench.tone", *quick]),
        ("solve time", ["bench.solve_time", *quick]),
        ("real photographs", ["bench.real_photos", "--markdown"]),
        ("the paper's Table 2, Figure 5 and jitter", ["bench.paper", *quick]),
        ("projection uncertainty against the truth", ["bench.uncertainty", *quick]),
        ("next-pose guidance", ["bench.guidance", *quick]),
        # The real node over DDS; the full runs take ~10 minutes, --quick one short run.
        ("node under load", ["bench.node_load", *quick]),
    ]
    failed = 0
    for name, module_args in steps:
        start = time.monotonic()
        print(f"\n=== {name} ===", flush=True)
        # One process per benchmark: each starts from a clean interpreter and memory.
        status = subprocess.run([sys.executable, "-m", *module_args], check=False).returncode
        failed += int(status != 0)
        print(f"=== {name}: {time.monotonic() - start:.0f} s ===", flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
