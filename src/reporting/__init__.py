"""Reporting: the published numbers of both papers and the result tables printed by eval."""

from src.reporting.published import (
    PublishedRow,
    ReportingError,
    find_published,
    load_published,
    published_table,
)
from src.reporting.tables import AVERAGE, ResultTable, results_from_metric

__all__ = [
    "AVERAGE",
    "PublishedRow",
    "ReportingError",
    "ResultTable",
    "find_published",
    "load_published",
    "published_table",
    "results_from_metric",
]
