"""Scene reading: TOML into a plain specification, solving nothing."""
