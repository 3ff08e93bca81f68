"""Broken frames by cause: one cause per kind of fault, whatever its numbers; counted per
cause; the first of each cause flagged (the node logs only that one)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from artcal_ros.cli.skipped import SkippedFrames, read_image_file
from artcal_ros.core.errors import ImageFormatError
from artcal_ros.core.images import image_to_numpy
from artcal_ros.core.images.broken_frames import BrokenTally, broken_cause


class Msg:
    def __init__(self, **fields: object) -> None:
        base = {"height": 4, "width": 6, "encoding": "mono8", "is_bigendian": 0, "step": 6,
                "data": bytes(24)}
        base.update(fields)
        self.__dict__.update(base)


def cause_of(msg: Msg) -> str:
    with pytest.raises(ImageFormatError) as e:
        image_to_numpy(msg)
    return broken_cause(e.value)


def test_one_cause_per_kind_of_fault_whatever_the_numbers() -> None:
    assert image_to_numpy(Msg()).shape == (4, 6)
    short = {cause_of(Msg(data=bytes(n))) for n in (3, 10, 23)}
    assert len(short) == 1 and not any(c.isdigit() for c in next(iter(short)))
    steps = {cause_of(Msg(step=s)) for s in (1, 5)}
    assert len(steps) == 1 and "mono8" in next(iter(steps)), steps
    encodings = {cause_of(Msg(encoding=e)) for e in ("yuv_weird", "abc")}
    assert len(encodings) == 2, encodings  # each unknown encoding is named
    assert all("supported" not in c for c in encodings)  # the long list is dropped
    assert len(short | steps | encodings) == 4


def test_a_cause_attribute_wins() -> None:
    assert broken_cause(ImageFormatError("data has 7 bytes", cause="short data")) == "short data"


def test_tally_counts_per_cause_and_flags_the_first() -> None:
    tally = BrokenTally()
    firsts = [tally.add(c) for c in ["a", "b", "a", "a", "c", "b"]]
    assert firsts == [True, True, False, False, True, False]
    assert tally.counts() == {"a": 3, "b": 2, "c": 1} and tally.total() == 6
    assert tally.summary() == "a: 3; b: 2; c: 1"
    assert np.all(np.array(list(tally.counts().values())) > 0)


def test_the_cli_and_the_node_count_the_same_causes() -> None:
    errors: list[ImageFormatError] = []
    for msg in (Msg(data=bytes(3)), Msg(data=bytes(10)), Msg(step=5), Msg(encoding="yuv_weird"),
                Msg(data=bytes(23))):
        with pytest.raises(ImageFormatError) as e:
            image_to_numpy(msg)
        errors.append(e.value)
    node = BrokenTally()
    cli = SkippedFrames()
    for error in errors:
        node.add(broken_cause(error))
        cli.add(error)
    assert node.total() == cli.count == 5 and len(node.counts()) == 3
    short = broken_cause(errors[0])
    assert cli.summary().startswith(f"skipped 5 broken frames: 3 {short}; ")
    for cause in node.counts():
        assert cause in cli.summary()


def test_an_unreadable_file_is_its_own_cause_named_as_given(tmp_path: Path) -> None:
    names = [tmp_path / "0001.png", tmp_path / "0002.png"]
    cli = SkippedFrames()
    for name in names:
        name.write_bytes(b"not an image")
        with pytest.raises(ImageFormatError) as e:
            read_image_file(str(name))
        cli.add(e.value)
    assert cli.count == 2
    for name in names:  # the numbers of a file name are kept
        assert f"1 cannot read image {name}: not an image OpenCV can decode" in cli.summary()
