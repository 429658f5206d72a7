"""Flight-test CSV tables read into named float columns, and the column helpers readers share."""

from __future__ import annotations

import contextlib
import csv
import re
from collections import Counter
from collections.abc import Collection, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import ChannelError, DataFormatError

FloatArray = NDArray[np.float64]


@contextlib.contextmanager
def arrow_file(path: Path | str) -> Any:
    """The file open for pyarrow: its own native file where the name is valid text, else
    Python's (a name with bytes that are not UTF-8, which pyarrow cannot encode)."""
    import pyarrow as pa

    name = str(path)
    try:
        name.encode("utf-8")
    except UnicodeEncodeError:
        with open(path, "rb") as raw, pa.PythonFile(raw, mode="r") as f:
            yield f
        return
    with pa.OSFile(name) as f:
        yield f


def _seconds(values: NDArray[Any]) -> FloatArray:
    """Datetimes as float seconds since the first sample, durations as float seconds.

    Epoch nanoseconds (about 1.7e18) lose sub-microsecond resolution in
    float64, so datetimes count from the first sample; a duration already
    counts from a reference the user chose and is kept. NaT becomes NaN, which
    the finite checks then report by index.
    """
    if values.dtype.kind == "M" and values.size:
        values = values - values[0]
    return np.asarray(values / np.timedelta64(1, "s"), dtype=np.float64)


# A config can name any file as a flight, and errors reach CI logs: a header is
# listed only when every column reads as a channel name, and no cell is quoted.
_NUMBER_LIKE = re.compile(r"[\d.,+\-eE ]{1,24}")


_NAME_LIKE = re.compile(r"[A-Za-z_][\w.\[\]()/ -]{0,63}")


def _columns_text(columns: Sequence[str]) -> str:
    cols = [str(c) for c in columns]
    if all(_NAME_LIKE.fullmatch(c) and "=" not in c for c in cols):
        return f"columns: {cols}"
    return f"{len(cols)} columns (not listed: the first line does not read as names)"


def _reader_error(exc: Exception) -> str:
    """A CSV reader's message without the row text some of them append."""
    return re.sub(r"(got \d+|Row #\d+)\s*:.*", r"\1", str(exc), flags=re.S)


_TIME_CANDIDATES = ("time", "t", "Time", "TIME", "time_s", "Time (s)", "t_s")


def _pick_time_column(columns: Sequence[str], time_column: str | None, path: Path) -> str:
    if time_column is not None:
        if time_column not in columns:
            raise ChannelError(
                f"{path}: time column {time_column!r} not found; {_columns_text(columns)}"
            )
        return time_column
    for candidate in _TIME_CANDIDATES:
        if candidate in columns:
            return candidate
    raise ChannelError(
        f"{path}: no time column found (tried 'time', 't', 'Time', ...); "
        f"pass time_column=...; {_columns_text(columns)}"
    )


class _Owned(np.ndarray):
    """A float64 array a loader built and hands over: `FlightData` keeps it without a copy.

    Only the loaders below create one, and they drop their own reference, so
    no caller can alias the record's arrays.
    """


def _adopt(values: _Owned) -> FloatArray:
    values.setflags(write=False)  # with the base read-only, the view cannot be made writable
    out = values.view(np.ndarray)
    out.setflags(write=False)
    return out


# The longest header line read (200,000 column names take a few MB).
_MAX_HEADER = 64 << 20


