"""CSV uploads: :mod:`canal_protocol.codecs.csv_table` (the reader the command line's
corrections use too) with this upload's budget, its errors as the service's."""

from __future__ import annotations

from canal_protocol.codecs.csv_table import InvalidCsv, UnreadableCsv, csv_table

from ..errors import BadUpload, InvalidInput
from .common import Budget, ParsedUpload, UploadLimits


def parse_csv(data: bytes, dim: int, budget: Budget | None = None) -> ParsedUpload:
    """The demonstration of a CSV upload; numpy stops one row past the points limit, so a
    huge file costs at most that much."""
    budget = budget or Budget(UploadLimits())
    try:
        table = csv_table(data, dim, max_rows=budget.limits.max_points + 1)
    except UnreadableCsv as exc:
        raise BadUpload(exc.message, field=exc.field) from exc
    except InvalidCsv as exc:
        raise InvalidInput(exc.message, field=exc.field) from exc
    budget.tick()
    budget.points(table.positions.shape[0], "the CSV file")
    return table
