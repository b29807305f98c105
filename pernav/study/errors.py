"""Errors of the study that the CLI reports in one line (exit code 2)."""


class CheckpointError(RuntimeError):
    """A checkpoint is missing, partial or corrupted (the message names the file)."""
