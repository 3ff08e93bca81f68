"""One module per ``artcal`` verb: ``add_arguments(parser)`` and ``run(args) -> int``."""
