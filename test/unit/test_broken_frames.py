"""Broken frames by cause: one cause per kind of fault, whatever its numbers; counted per
cause; the first of each cause flagged (the node logs only that one)."""

from __future__ import annotations

import numpy as np
import pytest

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
    error = ImageFormatError("data has 7 bytes")
    error.cause = "short data"  # type: ignore[attr-defined]
    assert broken_cause(error) == "short data"


def test_tally_counts_per_cause_and_flags_the_first() -> None:
    tally = BrokenTally()
    firsts = [tally.add(c) for c in ["a", "b", "a", "a", "c", "b"]]
    assert firsts == [True, True, False, False, True, False]
    assert tally.counts() == {"a": 3, "b": 2, "c": 1} and tally.total() == 6
    assert tally.summary() == "a: 3; b: 2; c: 1"
    assert np.all(np.array(list(tally.counts().values())) > 0)
