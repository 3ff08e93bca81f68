"""The kernel cache guard drops cached kernels when any numba source changes, and only then."""

from __future__ import annotations

from pathlib import Path

import pytest

from artcal_ros.core import kernel_cache


def _tree(tmp_path: Path) -> tuple[tuple[Path, ...], Path, Path]:
    folder = tmp_path / "detect"
    (folder / "__pycache__").mkdir(parents=True)
    (folder / "sampler.py").write_text("import numba\n\n@numba.njit(cache=True)\ndef f(): ...\n")
    (folder / "plain.py").write_text("x = 1\n")
    cached = folder / "__pycache__" / "caller.f-3.py311.1.nbi"
    cached.write_bytes(b"index")
    return (folder,), folder / "__pycache__" / "stamp", cached


def test_a_changed_kernel_source_drops_every_cached_kernel(tmp_path: Path,
                                                           monkeypatch: pytest.MonkeyPatch
                                                           ) -> None:
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    folders, stamp, cached = _tree(tmp_path)
    assert kernel_cache.check(folders, stamp)  # no stamp yet: the cache's origin is unknown
    assert not cached.exists() and stamp.is_file()
    cached.write_bytes(b"index")
    assert not kernel_cache.check(folders, stamp)  # same sources: the cache stays
    assert cached.exists()
    (folders[0] / "plain.py").write_text("x = 2\n")  # not a kernel source
    assert not kernel_cache.check(folders, stamp) and cached.exists()
    (folders[0] / "sampler.py").write_text("import numba  # changed\n")
    assert kernel_cache.check(folders, stamp)
    assert not cached.exists()


def test_a_cache_kept_elsewhere_is_left_alone(tmp_path: Path,
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    folders, stamp, cached = _tree(tmp_path)
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "elsewhere"))
    assert not kernel_cache.check(folders, stamp)
    assert cached.exists() and not stamp.exists()


def test_the_package_stamp_matches_its_sources_after_import() -> None:
    assert kernel_cache.STAMP.read_text().strip() == kernel_cache.sources_digest()
