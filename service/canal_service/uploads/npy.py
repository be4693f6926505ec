"""NumPy ``.npy`` uploads: the header checked against the data before any allocation."""

from __future__ import annotations

import io
import math

import numpy as np

from canal_protocol.codecs.csv_table import InvalidCsv, table_split_by_time

from ..errors import BadUpload, InvalidInput
from .common import NPY_MAGIC, Budget, ParsedUpload, UploadLimits


def parse_npy(data: bytes, dim: int, budget: Budget | None = None) -> ParsedUpload:
    """A ``.npy`` array of real numbers; never unpickles, never allocates more than the data."""
    from numpy.lib import format as npformat

    budget = budget or Budget(UploadLimits())
    if not data.startswith(NPY_MAGIC):
        raise BadUpload("not a .npy file (missing the \\x93NUMPY magic)", field="file")
    stream = io.BytesIO(data)
    try:
        version = npformat.read_magic(stream)
        if version == (1, 0):
            shape, _fortran, dtype = npformat.read_array_header_1_0(stream)
        elif version == (2, 0):
            shape, _fortran, dtype = npformat.read_array_header_2_0(stream)
        else:
            raise BadUpload(f"unsupported .npy format version {version}", field="file")
    except BadUpload:
        raise
    except Exception as exc:  # hostile header: any parser failure is a bad upload
        raise BadUpload(f"unreadable .npy header: {exc}", field="file") from exc
    if dtype.hasobject or dtype.kind not in "fiu" or dtype.fields is not None:
        raise BadUpload(f"expected a .npy array of real numbers, got dtype {dtype}", field="file")
    if any(not isinstance(n, int) or n < 0 for n in shape):
        raise BadUpload(f"expected a .npy shape of counts, got {shape!r}", field="file")
    # Python integers: a hostile header's shape need not fit 64 bits
    count = math.prod(shape)
    if count * dtype.itemsize != len(data) - stream.tell():
        raise BadUpload(
            f".npy header promises {count * dtype.itemsize} data bytes, file has "
            f"{len(data) - stream.tell()}",
            field="file",
        )
    if shape:
        budget.points(int(shape[0]), "the .npy array")
    try:
        array = np.load(io.BytesIO(data), allow_pickle=False)
    except Exception as exc:  # same reason as above
        raise BadUpload(f"unreadable .npy data: {exc}", field="file") from exc
    try:
        return table_split_by_time(np.asarray(array, dtype=np.float64), dim)
    except InvalidCsv as exc:  # the shape rule a headerless CSV follows too
        raise InvalidInput(exc.message, field=exc.field) from exc
