"""The problem and its plain specifications: model, loads, operator, scales."""
