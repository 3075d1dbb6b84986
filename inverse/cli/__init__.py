"""Command-line tools of the inverse package."""
