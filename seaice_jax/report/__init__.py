"""Presentation: figures (PNG, matplotlib) and text reports of results computed by the layers below."""
