"""Readiness from the projection uncertainty: enough views, and a camera known well enough.

A collection is ready when it holds at least ``min_views`` views and the live solve's
projection uncertainty (1-sigma, RMS over the whole image; docs/conventions.md) is at or
below ``readiness.max_uncertainty``. Coverage and tilt are not conditions of their own:
they matter through the uncertainty they lower. While the uncertainty is too high, the
coverage and tilt the collection still lacks are listed after it as what to add.
"""

from __future__ import annotations

from dataclasses import replace

from artcal_ros.core.live.coverage import Readiness, count_text
from artcal_ros.core.live.live_solve import MIN_VIEWS, LiveEstimate

__all__ = ["calibrate_readiness", "live_readiness", "not_solved_text", "uncertainty_text"]


def live_readiness(collection: Readiness, estimate: LiveEstimate | None,
                   max_uncertainty_px: float) -> Readiness:
    """The collection's readiness judged by the live solve.

    Args:
        collection: the collection's own (:meth:`ViewCollector.snapshot`): views, coverage,
            tilt and what it lacks.
        estimate: the live solve's latest estimate (None before the first).
        max_uncertainty_px: ``readiness.max_uncertainty``, pixels.

    Returns:
        The same figures; ``missing`` says, in words, the views still needed and the
        projection uncertainty against its bound (empty: ready).
    """
    n, needed = collection.views, collection.views_needed
    missing: list[str] = []
    if n < needed:
        missing.append(count_text(needed - n, "more view"))
    hints = [m for m in collection.missing if "more view" not in m]
    if estimate is None:
        missing.append(f"projection uncertainty: {not_solved_text(n)}")
        missing += hints
    elif estimate.uncertainty_rms_px > max_uncertainty_px:
        missing.append(f"projection uncertainty {estimate.uncertainty_rms_px:.3g} px, needs "
                       f"<= {max_uncertainty_px:.3g} px")
        missing += hints
    elif estimate.collected < needed <= n:
        missing.append(f"projection uncertainty of all {n} views (solving)")
    return replace(collection, missing=tuple(missing))


def uncertainty_text(estimate: LiveEstimate | None, views: int) -> str:
    """The diagnostics' ``projection uncertainty``: ``0.083 px RMS, max 0.112 px (14 views)``,
    or ``not yet (1 view)`` before the first solve."""
    if estimate is None:
        return f"not yet ({count_text(views, 'view')})"
    return (f"{estimate.uncertainty_rms_px:.3f} px RMS, max {estimate.uncertainty_max_px:.3f} "
            f"px ({estimate.n_views} views)")


def calibrate_readiness(uncertainty_rms_px: float, views: int, min_views: int,
                        max_uncertainty_px: float) -> str:
    """How far a solve's views are from ready, in words, for the ``~/calibrate`` answer.

    Args:
        uncertainty_rms_px: the solve's projection uncertainty (RMS over the image), pixels.
        views: views collected; min_views, max_uncertainty_px: the readiness bounds.
    """
    short = []
    if views < min_views:
        short.append(f"{min_views - views} more views")
    if not uncertainty_rms_px <= max_uncertainty_px:
        short.append(f"projection uncertainty {uncertainty_rms_px:.3g} px, needs <= "
                     f"{max_uncertainty_px:.3g} px: "
                     f"{uncertainty_rms_px / max_uncertainty_px:.1f} x the bound")
    if not short:
        return (f"ready: projection uncertainty {uncertainty_rms_px:.3g} px <= "
                f"{max_uncertainty_px:.3g} px")
    return "not ready yet: " + "; ".join(short) + " (add views where 'next pose' says)"


def not_solved_text(views: int) -> str:
    """Why there is no projection uncertainty yet: ``not yet (1 view, needs 2 to solve)``
    or ``not yet (3 views, solving)``."""
    return (f"not yet ({count_text(views, 'view')}"
            + (f", needs {MIN_VIEWS} to solve)" if views < MIN_VIEWS else ", solving)"))
