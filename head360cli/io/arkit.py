"""ARKit-52 blendshape streams: read, validate, resample, smooth and write CSV files.

Formats read (columns are always matched by name, never by position):

- Live Link Face CSV: ``Timecode,BlendshapeCount`` (or ``BlendShapeCount``), the 52
  capitalised names (``EyeBlinkLeft``) in the app's own order, then 9 rotation columns
  (``HeadYaw ... RightEyeRoll``, radians). Timecodes are ``HH:MM:SS:FF.fff``: frame ``FF``
  at the nominal rate plus a sub-frame fraction.
- MediaPipe/ARKit-named CSV: ``eyeBlinkLeft`` ..., optionally ``_neutral`` (ignored).
- Generic CSV: any subset of the names in any common spelling (see
  :func:`head360cli.mesh.arkit52.canonical_name`); missing shapes are zero, with one
  warning. An optional time column: ``time``/``timestamp``/``seconds``/``t`` (seconds),
  ``time_ms``/``timestamp_ms`` (milliseconds) or ``frame`` (frame number).

Cells are separated by commas; a header without a comma but with semicolons or tabs
sets that separator instead, and then a decimal comma (``0,5``) reads as a point, as
spreadsheets in such locales save them.

Bad cells (NaN, inf, empty, non-numeric) and rows with the wrong number of cells follow
a policy: ``error`` (default: a :class:`~head360cli.errors.BadInputError` naming the line),
``skip`` (drop the row) or ``hold`` (repeat the previous frame's value; zero for the first
frame). Weights outside [0, 1] are clamped and counted in a warning.
"""

from __future__ import annotations

import codecs
import csv
import dataclasses
import io
import itertools
import math
import re
import sys
from array import array
from collections.abc import Iterable
from pathlib import Path
from typing import IO, TYPE_CHECKING, Literal

import numpy as np

from head360cli.errors import BadInputError, FileFormatError
from head360cli.mesh.arkit52 import (
    ARKIT52,
    INDEX,
    MEDIAPIPE_BLENDSHAPES,
    NUM_BLENDSHAPES,
    canonical_name,
    split_part,
)

if TYPE_CHECKING:
    from head360cli.io.sources import NamedBytes

__all__ = [
    "LIVE_LINK_FACE_ORDER",
    "ROTATION_COLUMNS",
    "ArkitStream",
    "BadCellPolicy",
    "read_arkit_csv",
    "resample",
    "smooth",
    "write_arkit_csv",
]

BadCellPolicy = Literal["error", "skip", "hold"]

STANDARD_RATES = (24.0, 25.0, 30.0, 48.0, 50.0, 60.0, 90.0, 100.0, 120.0, 240.0)
"""Frame rates a timecode's frame field is snapped to."""

NTSC_RATES = (23.976, 29.97, 59.94)
"""NTSC's rates (24, 30 and 60 times 1000/1001), reported as themselves."""

DEFAULT_FPS = 60.0
"""Rate assumed for a stream without any time column (ARKit tracks at 60 Hz)."""

ROTATION_COLUMNS: tuple[str, ...] = (
    "HeadYaw", "HeadPitch", "HeadRoll",
    "LeftEyeYaw", "LeftEyePitch", "LeftEyeRoll",
    "RightEyeYaw", "RightEyePitch", "RightEyeRoll",
)  # fmt: skip
"""Live Link Face rotation columns (radians); head first, then left and right eye."""

_SWAPS = {"jawLeft": "jawRight", "jawRight": "jawLeft", "mouthLeft": "mouthRight",
          "mouthRight": "mouthLeft"}  # fmt: skip
LIVE_LINK_FACE_ORDER: tuple[str, ...] = tuple(
    (n[0].upper() + n[1:]) if n not in _SWAPS else (_SWAPS[n][0].upper() + _SWAPS[n][1:])
    for n in ARKIT52
)
"""Blendshape columns in the order the Live Link Face app writes them: Apple's order with
``JawLeft``/``JawRight`` and ``MouthLeft``/``MouthRight`` swapped."""

_TIMECODE = re.compile(r"^\s*(\d+):(\d{1,2}):(\d{1,2})[:;](\d{1,3})(\.\d+)?\s*$")
_SECONDS_COLUMNS = {"time", "timestamp", "seconds", "t", "time_s", "timestamp_s", "times"}
_MS_COLUMNS = {"time_ms", "timestamp_ms", "ms"}
_FRAME_COLUMNS = {"frame", "frame_index", "frameindex", "frame_number", "index"}
_IGNORED_KNOWN = {"blendshapecount", "_neutral", "neutral"}


_MEDIAPIPE_SHAPES = frozenset(MEDIAPIPE_BLENDSHAPES[1:])
"""The 51 ARKit names MediaPipe's face model scores (all but tongueOut): a file with
exactly these is MediaPipe's layout, written by head360's ``--format mediapipe`` or by
MediaPipe itself."""


