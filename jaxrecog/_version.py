"""The package version (its own module: read without importing the package's names)."""

__version__ = "0.1.0"
