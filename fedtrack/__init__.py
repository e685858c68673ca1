"""fedtrack: shared plumbing (CLI, config, I/O formats, progress, wire protocol)."""

__version__ = "0.1.0"
