"""Minimisers of Π at one load factor on one discretisation and what a minimisation changes
and saves: Adam and L-BFGS over a field's parameters (`minimisers`), the one Newton over a
dense or sparse linearisation (`newton`, `linearisation`, `assembly`, `linear_solve`,
`multigrid`, `last_layer`, `sensitivity`), the state, checkpoints, backoff and callbacks of a
solve, and the one continuation loop over grid levels × load steps (`continuation`,
`refinement`)."""