def _csv_header(path: Path) -> tuple[list[str], int, int]:
    """The header, the byte offset of the first data line, and the header's line number.

    Comment lines (``#`` first) and blank lines before the header are skipped,
    as flight-test exports often carry them.
    """
    offset = 0
    line_no = 0
    with open(path, "rb") as f:
        while raw := f.readline(_MAX_HEADER + 1):
            if len(raw) > _MAX_HEADER:  # a binary file or a bomb: a line is read whole
                raise DataFormatError(
                    f"{path}: line {line_no + 1} is longer than {_MAX_HEADER >> 20} MiB; "
                    "not a CSV header"
                )
            line_no += 1
            start = offset
            offset += len(raw)
            try:
                text = raw.decode("utf-8")
            except UnicodeDecodeError as exc:
                raise DataFormatError(f"{path}: not a UTF-8 text file ({exc})") from None
            if start == 0:
                text = text.removeprefix("\ufeff")
            if not text.strip() or text.lstrip().startswith("#"):
                continue
            line = text.rstrip("\r\n")
            if "\r" in line:  # readline splits at \n only: the whole file is one line
                raise DataFormatError(
                    f"{path}: lines end in a carriage return alone (classic Mac OS); "
                    "save the file with \\n or \\r\\n line endings"
                )
            try:
                header = [h.strip() for h in next(csv.reader([line]))]
            except csv.Error as exc:
                raise DataFormatError(f"{path}: line {line_no}: not a CSV header ({exc})") from None
            return header, offset, line_no
    raise DataFormatError(f"{path}: empty file")


def _csv_units(path: Path, marker: str, columns: Collection[str]) -> dict[str, str]:
    """The units a comment line before the header declares (`FlightData.to_csv` writes
    ``# units: {"alpha": "rad"}``); empty when there is none. The lines before the
    header are read, and the comment lines right after it.

    An entry for a name not among the file's `columns` (a typo, ``qq`` for ``q``) is
    dropped with a warning naming it: the column it meant would lose its unit silently.

    A ``# units:`` line that is not that JSON object of names to unit strings (hand
    edited, cut short, or another tool's note, ``# units: deg, deg/s``) declares
    nothing, with a warning naming the file and the line: the units would otherwise
    vanish without a word (deg read as rad). So does a units line that is not read: a
    second one, one after the header, or one written otherwise (``#units:``, ``# Units:``).
    """
    import json

    declared: dict[str, str] | None = None
    header_seen = False
    with open(path, "rb") as f:
        line_no = 0
        while raw := f.readline(_MAX_HEADER + 1):
            line_no += 1
            text = raw.decode("utf-8", errors="replace").removeprefix("\ufeff").strip()
            if not text:
                continue
            if not text.startswith("#"):
                if header_seen:
                    break  # the data: comment lines among it are not looked at
                header_seen = True
                continue
            if not _UNITS_LIKE.match(text):
                continue
            if header_seen or declared is not None or not text.startswith(marker):
                why = (
                    "it is after the header"
                    if header_seen
                    else "a second units line"
                    if declared is not None
                    else f"written {text.split(':', 1)[0] + ':'!r}, not {marker!r}"
                )
                _units_not_read(path, line_no, why, marker)
                continue
            try:
                found = json.loads(text[len(marker) :])
                why = "" if isinstance(found, dict) else "not a JSON object"
            except json.JSONDecodeError as exc:
                found, why = None, f"not JSON: {exc.msg.lower()}"
            if isinstance(found, dict):
                odd = [k for k, v in found.items() if not isinstance(v, str)]
                why = f"the unit of {odd[0]!r} is not a string" if odd else ""
            if why:
                _units_not_read(path, line_no, why, marker)
                declared = {}
            else:
                _warn_unknown_units(path, line_no, found, columns)
                declared = dict(found)
    return declared or {}


# a comment line meant to declare units, however it is written
_UNITS_LIKE = re.compile(r"#\s*units\s*:", re.IGNORECASE)


def _units_not_read(path: Path, line_no: int, why: str, marker: str) -> None:
    import warnings

    warnings.warn(
        f"{path}: line {line_no}: units comment not read ({why}); no unit is declared by "
        f'it (FlightData.to_csv writes one line before the header: {marker} {{"alpha": '
        '"rad"})',
        UserWarning,
        stacklevel=4,  # here, _csv_units, load_flight_test, its caller
    )


