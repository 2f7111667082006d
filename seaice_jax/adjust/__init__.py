"""Estimation: one weighted least-squares engine and its quality control."""
