"""Fast DDS transport for camera images: a shared-memory segment that holds a 4K frame.

Fast DDS's built-in shared-memory segment is 512 kB per participant. A larger message
travels in fragments, and on a best-effort link a frame is lost when one fragment is; most
colour or 1080p frames then never arrive. The package installs a profile with a 64 MB
segment (``fastdds_large_shm.xml`` beside this module) and :func:`use_large_shared_memory`
points Fast DDS at it, in the node's own process and before its participant exists, unless
the user has chosen a transport setup of their own:

- ``FASTDDS_DEFAULT_PROFILES_FILE`` or ``FASTRTPS_DEFAULT_PROFILES_FILE`` is set;
- ``FASTDDS_BUILTIN_TRANSPORTS`` is set;
- a ``DEFAULT_FASTDDS_PROFILES.xml`` lies in the working directory (Fast DDS loads it);
- ``RMW_IMPLEMENTATION`` names another middleware;
- ``ARTCAL_FASTDDS_PROFILE`` is ``0`` (off on request).

It is skipped too when ``/dev/shm`` has less room than two segments. Nothing here imports
rclpy: call it before ``rclpy.init``. ``python -m artcal_ros.ros.transport`` prints the
profile's path, for a camera driver's ``FASTDDS_DEFAULT_PROFILES_FILE``.
"""

from __future__ import annotations

import os
import shutil
import sys
from collections.abc import MutableMapping
from pathlib import Path

PROFILE = Path(__file__).with_name("fastdds_large_shm.xml")
SEGMENT_BYTES = 64 * 1024 * 1024
USER_PROFILE_VARIABLES = ("FASTDDS_DEFAULT_PROFILES_FILE", "FASTRTPS_DEFAULT_PROFILES_FILE")
SHM_DIR = Path("/dev/shm")


def _user_choice(environ: MutableMapping[str, str], cwd: Path) -> str:
    """Why the user's own transport setup applies, or empty if they chose none."""
    for name in USER_PROFILE_VARIABLES:
        if environ.get(name):
            return f"{name}={environ[name]}"
    if environ.get("FASTDDS_BUILTIN_TRANSPORTS"):
        return f"FASTDDS_BUILTIN_TRANSPORTS={environ['FASTDDS_BUILTIN_TRANSPORTS']}"
    if (cwd / "DEFAULT_FASTDDS_PROFILES.xml").is_file():
        return f"{cwd / 'DEFAULT_FASTDDS_PROFILES.xml'}"
    rmw = environ.get("RMW_IMPLEMENTATION", "")
    if rmw and not rmw.startswith("rmw_fastrtps"):
        return f"RMW_IMPLEMENTATION={rmw}"
    if environ.get("ARTCAL_FASTDDS_PROFILE", "") == "0":
        return "ARTCAL_FASTDDS_PROFILE=0"
    return ""


def use_large_shared_memory(environ: MutableMapping[str, str] | None = None, *,
                            cwd: Path | None = None, shm_dir: Path = SHM_DIR) -> str:
    """Apply the package's Fast DDS profile to this process unless the user chose a setup.

    Args:
        environ: the environment to change (default ``os.environ``, which Fast DDS reads
            when the first participant is created).
        cwd: the working directory Fast DDS looks in (default: the current one).
        shm_dir: where shared-memory segments live.

    Returns:
        What the process's transport is, in words (for the log and the diagnostics).
    """
    env = os.environ if environ is None else environ
    chosen = _user_choice(env, Path.cwd() if cwd is None else cwd)
    if chosen:
        return f"the user's ({chosen})"
    if not PROFILE.is_file():
        return f"Fast DDS defaults (512 kB shared memory): {PROFILE} is missing"
    try:
        free = shutil.disk_usage(shm_dir).free
    except OSError:
        free = 0
    if free < 2 * SEGMENT_BYTES:
        return (f"Fast DDS defaults (512 kB shared memory): {shm_dir} has "
                f"{free / 2**20:.0f} MB free, under the {2 * SEGMENT_BYTES // 2**20} MB the "
                "large segment needs")
    env["FASTDDS_DEFAULT_PROFILES_FILE"] = str(PROFILE)
    return f"{SEGMENT_BYTES // 2**20} MB shared memory ({PROFILE.name})"


if __name__ == "__main__":
    print(PROFILE)
    sys.exit(0 if PROFILE.is_file() else 1)