@dataclasses.dataclass
class ArkitStream:
    """A stream of ARKit-52 weights with its timing.

    Attributes:
        weights: ``(F, 52)`` float32 weights in [0, 1], columns in :data:`ARKIT52` order.
        timestamps: ``(F,)`` float64 seconds since the first frame, strictly increasing.
        fps: Effective frame rate (frames per second), from the median frame interval.
        head_rotation: ``(F, 3)`` float32 head yaw, pitch, roll in radians, or ``None``.
        eye_rotation: ``(F, 6)`` float32 left then right eye yaw, pitch, roll in radians,
            or ``None``.
        source_format: ``"livelinkface"``, ``"mediapipe"``, ``"arkit"`` or ``"generic"``.
        nominal_fps: The rate the timecodes were written at, when the file says so.
        columns_found: Canonical names of the blendshapes present in the file.
        columns_missing: Canonical names absent from the file (their weights are zero).
        columns_ignored: Headers that were not used (e.g. ``BlendshapeCount``).
        clamped: How many weights were outside [0, 1] and were clamped.
        repaired: How many bad cells the ``hold`` policy replaced.
        skipped_rows: How many rows the ``skip`` policy dropped.
        warnings: Human-readable warnings raised while reading.
    """

    weights: np.ndarray
    timestamps: np.ndarray
    fps: float
    head_rotation: np.ndarray | None = None
    eye_rotation: np.ndarray | None = None
    source_format: str = "generic"
    nominal_fps: float | None = None
    columns_found: list[str] = dataclasses.field(default_factory=list)
    columns_missing: list[str] = dataclasses.field(default_factory=list)
    columns_ignored: list[str] = dataclasses.field(default_factory=list)
    clamped: int = 0
    repaired: int = 0
    skipped_rows: int = 0
    warnings: list[str] = dataclasses.field(default_factory=list)

    @property
    def num_frames(self) -> int:
        """Number of frames ``F``."""
        return int(self.weights.shape[0])

    @property
    def duration(self) -> float:
        """Seconds from the first frame to the end of the last one."""
        if self.num_frames == 0:
            return 0.0
        return float(self.timestamps[-1]) + 1.0 / self.fps

    def weight(self, name: str) -> np.ndarray:
        """``(F,)`` weights of one blendshape, by any spelling of its name."""
        canonical = canonical_name(name)
        if canonical is None:
            raise BadInputError(f"expected an ARKit blendshape name, found {name!r}")
        return self.weights[:, INDEX[canonical]]

    def stats(self) -> dict[str, dict[str, float]]:
        """Min, mean and max of every blendshape, by canonical name."""
        if self.num_frames == 0:
            return {name: {"min": 0.0, "mean": 0.0, "max": 0.0} for name in ARKIT52}
        lo, mean, hi = self.weights.min(0), self.weights.mean(0), self.weights.max(0)
        return {
            name: {"min": float(lo[i]), "mean": float(mean[i]), "max": float(hi[i])}
            for i, name in enumerate(ARKIT52)
        }

    def between(self, start: float | None = None, end: float | None = None) -> ArkitStream:
        """The frames with ``start <= t < end`` (seconds; to a nanosecond, as a video's
        frames are cut), re-timed to start at zero."""
        t = self.timestamps
        keep = np.ones(len(t), dtype=bool)
        if start is not None:
            keep &= t >= start - 1e-9
        if end is not None:
            keep &= t < end - 1e-9
        if not keep.any():
            span = (f"from {start} s" if end is None else f"before {end} s" if start is None
                    else f"from {start} s to {end} s")
            raise BadInputError(
                f"expected frames {span}, found none (the stream lasts {self.duration:.3f} s)"
            )
        return self._take(keep)

    def _take(self, keep: np.ndarray) -> ArkitStream:
        t = self.timestamps[keep]
        return dataclasses.replace(
            self,
            weights=self.weights[keep],
            timestamps=t - t[0],
            head_rotation=None if self.head_rotation is None else self.head_rotation[keep],
            eye_rotation=None if self.eye_rotation is None else self.eye_rotation[keep],
            warnings=list(self.warnings),
        )


# --------------------------------------------------------------------------- reading


