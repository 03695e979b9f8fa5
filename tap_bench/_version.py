"""The version of tap-bench (one place: the package root and the results that record it
read it from here)."""

__version__ = "0.1.0"
