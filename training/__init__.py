"""Compact torch training package for TERL, its baselines and ablations."""