def _open_text(source: str | Path | IO[str] | NamedBytes) -> tuple[IO[str], str]:
    from head360cli.io.sources import NamedBytes, existing, read_whole

    if isinstance(source, NamedBytes):  # a pipe's content, read already
        path, raw = source.name, source.getvalue()
    elif not isinstance(source, (str, Path)):
        return source, getattr(source, "name", "<stream>")
    elif str(source) == "-":
        from head360cli.io.sources import check_stdin

        check_stdin("an ARKit stream")
        if not hasattr(sys.stdin, "buffer"):  # a text stream put in its place
            return sys.stdin, "<stdin>"
        # bytes, decoded as a file's are: UTF-16 with a mark, NULs named
        path, raw = "<stdin>", read_whole(sys.stdin.buffer, "<stdin>")
    else:
        path = existing(source, "an ARKit CSV file")
        try:
            raw = read_whole(path, str(path))  # a pipe (<(...)) too: read once, whole
        except OSError as exc:
            raise FileFormatError(f"cannot read {str(path)!r}: {exc.strerror}") from exc
    # Excel's "Unicode text" and other Windows tools write UTF-16 with a byte-order mark
    utf16 = raw.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE))
    try:
        text = raw.decode("utf-16" if utf16 else "utf-8-sig")
    except UnicodeDecodeError as exc:
        raise FileFormatError(
            f"expected a UTF-8 (or UTF-16 with a byte-order mark) text CSV in "
            f"{str(path)!r}, found binary data (byte {exc.start})"
        ) from exc
    if "\x00" in text:  # valid UTF-8, but no CSV has NULs: UTF-16 without its mark
        raise FileFormatError(
            f"expected a UTF-8 (or UTF-16 with a byte-order mark) text CSV in "
            f"{str(path)!r}, found NUL characters (UTF-16 without a byte-order mark?)")
    return io.StringIO(text, newline=""), str(path)  # lines end in \n, \r\n or \r (old Mac)


def _delimiter(first_line: str) -> str:
    """The header line's field separator: a comma, else a semicolon, else a tab.

    Spreadsheets in locales that write decimal commas (0,5) save CSV with semicolons.
    """
    if "," in first_line:
        return ","
    for candidate in (";", "\t"):
        if candidate in first_line:
            return candidate
    return ","


def _parse_timecode(cell: str) -> tuple[int, float] | None:
    """``HH:MM:SS:FF.fff`` -> (whole seconds, frames incl. sub-frame), or None."""
    m = _TIMECODE.match(cell)
    if m is None:
        return None
    h, mi, s, ff = (int(m.group(i)) for i in range(1, 5))
    frac = float(m.group(5)) if m.group(5) else 0.0
    return h * 3600 + mi * 60 + s, ff + frac


def _unsure_rate(parsed: list[tuple[int, float]], nominal: float) -> str | None:
    """The warning for Live Link Face timecodes that cannot tell their rate, else None.

    The rate is read off the largest frame number, which tells it only once the take
    passes a whole second (its frame numbers then reach the top of the rate). A take
    shorter than that whose rows step by whole frames (30 rows cut from a 60 fps take:
    frames 0 to 29) reads as the smallest standard rate above its largest frame, which
    may be too slow. Rows that step by fractions of a frame (head360's own short takes,
    numbered at a rate the reader gives back) keep their times and are not warned about.
    """
    if len(parsed) < 2 or len({whole for whole, _ in parsed}) > 1:
        return None
    frames = np.array([frame for _, frame in parsed], np.float64)
    steps = np.diff(frames)
    if not (np.abs(steps - np.round(steps)) < 0.02).all() or np.median(steps) < 0.5:
        return None
    top = int(frames.max())
    return (f"the stream's timecodes stay within one second (frames {int(frames.min())} to {top}), "
            f"which does not tell its frame rate: read at {nominal:g} fps, the smallest "
            f"standard rate above frame {top}; if it was recorded at another rate (Live "
            f"Link Face records at 60), give it with --stream-fps")


def _to_float(cell: str) -> float:
    try:
        return float(cell)
    except ValueError:
        return math.nan


