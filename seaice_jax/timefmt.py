"""ISO 8601 UTC times: dates in files are ISO 8601; times inside are seconds from a stated epoch (DESIGN.md)."""

from datetime import UTC, datetime

import numpy as np


def parse_time(text: str) -> datetime:
    """An ISO 8601 date-time (``Z`` or an offset; naive means UTC) as an aware UTC datetime."""
    moment = datetime.fromisoformat(text.strip().replace("Z", "+00:00"))
    return (moment if moment.tzinfo else moment.replace(tzinfo=UTC)).astimezone(UTC)


def format_time(moment: datetime) -> str:
    """ISO 8601 UTC (``YYYY-MM-DDTHH:MM:SSZ``) of an aware datetime."""
    return moment.astimezone(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def time_after(epoch: str, seconds: float) -> str:
    """ISO 8601 UTC of ``seconds`` after ``epoch`` (ISO 8601)."""
    return format_time(datetime.fromtimestamp(parse_time(epoch).timestamp() + float(seconds), UTC))


def seconds_since(epoch: str, times) -> np.ndarray:
    """Seconds from ``epoch`` (ISO 8601) of datetimes."""
    origin = parse_time(epoch)
    return np.array([(t - origin).total_seconds() for t in times], float)
