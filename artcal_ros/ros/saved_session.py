"""The calibrator's saved session, wired to a node: restore or announce at start, log."""

from __future__ import annotations

import threading

from rclpy.node import Node

from artcal_ros.core.board import Board
from artcal_ros.core.live.coverage import ViewCollector
from artcal_ros.core.live.saved_session import (
    FILE_NAME,
    SessionSource,
    SessionStore,
    session_dir,
)
from artcal_ros.core.params import ParamValue


def open_session(node: Node, board: Board, collector: ViewCollector,
                 params: dict[str, ParamValue], stopping: threading.Event) -> SessionStore:
    """The session store of ``camera_name``: restored into ``collector`` when ``resume`` is
    true, saving in the background from now on (warnings logged unless ``stopping``).

    Raises:
        SessionMismatchError: ``resume`` of a session saved from another board or image
            topic (the node refuses to start).
    """
    log = node.get_logger()

    def warn(text: str) -> None:
        if not stopping.is_set():
            log.warning(text)

    camera_name = str(params["camera_name"])
    source = SessionSource(camera_name, node.resolve_topic_name("image"), board.describe())
    store = SessionStore(session_dir(camera_name) / FILE_NAME, board, collector, warn=warn,
                         source=source)
    for line in store.open(resume=bool(params["resume"])):
        if line.startswith("WARN: "):
            log.warning(line.removeprefix("WARN: "))
        else:
            log.info(line)
    store.start()
    return store
