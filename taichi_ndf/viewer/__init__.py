"""Interactive web viewer of runs (viser, the optional [viewer] extra; imported lazily)."""
