"""Detection speed against OpenCV's default ArUco detector, on the same frames in the same run.

    python -m bench.speed                    # 640x480 .. 3840x2160, 1 and 2 threads
    python -m bench.speed --quick            # fewer frames, one round
    python -m bench.speed --plot docs/speed.png

For each resolution a hand-held sweep at 30 fps (``smooth_poses`` with its default ten
frames between key views, as ``artcal synth --motion smooth`` renders it, with the
cluttered wall behind the board) is rendered once; then, per thread count, the median
time per frame of:

- cold ``detect()`` (a new :class:`Detector` per frame: no history);
- one streaming :class:`Detector` (``DetectorConfig(stream=True)``: each frame's markers
  predicted from the frames before) fed the frames in order (precise, same accuracy);
- the node's fast tier, :class:`MarkerTracker` (approximate markers for the overlay and
  view selection), seeded with the precise detection of the frame before (timed and
  checked against the truth), and once more with each precise detection arriving as many
  frames late as it took at 30 fps, as the node's background tier delivers them here
  (markers shown);
- ``cv2.aruco.ArucoDetector`` with its default parameters;
- offline, as ``artcal calibrate`` reads a recording: :func:`detect_frames` on as many
  worker processes as threads (one kernel thread each), the mean wall time per frame of
  the whole set, its warm-up included (:data:`OFFLINE_WARMUP` frames, then runs of
  :data:`OFFLINE_RUN`: shorter than the command's 8 and 16, so that a dozen frames keep
  both workers busy; the work per frame is the same).

Against the renderer's truth: corner RMS of the precise and of OpenCV's corners, the
tracked corners' median error, and markers found per frame. An empty scene (the wall
alone, the board out of view) is timed at 1920x1080. The machine's speed varies from run
to run; the ratios to OpenCV in the same run are what to compare.
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import os
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.detect import Detector, DetectorConfig, detect
from artcal_ros.core.detect.frames import detect_frames
from artcal_ros.core.detections import Detections
from artcal_ros.core.live.tracking import MarkerTracker
from artcal_ros.synth import Camera, RenderedView, render_view
from artcal_ros.synth.backdrop import Backdrop
from artcal_ros.synth.poses import smooth_poses

# name -> (camera preset, scale of its focal lengths and size): 4K is the hd lens, doubled
RESOLUTIONS: dict[str, tuple[str, int]] = {
    "640x480": ("webcam", 1), "1280x800": ("wide", 1), "1920x1080": ("hd", 1),
    "3840x2160": ("hd", 2)}
EMPTY = "1920x1080 empty"


FRAME_S = 1 / 30  # the stream's frame period, seconds
OFFLINE_WARMUP, OFFLINE_RUN = 2, 4  # detect_frames' warm-up and run length here


@dataclass(frozen=True)
class Row:
    """Median milliseconds per frame of one frame set at one thread count, and accuracy.

    Attributes:
        markers, tracked_markers, opencv_markers: mean markers per frame found by precise
            detection, shown by the tracker seeded with the previous frame's precise
            detection, found by OpenCV.
        corner_rms_px, opencv_rms_px: corner RMS against the truth of precise detection
            and OpenCV (on the markers each found); tracked_median_px: median corner error
            of the tracked markers (NaN without markers).
        live_markers, live_lag: mean markers per frame the tracker shows when each precise
            detection arrives ``live_lag`` frames late (its measured time at 30 fps), as in
            the node on this machine.
        offline_ms: mean wall time per frame of the whole set detected offline on
            ``threads`` processes (precise, as the streamed Detector).
    """

    frames: str
    threads: int
    cold_ms: float
    stream_ms: float
    tracked_ms: float
    opencv_ms: float
    markers: float
    tracked_markers: float
    opencv_markers: float
    corner_rms_px: float
    tracked_median_px: float
    opencv_rms_px: float
    live_markers: float
    live_lag: int
    offline_ms: float = float("nan")


def camera(name: str) -> Camera:
    """The renderer's camera for a name of :data:`RESOLUTIONS`."""
    preset, k = RESOLUTIONS[name]
    base = Camera.preset(preset)
    if k == 1:
        return base
    K = base.K.copy()
    K[:2] *= k
    return Camera(base.model, K, base.dist, (base.width * k, base.height * k))


def sweep(name: str, n: int, seed: int) -> list[RenderedView]:
    """``n`` frames of a 30 fps hand-held sweep at resolution ``name``, with their truth."""
    board = Board()
    cam = camera(name)
    rng = np.random.default_rng(seed)
    wall = Backdrop.random(board, np.random.default_rng([seed, 2]))
    return [render_view(board, cam, r, t, rng=rng, backdrop=wall)
            for r, t in smooth_poses(board, cam, n, rng)]


