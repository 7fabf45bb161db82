"""The package version, in one place (read by the package, checkpoints and exports)."""

__version__ = "0.1.0"
