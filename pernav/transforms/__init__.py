"""TorchRL transforms: :class:`HistoryWindow`, the stateless window of the last K (state, action) pairs."""

from pernav.transforms.history import HistoryWindow

__all__ = ["HistoryWindow"]
