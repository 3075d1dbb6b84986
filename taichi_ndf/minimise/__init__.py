"""Minimisers of Π over a local-support (spline) displacement field: sparse assembly of the
gradient and Hessian over the coefficients, projected Newton, refinement studies."""
