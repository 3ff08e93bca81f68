"""One camera stream, live: what the node does with each frame before a solve.

- :mod:`.stream`: the two tiers (every frame tracked, new views detected precisely in the
  background); :mod:`.tracking` the fast tier's marker tracker.
- :mod:`.coverage`: the view collection (novelty, coverage, readiness); :mod:`.view_geometry`
  the one view geometry the collection and the solve both judge by.
- :mod:`.overlay`: the overlay and coverage heat map images; :mod:`.board_mismatch`: a
  stream that shows another board than the configured one.
- :mod:`.saved_session`: the collected views on disk (``resume``).
"""
