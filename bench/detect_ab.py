"""Cold ``detect()`` time of two source trees on the same frames, in the same run.

    python -m bench.detect_ab --ref /path/to/other/tree            # 640x480, 1 thread
    python -m bench.detect_ab --ref ../main --threads 2 --rounds 3

Each tree runs in its own worker process (``PYTHONPATH`` set to the tree); the frames
of :mod:`bench.speed`'s 640x480 sweep are rendered once, in this process, and each frame
goes to both workers in turn, the order swapped every frame, so a change in the
machine's load falls on both alike. A fresh :func:`detect` per frame (no history).
Printed: median wall and CPU milliseconds per frame for each tree, their ratios, and the
median of the per-frame CPU ratios. Not part of ``make bench``: it needs a second tree.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

_HERE = Path(__file__).resolve().parent.parent


def worker(frames_path: str) -> int:
    """Serve ``detect()`` timings: a frame index per stdin line, 'wall_ms cpu_ms n' back."""
    import cv2

    import artcal_ros
    from artcal_ros.core.board import Board
    from artcal_ros.core.detect import detect

    cv2.setNumThreads(int(os.environ.get("ARTCAL_THREADS", "2")))
    frames = np.load(frames_path)
    board = Board()
    print(f"ready {Path(artcal_ros.__file__ or '').parent}", flush=True)
    for line in sys.stdin:
        image = frames[int(line)]
        t0, c0 = time.perf_counter(), time.process_time()
        found = detect(image, board)
        t1, c1 = time.perf_counter(), time.process_time()
        print(f"{1e3 * (t1 - t0):.3f} {1e3 * (c1 - c0):.3f} {len(found)}", flush=True)
    return 0


class _Tree:
    def __init__(self, root: Path, frames_path: str, threads: int) -> None:
        env = dict(os.environ, PYTHONPATH=str(root), ARTCAL_THREADS=str(threads))
        self.proc = subprocess.Popen(
            # this file as a script: the tree's artcal_ros, whatever bench/ it has
            [sys.executable, str(Path(__file__).resolve()), "--worker", frames_path],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env,
            cwd=Path(frames_path).parent)
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.stdin, self.stdout = self.proc.stdin, self.proc.stdout
        ready = self.stdout.readline().split()
        if ready[:1] != ["ready"] or Path(ready[1]) != root / "artcal_ros":
            raise RuntimeError(f"the worker of {root} did not start with its artcal_ros "
                               f"(said {' '.join(ready)!r})")

    def time(self, i: int) -> tuple[float, float, int]:
        self.stdin.write(f"{i}\n")
        self.stdin.flush()
        wall, cpu, n = self.stdout.readline().split()
        return float(wall), float(cpu), int(n)

    def close(self) -> None:
        self.stdin.close()
        self.proc.wait(timeout=30)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.detect_ab", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--ref", type=Path, help="the other source tree (its root)")
    parser.add_argument("--frames", type=int, default=24)
    parser.add_argument("--rounds", type=int, default=4)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--seed", type=int, default=31337)
    parser.add_argument("--worker", metavar="FRAMES", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        return worker(args.worker)
    if args.ref is None:
        parser.error("--ref is needed")
    from bench.speed import sweep

    with tempfile.TemporaryDirectory() as tmp:
        frames_path = str(Path(tmp) / "frames.npy")
        np.save(frames_path, np.stack([v.image for v in sweep("640x480", args.frames,
                                                              args.seed)]))
        trees = {"ref": _Tree(args.ref.resolve(), frames_path, args.threads),
                 "this": _Tree(_HERE, frames_path, args.threads)}
        for i in range(min(3, args.frames)):    # compiled kernels loaded, caches warm
            for tree in trees.values():
                tree.time(i)
        times: dict[str, list[tuple[float, float, int]]] = {k: [] for k in trees}
        for r in range(args.rounds):
            for i in range(args.frames):
                order = list(trees) if (i + r) % 2 == 0 else list(trees)[::-1]
                for k in order:
                    times[k].append(trees[k].time(i))
        for tree in trees.values():
            tree.close()
    a, b = np.array(times["ref"]), np.array(times["this"])
    for name, t in (("ref", a), ("this", b)):
        print(f"{name}: wall {np.median(t[:, 0]):.1f} ms, CPU {np.median(t[:, 1]):.1f} ms, "
              f"{t[:, 2].mean():.1f} markers a frame ({len(t)} frames, {args.threads} threads)")
    print(f"this / ref: wall {np.median(b[:, 0]) / np.median(a[:, 0]):.3f}, "
          f"CPU {np.median(b[:, 1]) / np.median(a[:, 1]):.3f}, "
          f"per-frame CPU ratio (median) {np.median(b[:, 1] / a[:, 1]):.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
