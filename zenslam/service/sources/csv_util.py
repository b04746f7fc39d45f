"""Small text-table helpers shared by the dataset readers: rows, exact stamps, stamp association."""

from __future__ import annotations

from dataclasses import dataclass
from decimal import ROUND_HALF_EVEN, Decimal, InvalidOperation
from pathlib import Path

import numpy as np

from zenslam.errors import DatasetError, TimestampError


@dataclass(frozen=True)
class Row:
    """One data line of a text table: its 1-based line number and its fields."""

    line: int
    fields: list[str]


def read_rows(path: Path, what: str, min_columns: int, sep: str | None = None) -> list[Row]:
    """Data rows of a text table, skipping blank lines and ``#`` comments.

    ``sep`` is "," for CSV or None for whitespace. ``what`` names the file's role in errors.
    Every row must have at least ``min_columns`` fields.
    """
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{what} {path} does not exist; check the dataset folder is complete")
    rows: list[Row] = []
    with path.open("r", encoding="utf-8", errors="replace") as handle:
        for number, text in enumerate(handle, start=1):
            text = text.strip()
            if not text or text.startswith("#"):
                continue
            fields = text.split() if sep is None else [f.strip() for f in text.split(sep)]
            if len(fields) < min_columns:
                raise DatasetError(
                    f"{what} {path}, line {number}: expected at least {min_columns} fields, got {len(fields)} "
                    f"({text[:80]!r}); fix or remove the line"
                )
            rows.append(Row(number, fields))
    return rows


def _to_decimal(text: str, path: Path, line: int) -> Decimal:
    try:
        value = Decimal(text)
    except InvalidOperation:
        raise TimestampError(f"{path}, line {line}: timestamp {text!r} is not a number") from None
    if not value.is_finite():
        raise TimestampError(f"{path}, line {line}: timestamp {text!r} is not finite")
    return value


def parse_ns(text: str, path: Path, line: int) -> int:
    """An integer-nanosecond stamp, exactly; a fractional part such as ``.0000`` is rounded away."""
    try:
        return int(text)
    except ValueError:
        pass
    value = _to_decimal(text, path, line)
    return int(value.to_integral_value(rounding=ROUND_HALF_EVEN))


def parse_seconds_ns(text: str, path: Path, line: int) -> int:
    """A stamp written in seconds (``1305031102.175304`` or ``1.044989e-01``) as integer ns, exactly."""
    value = _to_decimal(text, path, line) * Decimal(1_000_000_000)
    return int(value.to_integral_value(rounding=ROUND_HALF_EVEN))


def parse_floats(fields: list[str], path: Path, line: int) -> np.ndarray:
    """The fields as float64; a DatasetError naming the file and line when one is not a number."""
    try:
        return np.array([float(f) for f in fields], dtype=np.float64)
    except ValueError:
        raise DatasetError(f"{path}, line {line}: expected numbers, got {fields}; fix or remove the line") from None


def parse_float_table(rows: list[Row], first: int, count: int, path: Path) -> np.ndarray:
    """Fields ``first .. first + count - 1`` of every row as a float64 array (len(rows), count)."""
    try:
        return np.array([r.fields[first : first + count] for r in rows], dtype=np.float64).reshape(-1, count)
    except ValueError:
        for row in rows:  # find the offending line for the message
            parse_floats(row.fields[first : first + count], path, row.line)
        raise


def check_increasing(stamps_ns: np.ndarray, lines: list[int], path: Path) -> None:
    """Raise TimestampError naming the file and line where ``stamps_ns`` stops strictly increasing."""
    stamps_ns = np.asarray(stamps_ns, dtype=np.int64)
    if len(stamps_ns) < 2:
        return
    bad = np.flatnonzero(np.diff(stamps_ns) <= 0)
    if bad.size:
        i = int(bad[0])
        raise TimestampError(
            f"timestamps in {path} must strictly increase: line {lines[i + 1]} ({stamps_ns[i + 1]} ns) follows "
            f"line {lines[i]} ({stamps_ns[i]} ns); sort the file or remove the duplicate"
        )


def format_seconds(stamp_ns: int) -> str:
    """A non-negative ns stamp as seconds with 6 decimals (the TUM text format), truncating below 1 us."""
    stamp_ns = int(stamp_ns)
    if stamp_ns < 0:
        raise TimestampError(f"stamp {stamp_ns} ns is negative; the TUM text format needs stamps >= 0")
    return f"{stamp_ns // 1_000_000_000}.{(stamp_ns % 1_000_000_000) // 1000:06d}"


def associate_stamps(a_ns: np.ndarray, b_ns: np.ndarray, max_difference_ns: int) -> tuple[np.ndarray, np.ndarray]:
    """One-to-one matches between two sorted stamp lists, like TUM's ``associate.py``.

    Candidate pairs are those with |a - b| <= max_difference_ns; they are taken greedily by smallest
    difference (ties by a index, then b index) so each stamp is used at most once. Returns index
    arrays (ia, ib), ordered by ia.
    """
    a = np.asarray(a_ns, dtype=np.int64)
    b = np.asarray(b_ns, dtype=np.int64)
    if a.size == 0 or b.size == 0:
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty
    # Both lists are sorted, so each a has a contiguous window of candidates in b.
    lo = np.searchsorted(b, a - max_difference_ns, side="left")
    hi = np.searchsorted(b, a + max_difference_ns, side="right")
    counts = hi - lo
    ia = np.repeat(np.arange(a.size), counts)
    starts = np.repeat(lo - np.concatenate(([0], np.cumsum(counts)[:-1])), counts)
    ib = np.arange(ia.size) + starts
    diff = np.abs(a[ia] - b[ib])
    order = np.lexsort((ib, ia, diff))
    used_a = np.zeros(a.size, dtype=bool)
    used_b = np.zeros(b.size, dtype=bool)
    pairs: list[tuple[int, int]] = []
    for k in order:
        i, j = int(ia[k]), int(ib[k])
        if not used_a[i] and not used_b[j]:
            used_a[i] = used_b[j] = True
            pairs.append((i, j))
    pairs.sort()
    out = np.array(pairs, dtype=np.int64).reshape(-1, 2)
    return out[:, 0], out[:, 1]
