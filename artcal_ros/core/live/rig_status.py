"""What a live rig says about its cameras: each camera's live solve, and the rig's readiness.

:class:`RigStatus` owns one :class:`~artcal_ros.core.live.live_status.LiveStatus` per camera
(each with its own thread "live solve"), fed that camera's precise detections of the kept
rig views whenever the rig collection changes. The rig is ready when it holds ``min_views``
rig views, every camera is connected to the others, and every camera's projection
uncertainty (1-sigma, RMS over its whole image; docs/conventions.md) is at or below
``readiness.max_uncertainty``. The extrinsics are not judged: they follow from shared views
of cameras each known well enough.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from functools import partial
from typing import Any

import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.detections import Detections
from artcal_ros.core.live.coverage import Readiness, Snapshot
from artcal_ros.core.live.live_solve import LiveEstimate
from artcal_ros.core.live.live_status import LiveStatus
from artcal_ros.core.live.readiness import not_solved_text, uncertainty_text
from artcal_ros.core.live.rig_views import RigSnapshot

__all__ = ["CameraUncertainty", "RigReadiness", "RigStatus", "camera_views"]


def camera_views(snap: RigSnapshot, name: str) -> list[Detections]:
    """Camera ``name``'s precise detections of the kept rig views it measures the board in,
    oldest first (the same objects from one snapshot to the next, so its live solve
    warm-starts)."""
    out = []
    for view in snap.views:
        dets = view.detections.get(name)
        if name in view.measured and dets is not None:
            out.append(dets)
    return out


@dataclass(frozen=True)
class CameraUncertainty:
    """One camera's live solve, judged against the bound.

    Attributes:
        name: the camera.
        views: rig views in which it measures the board.
        estimate: its live solve's latest estimate of these views (None: none yet, or made
            of views since forgotten).
        missing: what it lacks, in words, starting with its name ("" within the bound).
    """

    name: str
    views: int
    estimate: LiveEstimate | None
    missing: str

    @property
    def uncertainty_rms_px(self) -> float | None:
        """Projection uncertainty RMS over the image, pixels (None before an estimate)."""
        return None if self.estimate is None else self.estimate.uncertainty_rms_px


@dataclass(frozen=True)
class RigReadiness:
    """How far a live rig is from a good solve.

    Attributes:
        views: rig views kept; views_needed: ``min_views``.
        shared: (a, b) -> rig views both cameras measure the board in.
        cameras: camera -> its projection uncertainty against the bound.
        max_uncertainty_px: ``readiness.max_uncertainty``, pixels.
        missing: what the rig lacks, in words (empty: ready).
    """

    views: int
    views_needed: int
    shared: dict[tuple[str, str], int]
    cameras: dict[str, CameraUncertainty]
    max_uncertainty_px: float
    missing: tuple[str, ...]

    @property
    def ready(self) -> bool:
        """Enough rig views, every camera connected and known within the bound."""
        return not self.missing

    def summary(self) -> str:
        """One line: rig views, shared views, each camera's uncertainty, what is missing."""
        pairs = ", ".join(f"{a}-{b} {n}" for (a, b), n in self.shared.items())
        unc = ", ".join(f"{n} " + ("-" if c.estimate is None
                                    else f"{c.estimate.uncertainty_rms_px:.3g} px")
                        for n, c in self.cameras.items())
        text = (f"rig views {self.views}/{self.views_needed} (shared views {pairs}); "
                f"projection uncertainty {unc} (needs <= {self.max_uncertainty_px:.3g} px)")
        return text + ("; ready" if self.ready else "; missing: " + "; ".join(self.missing))

    def for_camera(self, collection: Readiness) -> Readiness:
        """A camera's own figures (views, coverage, tilts) with the rig's missing items:
        what its overlay prints."""
        return replace(collection, missing=self.missing)


def camera_missing(name: str, estimate: LiveEstimate | None, views: int, rig_views: int,
                   min_views: int, max_uncertainty_px: float) -> str:
    """What one camera of the rig lacks, in words ("" when its uncertainty is in bounds).

    Args:
        estimate: its live solve's estimate; views: rig views it measures the board in.
        rig_views, min_views: rig views kept and needed.
        max_uncertainty_px: ``readiness.max_uncertainty``, pixels.
    """
    if estimate is None:
        return f"{name}: projection uncertainty {not_solved_text(views)}"
    if estimate.uncertainty_rms_px > max_uncertainty_px:
        return (f"{name}: projection uncertainty {estimate.uncertainty_rms_px:.3g} px, needs "
                f"<= {max_uncertainty_px:.3g} px")
    if estimate.collected < min(min_views, views) and rig_views >= min_views:
        return f"{name}: projection uncertainty of all {views} views (solving)"
    return ""