def read_arkit_csv(
    source: str | Path | IO[str] | NamedBytes,
    *,
    on_bad: BadCellPolicy = "error",
    fps: float | None = None,
) -> ArkitStream:
    """Read an ARKit-52 CSV stream (Live Link Face, MediaPipe-named or generic).

    Args:
        source: A path (a pipe, ``<(...)``, too), ``"-"`` for standard input, an open
            text stream, or a pipe's bytes already read
            (:class:`~head360cli.io.sources.NamedBytes`).
        on_bad: What to do with bad cells and malformed rows: ``"error"``, ``"skip"``
            the row, or ``"hold"`` the previous frame's value.
        fps: Frame rate to assume when the file has no time column (default 60), or the
            rate of a ``frame`` column. Files with seconds ignore it. Live Link Face
            timecodes carry no rate: it is inferred (the next standard rate above the
            largest frame number) unless ``fps`` is given and above that number. Files
            that head360 writes read back right without it, short takes included
            (:func:`write_arkit_csv` numbers those at a rate the inference gives back).

    Returns:
        The stream, with weights clamped to [0, 1] and warnings collected.

    Raises:
        BadInputError: On bad values under the ``error`` policy, on duplicate columns,
            on a file without any blendshape column, or on time going backwards.
        FileFormatError: When the file cannot be read as text.
    """
    if on_bad not in ("error", "skip", "hold"):
        raise BadInputError(f"expected on_bad to be error, skip or hold, found {on_bad!r}")
    if fps is not None and not (math.isfinite(fps) and fps > 0):
        raise BadInputError(f"expected a positive frame rate, found {fps!r}")
    handle, label = _open_text(source)
    first = handle.readline()
    delimiter = _delimiter(first)
    reader = csv.reader(itertools.chain([first] if first else [], handle), delimiter=delimiter)
    decimal_comma = delimiter != ","  # a spreadsheet's export in a locale that writes 0,5
    try:
        header = next(reader)
    except StopIteration:
        raise BadInputError(f"expected a CSV header in {label}, found an empty file") from None
    except csv.Error as exc:
        raise FileFormatError(f"{label}: not a readable CSV ({exc})") from exc
    header = [h.strip() for h in header]
    layout = _Layout.from_header(header, label)
    warnings: list[str] = []

    cols = layout.value_columns
    tcol = layout.time_column
    buf = array("d")  # compact: 8 bytes per value, whatever the stream's length
    time_cells: list[str] = []
    lines: list[int] = []
    first_bad: tuple[int, str, str] | None = None  # line, column name, raw text
    skipped = 0
    held_rows = 0
    previous: list[float] | None = None
    try:
        for row in reader:
            if not row or all(not c.strip() for c in row):
                continue  # blank line
            if decimal_comma:
                row = [c.replace(",", ".") for c in row]
            if len(row) == len(header) + 1 and not row[-1].strip():
                row = row[:-1]  # trailing comma
            if len(row) != len(header):
                message = (
                    f"{label}, line {reader.line_num}: expected {len(header)} cells as in the "
                    f"header, found {len(row)}"
                )
                if on_bad == "error":
                    raise BadInputError(message)
                if on_bad == "skip" or previous is None:
                    skipped += 1
                    continue
                buf.extend(previous)  # hold: repeat the previous row whole
                held_rows += 1
                time_cells.append(row[tcol] if tcol is not None and tcol < len(row) else "")
                lines.append(reader.line_num)
                continue
            floats = [_to_float(row[c]) for c in cols]
            if first_bad is None:
                for c, v in zip(cols, floats, strict=True):
                    if not math.isfinite(v):
                        first_bad = (reader.line_num, header[c], row[c])
                        break
            buf.extend(floats)
            previous = floats
            time_cells.append(row[tcol] if tcol is not None else "")
            lines.append(reader.line_num)
    except csv.Error as exc:
        raise FileFormatError(
            f"{label}, line {reader.line_num}: not a readable CSV ({exc})"
        ) from exc

    values = np.frombuffer(buf, dtype=np.float64).reshape(-1, len(cols)).copy()
    del buf
    bad = ~np.isfinite(values)

    times, time_bad, nominal, rate_note = layout.parse_times(time_cells, fps)
    if rate_note:
        warnings.append(rate_note)
    if time_bad is not None and time_bad.any():
        r = int(np.argmax(time_bad))
        if first_bad is None or lines[r] < first_bad[0]:
            first_bad = (lines[r], header[tcol], time_cells[r])  # type: ignore[index]
        bad = np.concatenate([bad, time_bad[:, None]], axis=1)

    repaired = 0
    if bad.any():
        assert first_bad is not None
        if on_bad == "error":
            line, name, raw = first_bad
            raise BadInputError(
                f"{label}, line {line}, column {name!r}: expected a finite number, "
                f"found {raw!r} (use the skip or hold policy to read past bad cells)"
            )
        if on_bad == "skip":
            keep = ~bad.any(axis=1)
            skipped += int((~keep).sum())
            values = values[keep]
            lines = [ln for ln, k in zip(lines, keep, strict=True) if k]
            times = None if times is None else times[keep]
        else:  # hold
            repaired = int(bad.sum())
            if time_bad is not None and time_bad.any():
                assert times is not None
                times = _fill_times(times, time_bad)
                bad = bad[:, :-1]
            values = _hold(values, bad)
    if skipped:
        warnings.append(f"skipped {skipped} bad row(s) under the skip policy")
    if repaired:
        warnings.append(f"held the previous frame's value for {repaired} bad cell(s)")
    if held_rows:
        warnings.append(
            f"held the previous frame for {held_rows} row(s) whose cells did not match "
            f"the header's {len(header)}"
        )

    n = values.shape[0]
    if n == 0:
        raise BadInputError(f"expected at least one frame in {label}, found none")

    weights = layout.gather_weights(values)
    outside = (weights < 0.0) | (weights > 1.0)
    clamped = int(outside.sum())
    if clamped:
        warnings.append(
            f"clamped {clamped} weight(s) outside [0, 1] (range found "
            f"{weights.min():.4g} to {weights.max():.4g})"
        )
        np.clip(weights, 0.0, 1.0, out=weights)
    missing = list(layout.missing)
    if layout.source_format == "mediapipe" and "tongueOut" in missing:
        missing.remove("tongueOut")  # MediaPipe's face model has none: nothing lost
    if missing:
        warnings.append(
            f"{len(missing)} of 52 blendshapes missing, set to zero: "
            + ", ".join(missing[:6])
            + (" ..." if len(missing) > 6 else "")
        )

    if times is None:
        rate = fps if fps is not None else DEFAULT_FPS
        if fps is None:
            warnings.append(f"no time column; assuming {DEFAULT_FPS:g} fps")
        timestamps = np.arange(n, dtype=np.float64) / rate
    else:
        # checked from zero: times near 2**53 seconds apart lose their steps to rounding
        with np.errstate(over="ignore", invalid="ignore"):  # overflow is checked there
            timestamps = _check_monotonic(times - times[0], lines, label)
        gap = _gap_warning(timestamps, lines)
        if gap:
            warnings.append(gap)
    effective = _effective_fps(timestamps, nominal if nominal else (fps or DEFAULT_FPS))

    head = layout.gather_rotation(values, 0)
    eyes = layout.gather_rotation(values, 1)
    return ArkitStream(
        weights=weights.astype(np.float32),
        timestamps=timestamps,
        fps=effective,
        head_rotation=head,
        eye_rotation=eyes,
        source_format=layout.source_format,
        nominal_fps=nominal,
        columns_found=layout.found,
        columns_missing=layout.missing,
        columns_ignored=layout.ignored,
        clamped=clamped,
        repaired=repaired,
        skipped_rows=skipped,
        warnings=warnings,
    )


