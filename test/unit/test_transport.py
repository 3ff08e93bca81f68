"""The nodes' Fast DDS profile: applied only when the user set up no transport of their own."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from artcal_ros.ros.transport import PROFILE, SEGMENT_BYTES, use_large_shared_memory

NS = {"f": "http://www.eprosima.com"}


def test_profile_is_a_fast_dds_profile_with_the_large_segment() -> None:
    root = ET.parse(PROFILE).getroot()
    sizes = [int(e.text or 0) for e in root.iterfind(".//f:segment_size", NS)]
    assert sizes == [SEGMENT_BYTES]
    # room for two 3840x2160 bgr8 frames
    assert SEGMENT_BYTES >= 2 * 3840 * 2160 * 3
    default = [p for p in root.iterfind("f:participant", NS)
               if p.get("is_default_profile") == "true"]
    assert len(default) == 1


def test_applied_when_nothing_is_set(tmp_path: Path) -> None:
    env: dict[str, str] = {}
    text = use_large_shared_memory(env, cwd=tmp_path)
    assert env == {"FASTDDS_DEFAULT_PROFILES_FILE": str(PROFILE)}
    assert text.startswith("64 MB shared memory")


@pytest.mark.parametrize("env", [
    {"FASTDDS_DEFAULT_PROFILES_FILE": "/etc/mine.xml"},
    {"FASTRTPS_DEFAULT_PROFILES_FILE": "/etc/mine.xml"},
    {"FASTDDS_BUILTIN_TRANSPORTS": "LARGE_DATA"},
    {"RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"},
    {"ARTCAL_FASTDDS_PROFILE": "0"},
])
def test_the_users_choice_is_kept(tmp_path: Path, env: dict[str, str]) -> None:
    before = dict(env)
    text = use_large_shared_memory(env, cwd=tmp_path)
    assert env == before
    assert text.startswith("the user's") and next(iter(before)) in text


def test_a_profile_in_the_working_directory_is_kept(tmp_path: Path) -> None:
    (tmp_path / "DEFAULT_FASTDDS_PROFILES.xml").write_text("<profiles/>")
    env: dict[str, str] = {"RMW_IMPLEMENTATION": "rmw_fastrtps_cpp"}
    assert "DEFAULT_FASTDDS_PROFILES.xml" in use_large_shared_memory(env, cwd=tmp_path)
    assert "FASTDDS_DEFAULT_PROFILES_FILE" not in env


def test_skipped_when_shared_memory_is_too_small(tmp_path: Path) -> None:
    # a shared-memory directory that cannot be read counts as no room at all
    env: dict[str, str] = {}
    text = use_large_shared_memory(env, cwd=tmp_path, shm_dir=tmp_path / "absent")
    assert env == {} and "MB free" in text
