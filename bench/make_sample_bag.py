"""Regenerate ``bags/sample``: the committed sample recording and its ground truth.

    python -m bench.make_sample_bag          # or: make sample-bag

A rosbag2 MCAP directory of 60 mono8 frames at 10 Hz on ``/camera/image_raw``, as
the ``webcam`` preset sees the default 19 x 9 board (config/calibrator.yaml) while
the camera is waved smoothly in front of it: whole-board and close partial views,
mostly clean light with mild noise, one frame in five harsh. The truth
(``bags/sample/truth.json``) lies beside the recording. Fixed seed: the output is
the same on every run.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from artcal_ros.bag import BagReader
from artcal_ros.cli.progress import Progress
from artcal_ros.core.board import Board
from artcal_ros.core.params import load_params
from artcal_ros.synth import Camera, load_truth
from artcal_ros.synth.dataset import write_dataset

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "bags" / "sample"
SEED = 2007
FRAMES = 60
RATE_HZ = 10.0


def main() -> int:
    board = Board.from_params(load_params(ROOT / "config" / "calibrator.yaml"))
    cam = Camera.preset("webcam")
    bar: Progress[None] = Progress(total=FRAMES, label="sample bag")
    start = time.monotonic()
    truth_path = write_dataset(board, cam, OUT, frames=FRAMES, seed=SEED, photometry="mixed",
                               encoding="mono8", partial_fraction=0.35, motion="smooth",
                               bag=True, rate_hz=RATE_HZ, overwrite=True,
                               progress=bar.update)
    bar.close()
    truth = load_truth(truth_path)
    with BagReader(OUT) as reader:
        count = reader.message_count
    size_mb = sum(p.stat().st_size for p in OUT.iterdir()) / 1e6
    inside = [int(f.inside.sum()) for f in truth.frames]
    print(f"wrote {OUT} ({count} messages, {size_mb:.1f} MB with truth.json) in "
          f"{time.monotonic() - start:.1f} s; markers fully inside per frame: "
          f"min {min(inside)}, median {sorted(inside)[len(inside) // 2]}, max {max(inside)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
