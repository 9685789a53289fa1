"""hdt's version: a leaf, so that every module that records it (checkpoints, run markers, zoo entries)
reads it without importing the package. pyproject.toml reads it from here too."""

__version__ = "0.2.0"
