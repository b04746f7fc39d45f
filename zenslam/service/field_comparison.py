"""Where two protobuf messages of one type differ: field by field, and element by element inside arrays.

Fields are visited in field-number order, repeated fields and the arrays that travel in bytes
fields (decoded with their element type and row shape by ``codec.array_field``) element by
element in row-major order, so the first difference is named down to one value, e.g.
``p_world[1372][0]``, with both values.

Exact comparison (no tolerance) asks for the same bits: -0.0 differs from 0.0, NaN equals NaN.
With a tolerance X, two floating-point values r (recorded) and p (replayed) agree when
``|r - p| <= X * max(1, |r|)``: X is an absolute bound for values of magnitude up to 1 and a
relative one above; NaN agrees only with NaN and an infinity only with itself. Integers, ids,
strings, enums, booleans and byte arrays (descriptors) must always be equal. Within tolerance,
the largest scaled deviation ``|r - p| / max(1, |r|)`` is kept so a report can say how close
the two were.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from google.protobuf.descriptor import FieldDescriptor
from google.protobuf.message import Message

from zenslam.schemas import codec

_SHOWN_CHARS = 60  # characters of a differing value shown in a report
ABSENT = "absent"


@dataclass(frozen=True)
class FieldDifference:
    """One value that differs: its path (``keyframes[2].T_world_cam.tx``, ``p_world[4][1]``) and both values."""

    path: str
    recorded: str
    replayed: str


@dataclass(frozen=True)
class Deviation:
    """A floating-point value that differs within tolerance, with its scaled deviation |r - p| / max(1, |r|)."""

    scaled: float
    difference: FieldDifference


@dataclass(frozen=True)
class MessageComparison:
    """The first difference beyond tolerance (None: the messages agree) and the largest deviation within it."""

    difference: FieldDifference | None = None
    largest: Deviation | None = None


def show(value: object) -> str:
    """A value as a report shows it: shortest round-trip digits for floats of either width, shortened text."""
    text = str(value) if isinstance(value, np.generic) else repr(value)
    return text if len(text) <= _SHOWN_CHARS else text[: _SHOWN_CHARS - 3] + "..."


class _Walk:
    """One comparison of two messages; keeps the largest deviation within tolerance it passes."""

    def __init__(self, tolerance: float | None):
        self.tolerance = tolerance
        self.largest: Deviation | None = None

    def _offer(self, scaled: float, path: str, recorded: object, replayed: object) -> None:
        if self.largest is None or scaled > self.largest.scaled:
            self.largest = Deviation(scaled, FieldDifference(path, show(recorded), show(replayed)))

    def scalar(self, path: str, a: object, b: object) -> FieldDifference | None:
        if isinstance(a, float) and isinstance(b, float):
            if (a == b and math.copysign(1.0, a) == math.copysign(1.0, b)) or (math.isnan(a) and math.isnan(b)):
                return None
            if self.tolerance is not None and math.isfinite(a) and math.isfinite(b):
                scaled = abs(a - b) / max(1.0, abs(a))
                if scaled <= self.tolerance:
                    self._offer(scaled, path, a, b)
                    return None
        elif a == b:
            return None
        return FieldDifference(path, show(a), show(b))

    def array(self, path: str, a: np.ndarray, b: np.ndarray) -> FieldDifference | None:
        """The first element, row-major, where two arrays differ; an element only one side has is 'absent'."""
        if a.dtype != b.dtype or a.shape[1:] != b.shape[1:]:
            a, b = np.frombuffer(a.tobytes(), np.uint8), np.frombuffer(b.tobytes(), np.uint8)
        n, row_size = min(len(a), len(b)), int(np.prod(a.shape[1:]))
        head_a, head_b = a[:n].reshape(n * row_size), b[:n].reshape(n * row_size)
        bad = self._float_mismatch(head_a, head_b, path, a.shape[1:]) if a.dtype.kind == "f" else head_a != head_b
        flat = np.flatnonzero(bad)
        if flat.size:
            return FieldDifference(_element(path, a.shape[1:], int(flat[0])), show(head_a[flat[0]]), show(head_b[flat[0]]))
        if len(a) != len(b):
            first = (a if len(a) > len(b) else b)[n].reshape(-1)[0]
            recorded, replayed = (show(first), ABSENT) if len(a) > len(b) else (ABSENT, show(first))
            return FieldDifference(_element(path, a.shape[1:], n * row_size), recorded, replayed)
        return None

    def _float_mismatch(self, a: np.ndarray, b: np.ndarray, path: str, row_shape: tuple[int, ...]) -> np.ndarray:
        """Which elements of two flat float arrays differ beyond tolerance (bitwise without one)."""
        bits = np.dtype(f"<u{a.dtype.itemsize}")
        differ = (a.view(bits) != b.view(bits)) & ~(np.isnan(a) & np.isnan(b))
        if self.tolerance is None or not differ.any():
            return differ
        r, p = a.astype(np.float64), b.astype(np.float64)
        with np.errstate(invalid="ignore", over="ignore"):
            scaled = np.where(differ, np.abs(r - p) / np.maximum(1.0, np.abs(r)), 0.0)
        beyond = differ & ~(scaled <= self.tolerance)  # NaN against a number, or an infinity, is beyond
        within = np.flatnonzero(differ & ~beyond)
        if within.size:
            worst = int(within[np.argmax(scaled[within])])
            self._offer(float(scaled[worst]), _element(path, row_shape, worst), a[worst], b[worst])
        return beyond

    def repeated(self, path: str, fd: FieldDescriptor, a: Sequence, b: Sequence) -> FieldDifference | None:
        for i, (x, y) in enumerate(zip(a, b)):
            found = self.message(x, y, f"{path}[{i}].") if fd.message_type is not None else self.scalar(f"{path}[{i}]", x, y)
            if found is not None:
                return found
        if len(a) != len(b):
            i = min(len(a), len(b))

            def present(values: Sequence) -> str:
                if i >= len(values):
                    return ABSENT
                return f"a {fd.message_type.name}" if fd.message_type is not None else show(values[i])

            return FieldDifference(f"{path}[{i}]", present(a), present(b))
        return None

    def message(self, a: Message, b: Message, prefix: str = "") -> FieldDifference | None:
        for fd in sorted(a.DESCRIPTOR.fields, key=lambda f: f.number):
            found = self.field(a, b, fd, prefix + fd.name)
            if found is not None:
                return found
        return None

    def field(self, a: Message, b: Message, fd: FieldDescriptor, path: str) -> FieldDifference | None:
        va, vb = getattr(a, fd.name), getattr(b, fd.name)
        if fd.message_type is not None and fd.message_type.GetOptions().map_entry:
            da, db = dict(va), dict(vb)
            for key in sorted(set(da) | set(db)):
                where = f"{path}[{key!r}]"
                if key not in da or key not in db:
                    return FieldDifference(where, show(da.get(key, ABSENT)), show(db.get(key, ABSENT)))
                found = self.scalar(where, da[key], db[key])
                if found is not None:
                    return found
            return None
        if fd.is_repeated:
            return self.repeated(path, fd, va, vb)
        if fd.has_presence and a.HasField(fd.name) != b.HasField(fd.name):
            return FieldDifference(path, "set" if a.HasField(fd.name) else "unset", "set" if b.HasField(fd.name) else "unset")
        if fd.message_type is not None:
            return self.message(va, vb, path + ".")
        if fd.type == fd.TYPE_BYTES:
            return None if va == vb else self.array(path, codec.array_field(a, fd.name), codec.array_field(b, fd.name))
        if fd.enum_type is not None and va != vb:
            return FieldDifference(path, _enum_name(fd, va), _enum_name(fd, vb))
        return self.scalar(path, va, vb)


def _enum_name(fd: FieldDescriptor, number: int) -> str:
    value = fd.enum_type.values_by_number.get(number)
    return value.name if value is not None else str(number)


def _element(path: str, row_shape: tuple[int, ...], flat_index: int) -> str:
    """``path[row][i][j]`` of element ``flat_index`` of a row-major array whose rows have ``row_shape``."""
    row, within = divmod(flat_index, int(np.prod(row_shape)))
    index = (row, *np.unravel_index(within, row_shape)) if row_shape else (row,)
    return path + "".join(f"[{int(i)}]" for i in index)


def compare_messages(a: Message, b: Message, tolerance: float | None = None) -> MessageComparison:
    """The first field where two messages of one type differ (beyond ``tolerance``, see the module
    docstring; None: exactly) and the largest deviation within tolerance."""
    walk = _Walk(tolerance)
    return MessageComparison(walk.message(a, b), walk.largest)


def bytes_difference(path: str, a: bytes, b: bytes) -> FieldDifference | None:
    """The first differing byte of two undecodable payloads, as ``path[i]`` with both byte values."""
    return _Walk(None).array(path, np.frombuffer(a, np.uint8), np.frombuffer(b, np.uint8))