def _hold(values: np.ndarray, bad: np.ndarray) -> np.ndarray:
    """Replace bad cells by the last good value above them (zero before any)."""
    out = np.where(bad, 0.0, values)
    # Index of the last good row at or above each cell; bad cells before any good row
    # point at row 0, which is then bad too and so already zero.
    idx = np.where(bad, 0, np.arange(len(values))[:, None])
    np.maximum.accumulate(idx, axis=0, out=idx)
    return np.take_along_axis(out, idx, axis=0)


def _fill_times(times: np.ndarray, bad: np.ndarray) -> np.ndarray:
    """Interpolate bad time stamps from their good neighbours (extrapolate at the ends)."""
    good = np.nonzero(~bad)[0]
    if good.size == 0:
        return np.arange(len(times), dtype=np.float64) / DEFAULT_FPS
    idx = np.arange(len(times), dtype=np.float64)
    with np.errstate(over="ignore", invalid="ignore"):  # :func:`_check_monotonic` refuses
        step = float(np.median(np.diff(times[good]) / np.diff(good))) if good.size > 1 \
            else 1 / 60
        out = np.interp(idx, good.astype(np.float64), times[good])
        out[: good[0]] = times[good[0]] - (good[0] - idx[: good[0]]) * step
        out[good[-1] + 1 :] = times[good[-1]] + (idx[good[-1] + 1 :] - good[-1]) * step
    return out


def _check_monotonic(times: np.ndarray, lines: list[int], label: str) -> np.ndarray:
    if not np.isfinite(times).all():  # stamps near the float limit, once offset or filled
        i = int(np.argmin(np.isfinite(times)))
        raise BadInputError(f"{label}, line {lines[i]}: expected a time stamp within "
                            f"float range of the first, found one that overflows")
    times = times.copy()
    # Timecodes wrap at midnight: a drop of more than 12 hours is a new day.
    for i in np.nonzero(np.diff(times) < -43200.0)[0]:
        times[i + 1 :] += 86400.0
    steps = np.diff(times)
    if (steps <= 0).any():
        i = int(np.argmax(steps <= 0))
        raise BadInputError(
            f"{label}, line {lines[i + 1]}: expected time to increase, found "
            f"{times[i + 1]:.6f} s after {times[i]:.6f} s"
        )
    return times


GAP_SECONDS = 1.0
"""A step in time longer than this, and than ten typical frame steps, is a gap in the
take (two takes joined, a clock jump), not a dropped frame or two."""


def _gap_warning(timestamps: np.ndarray, lines: list[int]) -> str | None:
    """A warning naming the gaps in a stream's time (see :data:`GAP_SECONDS`), which
    resampling would fill with frames interpolated across them, or ``None``."""
    steps = np.diff(timestamps)
    if steps.size < 2:
        return None
    long = steps > max(GAP_SECONDS, 10.0 * float(np.median(steps)))
    if not long.any():
        return None
    i = int(np.argmax(np.where(long, steps, -np.inf)))
    return (f"{int(long.sum())} gap(s) in time, the longest {steps[i]:.4g} s after "
            f"{timestamps[i]:.3f} s (line {lines[i + 1]}): animate fills a gap with frames "
            f"interpolated across it; --start/--end cut it out")


def _effective_fps(timestamps: np.ndarray, fallback: float) -> float:
    steps = np.diff(timestamps)
    if steps.size == 0:
        return float(fallback)
    rate = 1.0 / float(np.median(steps))
    # Report the nearest named rate when the median interval matches it within 1 %
    # (29.97 is NTSC's, not 30).
    named = sorted({float(fallback), *STANDARD_RATES, *NTSC_RATES},
                   key=lambda r: abs(rate - r) / r)
    return named[0] if abs(rate - named[0]) <= 0.01 * named[0] else rate


