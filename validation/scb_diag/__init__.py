"""Diagnostic scripts of the SCB near-tip study (validation/results/scb.md)."""
