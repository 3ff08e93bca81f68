"""Regenerate the committed sample recordings and their ground truth.

    python -m bench.make_sample_bag                # both; or: make sample-bag
    python -m bench.make_sample_bag sample_color   # one of them, by name

``bags/sample``: a rosbag2 MCAP directory of 60 mono8 frames at 10 Hz on
``/camera/image_raw``, as the ``webcam`` preset sees the default 19 x 9 board
(config/calibrator.yaml) while the camera is waved smoothly in front of it: whole-board
and close partial views, mostly clean light with mild noise, one frame in five harsh.
What ``make demo`` and the launch file play.

``bags/sample_color``: 40 bgr8 frames at 10 Hz on the same topic, 40 independent poses
(a colour camera's 921 kB frames; what the colour integration tests play), same light.

The truth (``truth.json``) lies beside each recording. Fixed seeds: the output is the same
on every run.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from artcal_ros.bag import BagReader
from artcal_ros.cli.progress import Progress
from artcal_ros.core.board import Board
from artcal_ros.core.params import load_params
from artcal_ros.synth import Camera, load_truth
from artcal_ros.synth.dataset import write_dataset

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class SampleBag:
    """One committed recording: where it goes and how it is rendered."""

    name: str  # directory under bags/
    frames: int
    seed: int
    encoding: str
    motion: str  # "smooth": a hand-held sweep; "random": independent poses
    partial_fraction: float
    rate_hz: float = 10.0


SAMPLES = {s.name: s for s in (
    SampleBag("sample", frames=60, seed=2007, encoding="mono8", motion="smooth",
              partial_fraction=0.35),
    SampleBag("sample_color", frames=40, seed=2020, encoding="bgr8", motion="random",
              partial_fraction=0.35),
)}


def make(sample: SampleBag) -> Path:
    """Render ``sample`` into bags/<name> (replacing it); the bag directory."""
    out = ROOT / "bags" / sample.name
    board = Board.from_params(load_params(ROOT / "config" / "calibrator.yaml"))
    cam = Camera.preset("webcam")
    bar: Progress[None] = Progress(total=sample.frames, label=sample.name)
    start = time.monotonic()
    truth_path = write_dataset(board, cam, out, frames=sample.frames, seed=sample.seed,
                               photometry="mixed", encoding=sample.encoding,
                               partial_fraction=sample.partial_fraction, motion=sample.motion,
                               bag=True, rate_hz=sample.rate_hz, overwrite=True,
                               progress=bar.update)
    bar.close()
    truth = load_truth(truth_path)
    with BagReader(out) as reader:
        count = reader.message_count
    size_mb = sum(p.stat().st_size for p in out.iterdir()) / 1e6
    inside = [int(f.inside.sum()) for f in truth.frames]
    print(f"wrote {out} ({count} {sample.encoding} messages, {size_mb:.1f} MB with truth.json) "
          f"in {time.monotonic() - start:.1f} s; markers fully inside per frame: "
          f"min {min(inside)}, median {sorted(inside)[len(inside) // 2]}, max {max(inside)}")
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", metavar="NAME",
                        help=f"which to make: {', '.join(SAMPLES)} (default: all)")
    args = parser.parse_args(argv)
    unknown = [n for n in args.names if n not in SAMPLES]
    if unknown:
        parser.error(f"no sample bag {', '.join(unknown)}; choose from {', '.join(SAMPLES)}")
    for name in args.names or list(SAMPLES):
        make(SAMPLES[name])
    return 0


if __name__ == "__main__":
    sys.exit(main())