def empty_scene(n: int, seed: int) -> list[RenderedView]:
    """``n`` 1920x1080 frames of the cluttered wall alone (the board slid out of view)."""
    board = Board()
    cam = camera("1920x1080")
    rng = np.random.default_rng(seed)
    wall = Backdrop.random(board, np.random.default_rng([seed, 2]))
    out = []
    for r, t in smooth_poses(board, cam, n, rng, partial_fraction=0.0):
        # the same camera, the board moved 3 m sideways on the wall's plane side
        t = np.asarray(t, dtype=np.float64) + np.array([3.0, 0.0, 0.0])
        out.append(render_view(board, cam, r, t, rng=rng, backdrop=wall))
    return out


@contextlib.contextmanager
def threads_used(n: int) -> Iterator[None]:
    """Run the block with ``n`` threads in OpenCV and in the detector's kernels
    (``ARTCAL_THREADS``); the previous settings come back afterwards."""
    before_cv, before_env = cv2.getNumThreads(), os.environ.get("ARTCAL_THREADS")
    cv2.setNumThreads(n)
    os.environ["ARTCAL_THREADS"] = str(n)
    try:
        yield
    finally:
        cv2.setNumThreads(before_cv)
        if before_env is None:
            os.environ.pop("ARTCAL_THREADS", None)
        else:
            os.environ["ARTCAL_THREADS"] = before_env


def _median_ms(fn: Callable[[np.ndarray], object], frames: list[np.ndarray]) -> float:
    times = []
    for img in frames:
        t0 = time.perf_counter()
        fn(img)
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times))


def _errors(ids: np.ndarray, corners: np.ndarray, view: RenderedView) -> np.ndarray:
    """(N, 4) corner errors against the truth, pixels (ids all on the board)."""
    pos = np.searchsorted(view.ids, ids)
    return np.asarray(np.linalg.norm(corners - view.corners_px[pos], axis=2))


def _opencv_markers(aruco: cv2.aruco.ArucoDetector, image: np.ndarray, board: Board
                    ) -> tuple[np.ndarray, np.ndarray]:
    corners, ids, _ = aruco.detectMarkers(image)
    if ids is None:
        return np.zeros(0, np.int64), np.zeros((0, 4, 2))
    ids = ids.ravel().astype(np.int64)
    on_board = np.isin(ids, board.ids)
    return ids[on_board], np.asarray(corners, dtype=np.float64).reshape(-1, 4, 2)[on_board]


def track_stream(board: Board, frames: list[np.ndarray], precise: list[Detections],
                 lag: int) -> tuple[list[float], list[Detections]]:
    """The fast tier on ``frames`` in order: seconds per frame and the tracked markers.

    A precise detection of frame i (``precise[i]``) arrives ``lag`` frames later, and the
    next one is started then, as the node's background tier does.
    """
    tracker = MarkerTracker(board)
    times, shown = [], []
    started, started_index = 0, 0
    for i, image in enumerate(frames):
        t0 = time.perf_counter()
        index, dets = tracker.track(image)
        times.append(time.perf_counter() - t0)
        shown.append(dets)
        if i == 0:
            started, started_index = 0, index
        if i == started + lag:
            tracker.seed(started_index, precise[started])
            started, started_index = i, index
    return times, shown


def time_frames(name: str, views: list[RenderedView], threads: int, repeats: int = 1) -> Row:
    """Median ms per frame of the four on ``views``, and their accuracy against the truth.

    Each of ``repeats`` rounds times them in turn on all frames (so slow spells of a
    shared machine hit them alike); the medians are over all rounds.
    """
    with threads_used(threads):
        return _time_frames(name, views, threads, repeats)