class RigStatus:
    """The live solve of every camera of a rig and what they tell the user.

    Args:
        board: the calibration board.
        names: the cameras.
        params: validated flat parameters (the solve options, ``readiness.max_uncertainty``).
        on_error: called on a live solve's thread with the camera and an update's error.
        defer_while: every live solve's update waits while it is True (rig frames wait for
            precise detection), up to 2 s; it must take no lock
            (:class:`~artcal_ros.core.live.live_solve.LiveSolve`'s).
    """

    def __init__(self, board: Board, names: tuple[str, ...], params: Mapping[str, Any], *,
                 on_error: Callable[[str, BaseException], None] | None = None,
                 defer_while: Callable[[], bool] | None = None) -> None:
        self.names = tuple(names)
        self.cameras = {n: LiveStatus(board, params,
                                      on_error=None if on_error is None else partial(on_error, n),
                                      defer_while=defer_while) for n in self.names}
        self._max_uncertainty = float(params["readiness.max_uncertainty"])

    def offer(self, snap: RigSnapshot) -> None:
        """Solve each camera's views of this collection next (returns at once)."""
        for n, status in self.cameras.items():
            size = snap.image_sizes.get(n)
            views = camera_views(snap, n)
            if size is not None and views:
                status.offer(Snapshot(views, size, snap.counts[n], snap.readiness[n]))

    def readiness(self, snap: RigSnapshot) -> RigReadiness:
        """The rig collection's readiness judged by every camera's live solve."""
        bound = self._max_uncertainty
        n_views = len(snap.views)
        missing = snap.missing()
        cameras = {}
        for n, status in self.cameras.items():
            views = len(camera_views(snap, n))
            estimate = status.estimate
            if estimate is not None and estimate.collected > views:
                estimate = None  # made of views since forgotten (a reset, a new image size)
            why = camera_missing(n, estimate, views, n_views, snap.min_views, bound)
            cameras[n] = CameraUncertainty(n, views, estimate, why)
            if why:
                missing.append(why)
        return RigReadiness(n_views, snap.min_views, dict(snap.shared), cameras, bound,
                            tuple(missing))

    def diagnostics(self, snap: RigSnapshot, readiness: RigReadiness
                    ) -> tuple[dict[str, dict[str, str]], dict[str, str]]:
        """(camera -> its ``projection uncertainty``, ``projection uncertainty needed``,
        ``next pose``, ``live solve``; the rig's ``<camera>: projection uncertainty`` of each
        camera)."""
        per_camera, rig = {}, {}
        for n, status in self.cameras.items():
            collection = snap.readiness[n]
            values = status.diagnostics(collection)
            camera = readiness.cameras[n]
            if camera.estimate is None:  # forgotten views: not the stale estimate's figures
                values["projection uncertainty"] = uncertainty_text(None, camera.views)
            per_camera[n] = values
            rig[f"{n}: projection uncertainty"] = values["projection uncertainty"]
        return per_camera, rig

    def draw(self, name: str, overlay: np.ndarray, image_width: int,
             markers: Detections) -> None:
        """Draw camera ``name``'s next pose on its overlay, in place."""
        self.cameras[name].draw(overlay, image_width, markers)

    def reconfigure(self, params: Mapping[str, Any]) -> bool:
        """Take changed parameters; whether the solve options changed (then offer again)."""
        self._max_uncertainty = float(params["readiness.max_uncertainty"])
        changed = [status.reconfigure(params) for status in self.cameras.values()]
        return any(changed)

    def reset(self) -> None:
        """Forget every camera's estimate and suggestion."""
        for status in self.cameras.values():
            status.reset()

    def running(self) -> list[str]:
        """``<camera>: live solve`` of the live solves still running."""
        return [f"{n}: live solve" for n, s in self.cameras.items() if s.alive]

    def stop(self, timeout: float = 1.0) -> list[str]:
        """End every live solve's thread, each joined for up to ``timeout`` s (an update in
        progress finishes), ``timeout`` s in all; the ones still running (as :meth:`running`).
        Idempotent."""
        deadline = time.monotonic() + timeout
        for status in self.cameras.values():
            status.stop(max(0.0, deadline - time.monotonic()))
        return self.running()