def _warn_unknown_units(
    path: Path, line_no: int, units: dict[str, str], columns: Collection[str]
) -> None:
    import warnings

    unknown = [k for k in units if k not in columns]
    if not unknown:
        return
    # names from the file are quoted only where they read as names (errors reach logs)
    shown = (
        str(unknown)
        if all(_NAME_LIKE.fullmatch(k) and "=" not in k for k in unknown)
        else f"{len(unknown)} names"
    )
    warnings.warn(
        f"{path}: line {line_no}: the units comment declares {shown}, no such column; "
        f"those units are dropped ({_columns_text(list(columns))})",
        UserWarning,
        stacklevel=4,  # here, _csv_units, load_flight_test, its caller
    )


_NUMBER = r"^\s*[+-]?((\d+\.?\d*|\.\d+)([eE][+-]?\d+)?|(?i:inf|infinity|nan))\s*$"


def _file_line(path: Path, offset: int, header_line: int, nth: int, width: int | None) -> int:
    """The line number an editor shows for the `nth` (1-based) row after the header.

    Blank lines are no rows (pyarrow skips them); with the header's `width`, nor
    are comment lines whose cell count differs from it (the loader skips those).
    Only on the error path: it reads the file up to that row once more.
    """
    line, seen = header_line, 0
    with open(path, "rb") as f:
        f.seek(offset)
        for raw in f:
            line += 1
            text = raw.rstrip(b"\r\n")
            if not text:
                continue
            if width is not None and text.lstrip().startswith(b"#"):
                cells = next(csv.reader([text.decode("utf-8", errors="replace")]), [])
                if len(cells) != width:
                    continue
            seen += 1
            if seen == nth:
                return line
    return line


def _csv_cell_error(
    path: Path,
    header: list[str],
    offset: int,
    header_line: int,
    exc: Exception,
    columns: Sequence[str] | None = None,
) -> DataFormatError:
    """Name the row and column of the cell pyarrow refused (only ever on the error path)."""
    import pyarrow as pa

    try:
        return _locate_csv_error(path, header, offset, header_line, exc, columns)
    except (OSError, pa.ArrowException) as again:
        return DataFormatError(
            f"{path}: not a readable CSV file ({_reader_error(exc)}; {_reader_error(again)})"
        )


def _row_text(row: Any) -> str:
    """The text of a row pyarrow could not parse (`_require_utf8` has checked it decodes)."""
    return str(row.text)


def _require_utf8(path: Path, offset: int, header_line: int) -> None:
    """Refuse a file whose data is not UTF-8 before a parser's row callback meets it:
    pyarrow decodes a bad row's text for the callback and prints, not raises, its error.
    Only on the error path, so reading the file once more costs nothing on good files."""
    import codecs

    decoder = codecs.getincrementaldecoder("utf-8")()
    row, at = header_line + 1, offset
    with open(path, "rb") as f:
        f.seek(offset)
        while block := f.read(1 << 20):
            try:
                decoder.decode(block)
            except UnicodeDecodeError as exc:
                row += block[: exc.start].count(b"\n")
                raise DataFormatError(
                    f"{path}: row {row}: byte {at + exc.start} of the file is not UTF-8 text"
                ) from None
            row += block.count(b"\n")
            at += len(block)