def _time_frames(name: str, views: list[RenderedView], threads: int, repeats: int) -> Row:
    board = Board()
    frames = [v.image for v in views]
    aruco = cv2.aruco.ArucoDetector(board.dictionary, cv2.aruco.DetectorParameters())
    # warm-up: imports, first-call allocations, OpenCV's thread pool
    detect(frames[0], board)
    aruco.detectMarkers(frames[0])
    MarkerTracker(board).track(frames[0])
    cold, stream, tracked, ocv, offline = [], [], [], [], []
    precise: list[Detections] = []
    for _ in range(repeats):
        precise.clear()
        cold.append(_median_ms(lambda im: precise.append(detect(im, board)), frames))
        stream.append(_median_ms(Detector(board, DetectorConfig(stream=True)).detect, frames))
        # the previous frame's precise detection known (the streams target's premise)
        times, shown = track_stream(board, frames, precise, 1)
        tracked.append(1e3 * float(np.median(times)))
        # as the node runs here: a precise detection arrives as many frames later as it took
        lag = max(1, int(np.ceil(cold[-1] / 1e3 / FRAME_S)))
        _, live = track_stream(board, frames, precise, lag)
        ocv.append(_median_ms(aruco.detectMarkers, frames))
        t0 = time.perf_counter()
        list(detect_frames([(str(k), im) for k, im in enumerate(frames)], Detector(board),
                           workers=threads, warmup=OFFLINE_WARMUP, run=OFFLINE_RUN))
        offline.append(1e3 * (time.perf_counter() - t0) / len(frames))
    found = [_opencv_markers(aruco, im, board) for im in frames]
    err = [_errors(d.ids, d.corners_px, v) for d, v in zip(precise, views, strict=True)]
    err_cv = [_errors(i, c, v) for (i, c), v in zip(found, views, strict=True)]
    err_tr = [_errors(d.ids, d.corners_px, v) for d, v in zip(shown, views, strict=True)]

    def rms(parts: list[np.ndarray]) -> float:
        flat = np.concatenate([p.ravel() for p in parts])
        return float(np.sqrt(np.mean(flat ** 2))) if flat.size else float("nan")

    flat_tr = np.concatenate([p.ravel() for p in err_tr])
    return Row(name, threads, float(np.median(cold)), float(np.median(stream)),
               float(np.median(tracked)), float(np.median(ocv)),
               float(np.mean([len(d) for d in precise])),
               float(np.mean([len(d) for d in shown])),
               float(np.mean([len(i) for i, _ in found])), rms(err),
               float(np.median(flat_tr)) if flat_tr.size else float("nan"), rms(err_cv),
               float(np.mean([len(d) for d in live])), lag, float(np.median(offline)))


