"""A camera showing markers that are not the configured board's gets a named answer.

Rendered frames of a board from another dictionary, then of one with other ids, are sent
to a node configured for the default board: the diagnostics (WARN, key ``board mismatch``)
and the ``~/calibrate`` answer say "markers seen, none from the configured board (ids ...,
dictionary ...)" and which markers are in view, instead of a bare "views 0".
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from sensor_msgs.msg import Image
from std_srvs.srv import Trigger

from artcal_ros.core.board import Board
from test.integration.qos import RELIABLE
from test.integration.ros_harness import (
    Probe,
    calibrator_node,
    diagnostics_values,
)
from test.integration.streaming import publish_until

pytestmark = pytest.mark.integration

NAME = "cal_mismatch"
PREFIX = "markers seen, none from the configured board (ids 0..170, dictionary DICT_6X6_1000)"


def rendered(board: Board, seed: int = 2) -> Image:
    from artcal_ros.core.images import numpy_to_image
    from artcal_ros.synth import Camera, Photometry, random_poses, render_view

    cam = Camera.preset("webcam")
    rng = np.random.default_rng(seed)
    rvec, tvec = random_poses(board, cam, 1, rng)[0]
    view = render_view(board, cam, rvec, tvec, photometry=Photometry.clean(), rng=rng)
    fields = numpy_to_image(view.image, encoding="mono8", frame_id="camera")
    fields.pop("header", None)
    return Image(**fields)


def mismatch(diagnostics: list[Any], named: str) -> str:
    text = diagnostics_values(diagnostics, NAME).get("board mismatch", "")
    return text if named in text else ""


def test_foreign_markers_are_named(tmp_path: Path, probe: Probe) -> None:
    node = calibrator_node(tmp_path, NAME)
    diagnostics = probe.collect(DiagnosticArray, "/diagnostics", RELIABLE)
    publisher = probe.node.create_publisher(Image, f"/{NAME}/image", RELIABLE)
    try:
        other_dictionary = rendered(Board(dictionary_name="DICT_4X4_250"))
        text = publish_until(publisher, other_dictionary,
                             lambda: mismatch(diagnostics, "DICT_4X4_250"), 120,
                             "the diagnostics to name DICT_4X4_250")
        assert text.startswith(PREFIX), text
        warned = [st for array in list(diagnostics) for st in array.status
                  if st.name.startswith(f"{NAME}:") and st.level == DiagnosticStatus.WARN]
        assert any(PREFIX in st.message for st in warned)
        answer = probe.call(Trigger, f"/{NAME}/calibrate")
        assert not answer.success and "not enough views" in answer.message
        assert PREFIX in answer.message and "DICT_4X4_250" in answer.message, answer.message

        other_ids = rendered(Board(first_id=400))
        text = publish_until(publisher, other_ids,
                             lambda: mismatch(diagnostics, "DICT_6X6_1000 ids 4"), 120,
                             "the diagnostics to name the ids outside the board")
        assert text.startswith(PREFIX) and "board.first_id" in text, text
        assert int(diagnostics_values(diagnostics, NAME)["views"]) == 0
    finally:
        probe.node.destroy_publisher(publisher)
    assert node.stop() == 0
