"""Analyses of identified models and logged runs (Theorem 1 bound, figures)."""
