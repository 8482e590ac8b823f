"""Drivers that reproduce the paper's figures from `jaml.stream` / `jaml.relations` runs."""