def _locate_csv_error(
    path: Path,
    header: list[str],
    offset: int,
    header_line: int,
    exc: Exception,
    columns: Sequence[str] | None = None,
) -> DataFormatError:
    import pyarrow as pa
    import pyarrow.csv as pacsv

    # A row with the wrong number of cells (comment lines aside): the parser reports
    # its line number.
    bad_rows: list[Any] = []

    def keep(row: Any) -> str:
        if not _row_text(row).lstrip().startswith("#"):
            bad_rows.append(row)
        return "skip"

    def read(**convert: Any) -> Any:
        with arrow_file(path) as f:
            f.seek(offset)
            return pacsv.read_csv(
                f,
                read_options=pacsv.ReadOptions(column_names=header, use_threads=False),
                parse_options=pacsv.ParseOptions(invalid_row_handler=keep),
                convert_options=pacsv.ConvertOptions(**convert),
                memory_pool=pa.system_memory_pool(),
            )

    read(
        column_types=dict.fromkeys(header, pa.string()),
        include_columns=header[:1],
    )
    if bad_rows:
        row = bad_rows[0]
        # pyarrow numbers the lines after the header, blank lines not counted
        line = _file_line(path, offset, header_line, row.number, None)
        return DataFormatError(
            f"{path}: row {line} has {row.actual_columns} cells, header has {row.expected_columns}"
        )
    # Otherwise a cell is not a number: one streaming pass finds the earliest (a column
    # at a time would read a 200,000-column file 200,000 times).
    names = list(columns) if columns is not None else header
    if len(names) > _WIDE:
        found = _first_bad_cell_wide(path, header, offset, header_line, names)
    else:
        found = _first_bad_cell(path, header, offset, names, keep)
        if found is not None:
            found = (_file_line(path, offset, header_line, found[0] + 1, len(header)), *found[1:])
    if found is not None:
        row, name, cell = found
        if not cell:
            what = "blank"
        elif len(cell) <= 4 or _NUMBER_LIKE.fullmatch(cell):  # x, N/A, 1.2.3: shown
            what = f"non-numeric ({cell!r})"
        else:  # text: not quoted (a config can name any file; errors reach logs)
            what = f"non-numeric ({len(cell)} characters of text)"
        return DataFormatError(f"{path}: row {row}, column {name!r}: {what} cell")
    return DataFormatError(f"{path}: not a readable CSV file ({_reader_error(exc)})")


# Beyond this many columns pyarrow's cost per column outweighs its speed per cell.
_WIDE = 1000


