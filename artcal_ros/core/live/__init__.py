"""One camera stream, live: what the node does with each frame before a solve.

- :mod:`.stream`: the two tiers (every frame tracked, new views detected precisely in the
  background); :mod:`.tracking` the fast tier's marker tracker.
- :mod:`.coverage`: the view collection (novelty, coverage); :mod:`.view_geometry`
  the one view geometry the collection and the solve both judge by.
- :mod:`.live_solve`: the current camera and its projection uncertainty after every new
  view; :mod:`.readiness`: ready or not, and what is missing; :mod:`.guidance`: where to
  hold the board next; :mod:`.live_status`: those three for the node, off its threads.
- :mod:`.overlay`: the overlay and coverage heat map images; :mod:`.board_mismatch`: a
  stream that shows another board than the configured one.
- :mod:`.saved_session`: the collected views on disk (``resume``).
- A rig: :mod:`.rig_frames` pairs the cameras' frames by stamp, :mod:`.rig_views` collects
  rig views, :mod:`.rig_stream` runs the two tiers for every camera.
"""
