"""The ``artcal`` command: :mod:`.main` parses the verb; one module per verb (board, synth,
detect, calibrate)."""
