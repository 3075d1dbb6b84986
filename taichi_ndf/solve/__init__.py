"""Solve drivers: continuation over load steps and grid levels, and the estimates that solve."""
