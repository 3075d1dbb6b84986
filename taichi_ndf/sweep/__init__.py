"""Studies: one job run at many parameter points, resumable, on a local pool or on Ray.

`study` reads study files, `points` and `naming` make the points and their run directories'
names, `jobs` turns a point into a tool's command line and its outputs into numbers, `run`
runs one point, `pool` and `ray_engine` run many, `table` keeps the results table, `plot`
draws the summary. The command line is `ndf-sweep` (`taichi_ndf.cli.sweep`); docs/sweeps.md.
"""
