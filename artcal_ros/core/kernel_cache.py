"""Keep numba's on-disk kernel cache true to the sources it was compiled from.

numba stamps each cached kernel with its own source file only: a kernel that calls a compiled
function from another file (the shared one-point sampler, the homography map, the edge-spread
function) keeps the old machine code when only that other file changes, e.g. after a
``git pull`` into an editable install. :func:`check` hashes the content of every file holding
kernels and, when the hash differs from the one recorded beside the cache, removes the cached
kernels so they compile again. Content, not times: a copied or installed tree keeps its cache.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

CORE = Path(__file__).resolve().parent
# The folders whose modules hold cached kernels; every .py in them that uses numba counts.
KERNEL_DIRS = (CORE, CORE / "detect")
STAMP = CORE / "detect" / "__pycache__" / "kernel_sources.sha256"


def sources_digest(folders: tuple[Path, ...] = KERNEL_DIRS) -> str:
    """SHA-256 over the names and contents of the source files that use numba."""
    digest = hashlib.sha256()
    for folder in folders:
        for path in sorted(folder.glob("*.py")):
            text = path.read_bytes()
            if b"numba" in text:
                digest.update(path.name.encode())
                digest.update(text)
    return digest.hexdigest()


def check(folders: tuple[Path, ...] = KERNEL_DIRS, stamp: Path = STAMP) -> bool:
    """Drop cached kernels compiled from other sources; True when something was removed.

    Does nothing when ``NUMBA_CACHE_DIR`` moves the cache elsewhere or the package is not
    writable (an installed tree's sources do not change under it).
    """
    if os.environ.get("NUMBA_CACHE_DIR"):
        return False
    try:
        now = sources_digest(folders)
        if stamp.is_file() and stamp.read_text().strip() == now:
            return False
        removed = False
        for folder in folders:
            for cached in (folder / "__pycache__").glob("*.nb[ic]"):
                cached.unlink()
                removed = True
        stamp.parent.mkdir(exist_ok=True)
        stamp.write_text(now + "\n")
        return removed
    except OSError:
        return False
