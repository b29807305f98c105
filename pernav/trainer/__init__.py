"""Training: per-round replay buffers and the Follow-The-Meta-Leader meta-trainer."""

from pernav.trainer.buffers import RoundBuffers

__all__ = ["RoundBuffers"]