@dataclasses.dataclass
class _Layout:
    """Which header column feeds which output, worked out once from the header."""

    label: str
    source_format: str
    value_columns: list[int]  # header indices parsed as floats
    blend_sources: dict[int, list[int]]  # ARKIT52 index -> positions in value_columns
    rotation_sources: list[int | None]  # 9 positions in value_columns (or None)
    time_column: int | None
    time_kind: str | None  # "timecode", "seconds", "ms", "frame"
    found: list[str]
    missing: list[str]
    ignored: list[str]

    @classmethod
    def from_header(cls, header: list[str], label: str) -> _Layout:
        whole: dict[str, int] = {}
        halves: dict[str, list[int]] = {}
        rotations: dict[str, int] = {}
        time_column, time_kind = None, None
        ignored: list[str] = []
        rot_keys = {r.casefold(): k for k, r in enumerate(ROTATION_COLUMNS)}
        for i, col in enumerate(header):
            key = col.casefold()
            name = canonical_name(col)
            if name is not None:
                if split_part(col) is not None:
                    halves.setdefault(name, []).append(i)
                    continue
                if name in whole:
                    raise BadInputError(
                        f"{label}: blendshape {name!r} appears twice, as "
                        f"{header[whole[name]]!r} and {col!r}"
                    )
                whole[name] = i
            elif key.replace("_", "") in rot_keys:
                rotations[ROTATION_COLUMNS[rot_keys[key.replace("_", "")]]] = i
            elif time_column is None and key == "timecode":
                time_column, time_kind = i, "timecode"
            elif time_column is None and key in _SECONDS_COLUMNS:
                time_column, time_kind = i, "seconds"
            elif time_column is None and key in _MS_COLUMNS:
                time_column, time_kind = i, "ms"
            elif time_column is None and key in _FRAME_COLUMNS:
                time_column, time_kind = i, "frame"
            else:
                ignored.append(col)
        for name, idx in halves.items():
            if name in whole:
                ignored.extend(header[i] for i in idx)
        if not whole and not halves:
            raise BadInputError(
                f"{label}: expected columns named after ARKit blendshapes (e.g. "
                f"'eyeBlinkLeft' or 'EyeBlinkLeft'), found {', '.join(header[:5]) or 'none'}"
            )
        lowered = {h.casefold() for h in header}
        if time_kind == "timecode" and lowered & {"blendshapecount"}:
            source_format = "livelinkface"
        elif "_neutral" in lowered or (set(whole) == _MEDIAPIPE_SHAPES and not halves):
            source_format = "mediapipe"  # its model has no tongueOut
        elif all(header[i] == name for name, i in whole.items()) and not halves:
            source_format = "arkit"
        else:
            source_format = "generic"

        value_columns: list[int] = []
        blend_sources: dict[int, list[int]] = {}
        for name in ARKIT52:
            if name in whole:
                blend_sources[INDEX[name]] = [len(value_columns)]
                value_columns.append(whole[name])
            elif name in halves:
                blend_sources[INDEX[name]] = list(
                    range(len(value_columns), len(value_columns) + len(halves[name]))
                )
                value_columns.extend(halves[name])
        rotation_sources: list[int | None] = []
        for rot in ROTATION_COLUMNS:
            if rot in rotations:
                rotation_sources.append(len(value_columns))
                value_columns.append(rotations[rot])
            else:
                rotation_sources.append(None)
        found = [ARKIT52[i] for i in sorted(blend_sources)]
        missing = [n for n in ARKIT52 if INDEX[n] not in blend_sources]
        return cls(
            label=label,
            source_format=source_format,
            value_columns=value_columns,
            blend_sources=blend_sources,
            rotation_sources=rotation_sources,
            time_column=time_column,
            time_kind=time_kind,
            found=found,
            missing=missing,
            # Unexpected columns first, the well-known ones (BlendshapeCount...) last.
            ignored=sorted(ignored, key=lambda c: c.casefold() in _IGNORED_KNOWN),
        )

    def gather_weights(self, values: np.ndarray) -> np.ndarray:
        weights = np.zeros((values.shape[0], NUM_BLENDSHAPES), dtype=np.float64)
        for k, sources in self.blend_sources.items():
            weights[:, k] = values[:, sources].mean(axis=1)
        return weights

    def gather_rotation(self, values: np.ndarray, which: int) -> np.ndarray | None:
        sl = self.rotation_sources[0:3] if which == 0 else self.rotation_sources[3:9]
        if all(s is None for s in sl):
            return None
        out = np.zeros((values.shape[0], len(sl)), dtype=np.float32)
        for j, s in enumerate(sl):
            if s is not None:
                out[:, j] = values[:, s]
        return out

    def parse_times(
        self, cells: list[str], fps: float | None
    ) -> tuple[np.ndarray | None, np.ndarray | None, float | None, str | None]:
        """Times in seconds per row, a bad-cell mask for them, the nominal rate, and a
        warning when timecodes cannot tell the rate (:func:`_unsure_rate`)."""
        if self.time_column is None:
            return None, None, None, None
        if self.time_kind == "timecode":
            parsed = [_parse_timecode(c) for c in cells]
            bad = np.array([p is None for p in parsed], dtype=bool)
            good = [p for p in parsed if p is not None]
            if not good:
                return np.zeros(len(cells)), bad, None, None
            max_frame = max(int(p[1]) for p in good)
            nominal = next((r for r in STANDARD_RATES if r > max_frame), float(max_frame + 1))
            note = None
            if fps is not None and fps > max_frame:
                nominal = float(fps)
            elif fps is None:
                note = _unsure_rate(good, nominal)
            times = np.array(
                [np.nan if p is None else p[0] + p[1] / nominal for p in parsed], dtype=np.float64
            )
            return times, bad, nominal, note
        times = np.array([_to_float(c) for c in cells], dtype=np.float64)
        bad = ~np.isfinite(times)
        if self.time_kind == "ms":
            times = times / 1000.0
        elif self.time_kind == "frame":
            times = times / (fps if fps is not None else DEFAULT_FPS)
        return times, bad, None, None


