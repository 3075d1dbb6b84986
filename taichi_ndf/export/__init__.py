"""Runs converted to interchange formats (USD); optional dependencies are imported lazily."""
