"""Command-line entry points (`ndf-sim`, `ndf-export`, `ndf-validate`)."""
