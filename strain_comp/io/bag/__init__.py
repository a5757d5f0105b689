"""MCAP bag I/O: ``read_bag`` (reader), ``BagWriter`` (writer), contents and schemas."""

from strain_comp.io.bag.reader import iter_bag, located, read_bag
from strain_comp.io.bag.schemas import SCHEMAS, BagContents, Series, Status
from strain_comp.io.bag.writer import BagWriter

__all__ = ["SCHEMAS", "BagContents", "BagWriter", "Series", "Status", "iter_bag", "located",
           "read_bag"]