def _first_bad_cell(
    path: Path,
    header: list[str],
    offset: int,
    names: list[str],
    keep: Any,
    pattern: str = _NUMBER,
) -> tuple[int, str, str] | None:
    """(data row from 0, column, cell) of the earliest cell among `names` that `pattern`
    (a number) does not match, by pyarrow."""
    import pyarrow as pa
    import pyarrow.compute as pc
    import pyarrow.csv as pacsv

    with arrow_file(path) as f:
        f.seek(offset)
        reader = pacsv.open_csv(
            f,
            read_options=pacsv.ReadOptions(column_names=header, use_threads=False),
            parse_options=pacsv.ParseOptions(invalid_row_handler=keep),
            convert_options=pacsv.ConvertOptions(
                column_types=dict.fromkeys(names, pa.string()),
                include_columns=names,
                strings_can_be_null=False,
            ),
            memory_pool=pa.system_memory_pool(),
        )
        first_row = 0
        for batch in reader:
            rows = batch.num_rows
            if not rows:
                continue
            # every column of the batch in one regex call: cell k is row k % rows of
            # column k // rows
            cells = pa.concat_arrays(list(batch.columns))
            numeric = pc.match_substring_regex(cells, pattern)
            bad = np.flatnonzero(~np.asarray(numeric.to_numpy(zero_copy_only=False), dtype=bool))
            if bad.size:
                k = int(bad[np.lexsort((bad // rows, bad % rows))[0]])  # earliest row first
                name = batch.schema.names[k // rows]
                return first_row + k % rows, name, str(cells[k].as_py()).strip()
            first_row += rows
    return None


def _first_bad_cell_wide(
    path: Path, header: list[str], offset: int, header_line: int, names: list[str]
) -> tuple[int, str, str] | None:
    """`_first_bad_cell` for a wide file: Python's csv reader, row by row; the row is
    the file line."""
    import io

    number = re.compile(_NUMBER)
    where = {h: j for j, h in enumerate(header)}
    picked = [(where[n], n) for n in names]
    with open(path, "rb") as raw:
        raw.seek(offset)
        text = io.TextIOWrapper(raw, encoding="utf-8", newline="")
        reader = csv.reader(text)
        for cells in reader:
            if not cells or (len(cells) == 1 and not cells[0].strip()):
                continue  # blank lines, which pyarrow skips
            if cells[0].lstrip().startswith("#"):
                continue
            for j, name in picked:
                cell = cells[j].strip() if j < len(cells) else ""
                if not number.match(cell):
                    return header_line + reader.line_num, name, cell
    return None


def _read_with_timestamps(
    read: Any, types: dict[str, Any], path: Path, header: list[str], offset: int, line: int
) -> Any:
    """`read()`, with each column whose first cell is an ISO 8601 date and time read as
    timestamps (``types`` updated; they become seconds from the first sample, in UTC
    where the first cell gives a zone, ``Z`` or ``+02:00``). A later cell of such a
    column that is no date and time (or drops or adds the zone) is reported by its
    file line (`line`: the header's) and the column's name."""
    import pyarrow as pa

    for _ in range(len(types)):
        try:
            return read()
        except pa.ArrowInvalid as exc:
            if "conversion error" not in str(exc):
                raise
            names = [n for n, kind in types.items() if kind == pa.float64()]
            found = _first_bad_cell(path, header, offset, names, lambda row: "skip")
            if found is None or found[0] != 0 or not _ISO_TIME.fullmatch(found[2]):
                _raise_bad_time(types, path, header, offset, line)
                raise
            zoned = _ISO_TIME.fullmatch(found[2]).group("zone")  # type: ignore[union-attr]
            types[found[1]] = pa.timestamp("ns", tz="UTC") if zoned else pa.timestamp("ns")
    return read()


def _raise_bad_time(
    types: dict[str, Any], path: Path, header: list[str], offset: int, line: int
) -> None:
    """Raise the earliest cell of a timestamp column that is not read as one."""
    import pyarrow as pa

    for zoned in (False, True):
        stamped = [
            n
            for n, kind in types.items()
            if isinstance(kind, pa.TimestampType) and (kind.tz is not None) == zoned
        ]
        if not stamped:
            continue
        pattern = rf"^\s*{_ISO_BODY}{_ISO_ZONE if zoned else ''}\s*$"
        found = _first_bad_cell(path, header, offset, stamped, lambda row: "skip", pattern)
        if found is not None:
            row = _file_line(path, offset, line, found[0] + 1, len(header))
            cell = found[2]
            shown = (
                repr(cell)
                if len(cell) <= 32 and _ISO_CHARS.fullmatch(cell)
                else (f"{len(cell)} characters of text")
            )
            zone = "with" if zoned else "without"
            raise DataFormatError(
                f"{path}: row {row}, column {found[1]!r}: not an ISO 8601 date and time "
                f"{zone} a zone, as the column's first cell ({shown})"
            )


# an ISO 8601 date and time (a timestamp column of a CSV), with an optional zone
_ISO_BODY = r"\d{4}-\d\d-\d\d[T ]\d\d:\d\d(:\d\d(\.\d{1,9})?)?"
_ISO_ZONE = r"(Z|[+-]\d\d:?\d\d)"
_ISO_TIME = re.compile(rf"{_ISO_BODY}(?P<zone>{_ISO_ZONE})?")
# a cell shown in a message only where it reads as a date, time or number
_ISO_CHARS = re.compile(r"[\d.:+\-TZ ]*")


def _read_csv(
    path: Path, wanted: Collection[str] | None = None
) -> tuple[list[str], dict[str, FloatArray]]:
    """Parse with pyarrow (multi-threaded, straight to float64); locate bad cells only on failure.

    Only the columns named in `wanted` are converted (all when None); the header
    comes back whole. Row numbers in messages are the file's line numbers, as an
    editor shows them (comment lines before the header counted).
    """
    import pyarrow as pa
    import pyarrow.csv as pacsv

    header, offset, header_line = _csv_header(path)
    if any(not h for h in header):
        raise DataFormatError(f"{path}: empty column name at column {header.index('') + 1}")
    dupes = sorted(h for h, n in Counter(header).items() if n > 1)  # linear in columns
    if dupes:
        shown = dupes if all(_NAME_LIKE.fullmatch(h) and "=" not in h for h in dupes) else None
        raise DataFormatError(
            f"{path}: duplicate column names {shown}"
            if shown is not None
            else f"{path}: {len(dupes)} column names appear twice (not listed: not names)"
        )
    if offset >= path.stat().st_size:
        raise DataFormatError(f"{path}: fewer than 2 data rows")
    # (at least one column: pyarrow reads every column for an empty selection)
    names = header if wanted is None else [h for h in header if h in wanted] or header[:1]
    types = dict.fromkeys(names, pa.float64())

    def read(parse: Any = None) -> Any:
        with arrow_file(path) as f:
            f.seek(offset)
            # The system allocator hands freed column buffers back to the OS at once,
            # which keeps the peak near one copy of the data.
            return pacsv.read_csv(
                f,
                read_options=pacsv.ReadOptions(column_names=header, use_threads=True),
                parse_options=parse or pacsv.ParseOptions(),
                convert_options=pacsv.ConvertOptions(
                    column_types=types,
                    include_columns=names,
                    null_values=[""],
                    strings_can_be_null=False,
                ),
                memory_pool=pa.system_memory_pool(),
            )

    comments: list[int] = []

    def skip_comment(row: Any) -> str:
        if not _row_text(row).lstrip().startswith("#"):
            return "error"
        comments.append(1)
        return "skip"

    try:
        try:
            table = _read_with_timestamps(read, types, path, header, offset, header_line)
        except pa.ArrowInvalid as exc:
            # Comment lines among the data: read again without them (rare, so only
            # on the error path); anything else is located and reported. A cell that
            # is not a number is no comment line (those have the wrong cell count).
            table = None
            _require_utf8(path, offset, header_line)
            if "conversion error" not in str(exc):
                with contextlib.suppress(pa.ArrowInvalid):
                    table = read(pacsv.ParseOptions(invalid_row_handler=skip_comment))
            if table is None or not comments:
                numeric = [n for n in names if types[n] == pa.float64()]
                raise _csv_cell_error(path, header, offset, header_line, exc, numeric) from None
    except (OSError, pa.ArrowException) as exc:
        raise DataFormatError(f"{path}: not a readable CSV file ({_reader_error(exc)})") from None
    n = table.num_rows
    if n < 2:
        raise DataFormatError(f"{path}: fewer than 2 data rows")
    pending = dict(zip(table.column_names, table.columns, strict=True))
    del table
    columns: dict[str, FloatArray] = {}
    for name in names:
        chunked = pending.pop(name)
        if chunked.null_count:
            first = int(np.flatnonzero(np.asarray(chunked.is_null()))[0])
            row = _file_line(path, offset, header_line, first + 1, len(header))
            raise DataFormatError(f"{path}: row {row}, column {name!r}: blank cell")
        if types[name] != pa.float64():
            columns[name] = _seconds(chunked.to_numpy())
            continue
        out = _Owned((n,), dtype=np.float64)  # owns its memory, so adopting it freezes it
        at = 0
        for chunk in chunked.chunks:
            size = len(chunk)
            out[at : at + size] = chunk.to_numpy(zero_copy_only=True)
            at += size
        del chunked  # frees this column's Arrow buffers before the next is copied
        bad = ~np.isfinite(out)
        if bad.any():
            first = int(np.flatnonzero(bad)[0])
            row = _file_line(path, offset, header_line, first + 1, len(header))
            raise DataFormatError(
                f"{path}: row {row}, column {name!r}: non-finite value {str(float(out[first]))!r}"
            )
        columns[name] = out
    return header, columns
