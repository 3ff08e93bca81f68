"""How much of a side's bend to believe: its own fitted parabola, or the lens's bend.

A side fitted with a free parabola keeps it only where the curvature is significant
(:func:`drop_flat_parabolas`).
"""

from __future__ import annotations

import numpy as np

from artcal_ros.core.detect.sides import SideModel

__all__ = ["drop_flat_parabolas"]


def drop_flat_parabolas(model: SideModel) -> None:
    """Keep a parabola only where its curvature is significant (3 sigma); updates ``model``."""
    curved = model.order >= 3
    if not curved.any():
        return
    sd = np.sqrt(np.maximum(model.cov[:, 2, 2], 1e-30))
    keep = curved & (np.abs(model.coef[:, 2]) > 3.0 * sd)
    if (curved & ~keep).any():
        model.order = np.where(keep, 3, 2)
        model.coef[~keep, 2] = 0.0
        model.cov[~keep, 2, :] = 0.0
        model.cov[~keep, :, 2] = 0.0
