"""Where results go, and result files written atomically (a reader sees the old file or the
new one, never a part)."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from artcal_ros.core.errors import ArtcalError


def ros_home() -> Path:
    """``$ROS_HOME`` (``~`` expanded), else ``~/.ros``: where rcl keeps its logs too."""
    value = os.environ.get("ROS_HOME", "")
    return Path(os.path.expanduser(value)) if value else Path.home() / ".ros"


def write_text_atomic(path: str | os.PathLike[str], text: str) -> Path:
    """Write ``text`` to ``path`` through a temporary file in the same directory, flushed to
    disk and renamed over it; the path written.

    A kill at any moment leaves the old file or the new one (and at worst a stray
    ``.<name>.*.tmp`` beside it); a failure leaves any existing file untouched. Parent
    directories are created; the file gets the mode the umask gives a new file.

    Raises:
        ArtcalError: naming the path and the reason (a parent is a file, the path is a
            directory, no permission, a full disk).
    """
    target = Path(path).expanduser()
    blocking = next((p for p in reversed(target.parents) if p.exists() and not p.is_dir()),
                    None)
    if blocking is not None:
        raise ArtcalError(f"cannot write {target}: {blocking} is a file, not a directory")
    if target.is_dir():
        raise ArtcalError(f"cannot write {target}: it is a directory; give a file name")
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp",
                                   dir=str(target.parent))
    except OSError as e:
        raise ArtcalError(f"cannot write {target}: {e.strerror}") from None
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)   # mkstemp makes 0600; a result file is for sharing
        os.replace(tmp, target)
    except OSError as e:
        Path(tmp).unlink(missing_ok=True)
        raise ArtcalError(f"cannot write {target}: {e.strerror}") from None
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return target