# --------------------------------------------------------------------------- processing


def resample(stream: ArkitStream, fps: float) -> ArkitStream:
    """Resample a stream onto a uniform time grid by linear interpolation.

    Gaps in the source (dropped frames) are bridged by interpolation.

    Args:
        stream: The stream to resample.
        fps: Target frame rate in frames per second.

    Returns:
        A new stream with ``timestamps = arange(F') / fps`` covering the source.
    """
    if not (math.isfinite(fps) and fps > 0):
        raise BadInputError(f"expected a positive target frame rate, found {fps!r}")
    t = stream.timestamps
    n = math.floor(float(t[-1]) * fps + 1e-9) + 1
    grid = np.arange(n, dtype=np.float64) / fps

    def interp(a: np.ndarray | None, angles: bool = False) -> np.ndarray | None:
        if a is None:
            return None
        src = np.unwrap(a.astype(np.float64), axis=0) if angles else a.astype(np.float64)
        out = np.stack([np.interp(grid, t, src[:, j]) for j in range(a.shape[1])], axis=1)
        return out.astype(np.float32)

    weights = interp(stream.weights)
    assert weights is not None
    return dataclasses.replace(
        stream,
        weights=np.clip(weights, 0.0, 1.0),
        timestamps=grid,
        fps=float(fps),
        nominal_fps=float(fps),
        head_rotation=interp(stream.head_rotation, angles=True),
        eye_rotation=interp(stream.eye_rotation, angles=True),
        warnings=list(stream.warnings),
    )


def smooth(stream: ArkitStream, sigma_seconds: float) -> ArkitStream:
    """Zero-phase Gaussian smoothing of weights and rotations over time.

    Args:
        stream: The stream to smooth.
        sigma_seconds: Standard deviation of the Gaussian in seconds (0 returns a copy).

    Returns:
        A new stream; weights stay in [0, 1].
    """
    if not (math.isfinite(sigma_seconds) and sigma_seconds >= 0):
        raise BadInputError(f"expected a smoothing sigma >= 0 s, found {sigma_seconds!r}")
    if sigma_seconds == 0 or stream.num_frames < 2:
        return dataclasses.replace(
            stream,
            weights=stream.weights.copy(),
            head_rotation=None if stream.head_rotation is None else stream.head_rotation.copy(),
            eye_rotation=None if stream.eye_rotation is None else stream.eye_rotation.copy(),
            warnings=list(stream.warnings),
        )
    from scipy.ndimage import gaussian_filter1d

    sigma = sigma_seconds * stream.fps

    def filt(a: np.ndarray | None, angles: bool = False) -> np.ndarray | None:
        if a is None:
            return None
        # Angles are unwrapped first (as resample does): +179 and -179 degrees are two
        # degrees apart, and averaged as they lie they would make 0, the head turned round.
        src = np.unwrap(a.astype(np.float64), axis=0) if angles else a.astype(np.float64)
        return gaussian_filter1d(src, sigma, axis=0, mode="nearest").astype(np.float32)

    weights = filt(stream.weights)
    assert weights is not None
    return dataclasses.replace(
        stream,
        weights=np.clip(weights, 0.0, 1.0),
        head_rotation=filt(stream.head_rotation, angles=True),
        eye_rotation=filt(stream.eye_rotation, angles=True),
        warnings=list(stream.warnings),
    )


# --------------------------------------------------------------------------- writing


def _timecode(seconds: float, fps: float) -> str:
    whole = math.floor(seconds)
    frames = (seconds - whole) * fps
    ff = math.floor(frames + 1e-9)
    frac = max(0.0, frames - ff)
    if frac >= 0.9995:  # keep the printed fraction below one frame
        ff, frac = ff + 1, 0.0
    if ff >= fps:
        whole, ff = whole + 1, 0
    h, rem = divmod(int(whole), 3600)
    m, s = divmod(rem, 60)
    return f"{h:02d}:{m:02d}:{s:02d}:{ff:02d}.{round(frac * 1000):03d}"