def run(names: list[str], n_frames: int, threads: list[int], seed: int = 31337,
        empty: bool = True, repeats: int = 1, progress: bool = False) -> list[Row]:
    """Render the frame sets and time them; rows in (frames, threads) order.

    With ``progress``, a line on stderr as each set is rendered and each row timed.
    """
    def say(text: str) -> None:
        if progress:
            print(f"  {time.strftime('%H:%M:%S')} {text}", file=sys.stderr, flush=True)

    sets: dict[str, list[RenderedView]] = {}
    for i, name in enumerate(names):
        sets[name] = sweep(name, n_frames, seed + i)
        say(f"rendered {n_frames} frames {name}")
    if empty:
        sets[EMPTY] = empty_scene(max(2, n_frames // 2), seed + 99)
        say(f"rendered {EMPTY}")
    rows = []
    for name, frames in sets.items():
        for t in threads:
            rows.append(time_frames(name, frames, t, repeats))
            r = rows[-1]
            say(f"timed {name}, {t} thread(s): cold {r.cold_ms:.0f} ms, tracked "
                f"{r.tracked_ms:.1f} ms, OpenCV {r.opencv_ms:.0f} ms")
    return rows


def table(rows: list[Row]) -> str:
    """Markdown tables of the rows: times with ratios to OpenCV, then accuracy."""
    lines = ["| frames | threads | cold ms | streamed ms | tracked ms | OpenCV ms "
             "| cold / OpenCV | streamed / OpenCV | tracked / OpenCV | offline ms "
             "(processes = threads) | offline / OpenCV |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        cv_ms = max(r.opencv_ms, 1e-9)
        lines.append(f"| {r.frames} | {r.threads} | {r.cold_ms:.1f} | {r.stream_ms:.1f} | "
                     f"{r.tracked_ms:.1f} | {r.opencv_ms:.1f} | {r.cold_ms / cv_ms:.2f} | "
                     f"{r.stream_ms / cv_ms:.2f} | {r.tracked_ms / cv_ms:.2f} | "
                     f"{r.offline_ms:.1f} | {r.offline_ms / cv_ms:.2f} |")
    lines += ["", "| frames | markers: precise / tracked / OpenCV | corner RMS px: precise "
              "| OpenCV | tracked median px | tracked markers with the precise detections "
              "late (frames) |", "|---|---|---|---|---|---|"]
    for r in rows:
        if r.threads != rows[0].threads:
            continue
        lines.append(f"| {r.frames} | {r.markers:.0f} / {r.tracked_markers:.0f} / "
                     f"{r.opencv_markers:.0f} | {r.corner_rms_px:.3f} | {r.opencv_rms_px:.3f} "
                     f"| {r.tracked_median_px:.2f} | {r.live_markers:.0f} ({r.live_lag}) |")
    return "\n".join(lines)


def plot(rows: list[Row], path: Path, threads: int) -> None:
    """PNG of ms per frame against resolution (megapixels, log axes) for cold, streamed
    and OpenCV at ``threads`` threads, drawn with OpenCV."""
    pts = [r for r in rows if r.threads == threads and r.frames in RESOLUTIONS]
    W, H, m = 900, 560, 80
    img = np.full((H, W, 3), 255, np.uint8)
    mp = np.array([np.prod([int(v) for v in r.frames.split("x")]) / 1e6 for r in pts])
    series = {"cold detect()": ([r.cold_ms for r in pts], (40, 40, 200)),
              "streamed Detector (precise)": ([r.stream_ms for r in pts], (40, 150, 40)),
              "tracked (node's fast tier)": ([r.tracked_ms for r in pts], (200, 60, 160)),
              "OpenCV ArucoDetector": ([r.opencv_ms for r in pts], (160, 90, 20))}
    all_ms = np.concatenate([np.asarray(v) for v, _ in series.values()])
    x_lo, x_hi = np.log10(mp.min() / 1.3), np.log10(mp.max() * 1.3)
    y_lo, y_hi = np.log10(max(all_ms.min() / 1.5, 0.1)), np.log10(all_ms.max() * 1.5)

    def xy(x: float, y: float) -> tuple[int, int]:
        fx = (np.log10(x) - x_lo) / (x_hi - x_lo)
        fy = (np.log10(y) - y_lo) / (y_hi - y_lo)
        return int(m + fx * (W - 2 * m)), int(H - m - fy * (H - 2 * m))

    font = cv2.FONT_HERSHEY_SIMPLEX
    cv2.rectangle(img, (m, m), (W - m, H - m), (0, 0, 0), 1)
    for r, x in zip(pts, mp, strict=True):
        px, _ = xy(x, 10 ** y_lo)
        cv2.line(img, (px, H - m), (px, H - m + 6), (0, 0, 0), 1)
        cv2.putText(img, r.frames, (px - 40, H - m + 24), font, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    for e in range(int(np.floor(y_lo)), int(np.ceil(y_hi)) + 1):
        for v in (1, 2, 5):
            y = v * 10.0 ** e
            if y_lo <= np.log10(y) <= y_hi:
                _, py = xy(10 ** x_lo, y)
                cv2.line(img, (m, py), (W - m, py), (225, 225, 225), 1)
                cv2.putText(img, f"{y:g}", (m - 50, py + 5), font, 0.45, (0, 0, 0), 1,
                            cv2.LINE_AA)
    for k, (label, (ms, color)) in enumerate(series.items()):
        p = [xy(x, y) for x, y in zip(mp, ms, strict=True)]
        for a, b in itertools.pairwise(p):
            cv2.line(img, a, b, color, 2, cv2.LINE_AA)
        for c in p:
            cv2.circle(img, c, 4, color, -1, cv2.LINE_AA)
        cv2.line(img, (m + 20, m + 22 + 22 * k), (m + 50, m + 22 + 22 * k), color, 2)
        cv2.putText(img, label, (m + 58, m + 27 + 22 * k), font, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(img, f"median ms per frame ({threads} threads, same frames, same run)",
                (m, m - 30), font, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(img, "image size (log scale)", (W // 2 - 90, H - 25), font, 0.5, (0, 0, 0), 1,
                cv2.LINE_AA)
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), img)


def _now_and_load() -> str:
    """The date (UTC) and the machine's load averages (1, 5, 15 min): the times depend on it."""
    load = ", ".join(f"{v:.2f}" for v in os.getloadavg())
    return f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, load average {load}"


def main(argv: list[str] | None = None) -> int:
    """Time, print the table, write the plot."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="fewer frames, one round")
    ap.add_argument("--frames", type=int, default=None, help="frames per resolution")
    ap.add_argument("--plot", type=Path, default=Path("docs/speed.png"),
                    help="where to write the PNG plot")
    args = ap.parse_args(argv)
    n = args.frames or (12 if args.quick else 30)
    names = list(RESOLUTIONS)
    print(f"# Detection speed: {n} frames per resolution, smooth sweep, median ms per frame\n",
          flush=True)
    print(f"started {_now_and_load()}\n", flush=True)
    rows = run(names, n, [1, 2], repeats=1 if args.quick else 2, progress=True)
    print(table(rows))
    print(f"\nended {_now_and_load()}")
    plot(rows, args.plot, 2)
    print(f"\nplot: {args.plot}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
