"""What a live stream says about its current camera: readiness, the uncertainty, the next pose.

:class:`LiveStatus` owns the stream's :class:`~artcal_ros.core.live.live_solve.LiveSolve`
(thread "live solve"). After every update, on that thread, it also works out where the
board should be held next (:func:`~artcal_ros.core.live.guidance.next_pose`), so neither
the image callback nor the overlay ever waits for a solve: they read the last results.
Before the first solve (one view) the next pose comes from a provisional camera
and the intrinsics' prior (:func:`~artcal_ros.core.live.guidance_start.first_pose`).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.calibrate.model import ViewPoints
from artcal_ros.core.detections import Detections
from artcal_ros.core.live.coverage import Readiness, Snapshot
from artcal_ros.core.live.guidance import NextPose, next_pose, pose_match
from artcal_ros.core.live.guidance_start import first_pose
from artcal_ros.core.live.live_solve import MIN_VIEWS, LiveEstimate, LiveSolve, LiveSolveConfig
from artcal_ros.core.live.overlay import draw_next_pose
from artcal_ros.core.live.readiness import live_readiness, uncertainty_text

__all__ = ["LiveStatus"]


class LiveStatus:
    """The live solve of one stream and what it tells the user.

    Args:
        board: the calibration board.
        params: validated flat parameters (the solve options, ``readiness.max_uncertainty``);
            :meth:`reconfigure` takes new ones.
        on_error: called on the live solve's thread with an update's error.
        defer_while: :class:`~artcal_ros.core.live.live_solve.LiveSolve`'s: an update waits
            while it is True (frames wait for precise detection), up to 2 s.
    """

    def __init__(self, board: Board, params: Mapping[str, Any], *,
                 on_error: Callable[[BaseException], None] | None = None,
                 defer_while: Callable[[], bool] | None = None) -> None:
        self.board = board
        self._lock = threading.Lock()
        self._max_uncertainty = float(params["readiness.max_uncertainty"])
        self._next: NextPose | None = None
        self._next_error = ""
        self.solve = LiveSolve(board, LiveSolveConfig.from_params(params),
                               on_update=self._on_update, on_error=on_error,
                               on_early=self._on_early, defer_while=defer_while)

    def _on_update(self, estimate: LiveEstimate) -> None:
        # The live solve's thread: the next pose from the estimate just made.
        try:
            suggestion = next_pose(estimate.views, estimate.solution, self.board,
                                   estimate.image_size, weighted=estimate.weighted)
            error = "" if suggestion is not None else "no holdable pose shows the board"
        except Exception as e:  # a suggestion that fails leaves the solve's figures alone
            suggestion, error = None, f"not found: {e}"
        with self._lock:
            if self.solve.snapshot() is estimate:  # not reset or replaced meanwhile
                self._next, self._next_error = suggestion, error

    def _on_early(self, views: list[ViewPoints], image_size: tuple[int, int],
                  generation: int) -> None:
        # The live solve's thread, fewer views than a solve needs: the next pose from a
        # provisional camera of these views.
        config = self.solve.config
        weighted = any(v.sigma_px is not None and bool(np.isfinite(v.sigma_px).any())
                       for v in views)
        try:
            suggestion = first_pose(views, self.board, image_size, model=config.model,
                                    options=config.options, weighted=weighted)
            error = "" if suggestion is not None else "no holdable pose shows the board"
        except Exception as e:  # guidance that fails leaves the collection alone
            suggestion, error = None, f"not found: {e}"
        with self._lock:
            # not reset, reconfigured or solved meanwhile
            if self.solve.generation == generation and self.solve.snapshot() is None:
                self._next, self._next_error = suggestion, error

    def offer(self, snap: Snapshot) -> None:
        """Solve this collection next (returns at once)."""
        if snap.image_size is not None and snap.views:
            self.solve.offer(snap.views, snap.image_size)

    @property
    def estimate(self) -> LiveEstimate | None:
        """The live solve's last estimate."""
        return self.solve.snapshot()

    @property
    def suggestion(self) -> NextPose | None:
        """Where to hold the board next (None before the first view is solved for)."""
        with self._lock:
            return self._next

    def readiness(self, collection: Readiness) -> Readiness:
        """The collection's readiness judged by the projection uncertainty."""
        with self._lock:
            bound = self._max_uncertainty
        return live_readiness(collection, self.solve.snapshot(), bound)

    def diagnostics(self, collection: Readiness) -> dict[str, str]:
        """``projection uncertainty`` (and its bound), ``next pose`` and ``live solve``."""
        estimate = self.solve.snapshot()
        with self._lock:
            bound, suggestion, why = self._max_uncertainty, self._next, self._next_error
        if estimate is None:
            solve = self.solve.error or f"waiting for {MIN_VIEWS} usable views"
            pose = (suggestion.text if suggestion is not None
                    else why or "after the first view")
        else:
            solve = (f"{estimate.seconds:.2f} s, {estimate.n_views} views"
                     + (", warm start" if estimate.warm else ""))
            pose = suggestion.text if suggestion is not None else why
        return {"projection uncertainty": uncertainty_text(estimate, collection.views),
                "projection uncertainty needed": f"{bound:.3f}",
                "next pose": pose, "live solve": solve}

    def draw(self, overlay: np.ndarray, image_width: int, markers: Detections) -> None:
        """Draw the next pose's outline on the overlay, in place (green once the live
        board ``markers`` match it)."""
        suggestion = self.suggestion
        if suggestion is None:
            return
        match = pose_match(suggestion, markers.corners_px) if len(markers) else 0.0
        draw_next_pose(overlay, suggestion, zoom=overlay.shape[1] / image_width, match=match)

    def reconfigure(self, params: Mapping[str, Any]) -> bool:
        """Take changed parameters; whether the solve options changed (the live solve then
        starts again cold at the next offer)."""
        with self._lock:
            self._max_uncertainty = float(params["readiness.max_uncertainty"])
        config = LiveSolveConfig.from_params(params)
        if config == self.solve.config:
            return False
        self.solve.set_config(config)
        with self._lock:
            self._next = None
        return True

    def reset(self) -> None:
        """Forget the estimate and the suggestion."""
        self.solve.reset()
        with self._lock:
            self._next, self._next_error = None, ""

    @property
    def alive(self) -> bool:
        """Whether the live solve's thread still runs."""
        return self.solve.alive

    def stop(self, timeout: float = 1.0) -> bool:
        """End the live solve's thread (joined up to ``timeout`` s); whether it ended."""
        return self.solve.stop(timeout)