def _timecode_rate(fps: float) -> float:
    """The frame rate to number Live Link Face timecodes at: the stream's own where it is
    a standard one (NTSC's 29.97 numbered at 30, with fractions), else the smallest
    standard rate it divides (12.5 -> 25, 10 -> 30), else the nearest standard one
    (fractions of a frame keep the times). The reader infers it from the largest frame
    number, which :func:`_timecode_start` makes reach it."""
    near = min(STANDARD_RATES, key=lambda r: abs(r - fps) / r)
    if abs(near - fps) <= 0.002 * near:
        return near
    for rate in STANDARD_RATES:
        k = rate / fps
        if k >= 1 and abs(k - round(k)) < 1e-6:
            return rate
    return near


def _timecode_start(timestamps: np.ndarray, rate: float, start: float) -> float:
    """Where to put the first frame (seconds of the day, from ``start``) so that the
    largest frame number of the take is ``rate - 1`` and a reader infers ``rate`` (the
    next standard rate above its largest frame number), and the take is not all within
    one second (which a reader warns does not tell the rate): a take that does not do so
    by itself starts on the last frame of a second."""
    t = start + np.asarray(timestamps, np.float64)
    if not len(t):
        return start
    top = int(np.floor((t % 1.0) * rate + 1e-6).max())
    one_second = np.floor(t[0] + 1e-9) == np.floor(t[-1] + 1e-9)
    if next((r for r in STANDARD_RATES if r > top), None) == rate and not one_second:
        return start
    # the first frame on the last frame number of its second, the others after it
    return math.floor(t[0] + 1e-9) + (rate - 1) / rate - float(timestamps[0])


def write_arkit_csv(
    stream: ArkitStream,
    target: str | Path | IO[str],
    *,
    flavor: Literal["livelinkface", "arkit", "mediapipe"] = "livelinkface",
    decimals: int = 10,
    start_seconds: float = 0.0,
) -> None:
    """Write a stream as CSV, atomically when ``target`` is a path.

    Args:
        stream: The stream to write.
        target: A path or an open text stream.
        flavor: ``"livelinkface"`` (``Timecode,BlendshapeCount``, capitalised names in the
            app's order, 9 rotation columns), ``"arkit"`` (``time`` in seconds, then the
            52 names in Apple's order, then rotations if present) or ``"mediapipe"``
            (``timestamp_ms``, then the 51 names MediaPipe's Face Landmarker scores, in
            its order, then rotations if present).
        decimals: Digits after the decimal point.
        start_seconds: Time of day of the first frame, for Live Link Face timecodes (a
            take that would lie within one second, or not reach the last frame number of
            its rate, starts up to a second later: see :func:`_timecode_start`).
    """
    rows: Iterable[list[str]]
    fmt = f"{{:.{decimals}f}}"
    head = stream.head_rotation
    eyes = stream.eye_rotation
    n = stream.num_frames
    if flavor == "livelinkface":
        order = [INDEX[canonical_name(c) or ""] for c in LIVE_LINK_FACE_ORDER]
        header = ["Timecode", "BlendshapeCount", *LIVE_LINK_FACE_ORDER, *ROTATION_COLUMNS]
        rot = np.zeros((n, 9), dtype=np.float32)
        if head is not None:
            rot[:, :3] = head
        if eyes is not None:
            rot[:, 3:] = eyes
        rate = _timecode_rate(stream.fps)
        begin = _timecode_start(stream.timestamps, rate, start_seconds)
        rows = (
            [
                _timecode(begin + float(stream.timestamps[i]), rate),
                "61",
                *(fmt.format(v) for v in stream.weights[i, order]),
                *(fmt.format(v) for v in rot[i]),
            ]
            for i in range(n)
        )
    elif flavor in ("arkit", "mediapipe"):
        rot_names: list[str] = []
        rot_parts: list[np.ndarray] = []
        if head is not None:
            rot_names += list(ROTATION_COLUMNS[:3])
            rot_parts.append(head)
        if eyes is not None:
            rot_names += list(ROTATION_COLUMNS[3:])
            rot_parts.append(eyes)
        rot = np.concatenate(rot_parts, axis=1) if rot_parts else np.zeros((n, 0))
        if flavor == "arkit":
            names, scale, time_name = list(ARKIT52), 1.0, "time"
        else:
            names, scale, time_name = list(MEDIAPIPE_BLENDSHAPES[1:]), 1000.0, "timestamp_ms"
        cols = [INDEX[name] for name in names]
        header = [time_name, *names, *rot_names]
        rows = (
            [
                f"{scale * float(stream.timestamps[i]):.6f}",
                *(fmt.format(v) for v in stream.weights[i, cols]),
                *(fmt.format(v) for v in rot[i]),
            ]
            for i in range(n)
        )
    else:
        raise BadInputError(f"expected flavor livelinkface, arkit or mediapipe, found "
                            f"{flavor!r}")

    if isinstance(target, (str, Path)):
        from head360cli.io.atomic import atomic_path

        with atomic_path(target) as tmp, open(tmp, "w", newline="") as f:
            writer = csv.writer(f, lineterminator="\n")
            writer.writerow(header)
            writer.writerows(rows)
    else:
        writer = csv.writer(target, lineterminator="\n")
        writer.writerow(header)
        writer.writerows(rows)
