"""Synthetic but physically faithful scenarios whose truth is known."""
