"""The compiled kernels' small numerics (core/detect/linalg.py) against numpy."""

from __future__ import annotations

import numpy as np
import pytest

from artcal_ros.core.detect.linalg import median_small, select_small


@pytest.mark.parametrize("kind", ["normal", "ties", "sorted", "reversed", "constant"])
def test_median_small_is_numpys_median(kind: str) -> None:
    """The median of the first n entries, exactly as np.median gives it (the mean of the two
    middle values for an even n), for odd and even n, with ties and ordered inputs; the
    array is left as it was."""
    rng = np.random.default_rng(7)
    for n in [1, 2, 3, 4, 5, 8, 31, 64, 199, 200, 441]:
        x = {"normal": rng.normal(size=n + 3),
             "ties": rng.integers(0, 4, n + 3).astype(np.float64),
             "sorted": np.sort(rng.normal(size=n + 3)),
             "reversed": np.sort(rng.normal(size=n + 3))[::-1].copy(),
             "constant": np.full(n + 3, 0.25)}[kind]
        work = x.copy()
        assert median_small(work, n) == np.median(x[:n])
        assert np.array_equal(work, x)


@pytest.mark.parametrize("kind", ["normal", "ties", "sorted", "constant"])
def test_select_small_gives_two_neighbouring_ranks(kind: str) -> None:
    """The k-th and (k+1)-th smallest of the first n entries, as a sort gives them (inf above
    the largest), for every k, with ties and ordered inputs."""
    rng = np.random.default_rng(11)
    for n in [1, 2, 3, 7, 40, 121]:
        x = {"normal": rng.normal(size=n + 2),
             "ties": rng.integers(0, 3, n + 2).astype(np.float64),
             "sorted": np.sort(rng.normal(size=n + 2)),
             "constant": np.full(n + 2, -1.5)}[kind]
        ranked = np.append(np.sort(x[:n]), np.inf)
        for k in range(n):
            assert select_small(x.copy(), n, k) == (ranked[k], ranked[k + 1])
