"""Pre-flight checks of flight files: present, regular, and with the channels the model
and stages need (headers only; nothing is loaded)."""

from __future__ import annotations

import csv
import difflib
import glob
import os
import re
import stat
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ...errors import AeroidError
from ._check_common import (
    _CSV_SUFFIXES,
    _HEADER_BYTES,
    _MATLAB_NUMERIC,
    _PARQUET_SUFFIXES,
    _READS_DATA,
    _TIME_CANDIDATES,
    _generators,
    _hint,
    _ModelNames,
    _Problems,
)
from .config import (
    CampaignConfig,
    ChannelEntry,
    FileFlights,
    SimulatedSource,
    glob_files,
)


@dataclass(frozen=True)
class _Needs:
    """The channels every flight must carry for the stages that run."""

    model: str
    controls: tuple[str, ...]
    outputs: tuple[str, ...]  # each of these
    any_output: tuple[str, ...]  # at least one of these (the fit uses those present)
    known: tuple[str, ...] = ()  # every name of the model's (states, controls, outputs)


def _channel_needs(
    options: Mapping[tuple[str, str], Any], model: _ModelNames, unknown_pipeline: bool
) -> _Needs:
    stages = {stage for _, stage in options}
    reads = stages & _READS_DATA
    controls = model.control if (reads or unknown_pipeline) else ()
    outputs: list[str] = []
    for (_, stage), opts in options.items():
        named = getattr(opts, "outputs", None) if stage in _READS_DATA else None
        if named:
            outputs += [o for o in named if o in model.output]
        elif stage in ("filter", "infer"):  # these fit every model output
            outputs += list(model.output)
    return _Needs(
        model=model.name,
        controls=controls,
        outputs=tuple(dict.fromkeys(outputs)),
        any_output=model.output if (reads or unknown_pipeline) else (),
        known=(*(model.state or ()), *model.control, *model.output),
    )


def _missing(needs: _Needs, have: Sequence[str]) -> list[str]:
    """Faults of a flight whose channels are `have`."""
    faults = []
    for role, names in (("control", needs.controls), ("output", needs.outputs)):
        for name in names:
            if name not in have:
                faults.append(
                    f"model {needs.model!r} needs the {role} {name!r}, which the flight lacks"
                    + _column_hint(name, have)
                )
    if needs.any_output and not any(o in have for o in needs.any_output):
        faults.append(
            f"the flight has none of model {needs.model!r}'s outputs "
            f"({', '.join(needs.any_output)})"
            + (f"; its channels: {', '.join(named)}" if (named := _name_like(have)) else "")
        )
    return faults


def _check_simulated_channels(
    config: CampaignConfig, needs: _Needs | None, problems: _Problems
) -> None:
    if needs is None:
        return
    known = _generators()
    for i, item in enumerate(config.flights):
        if not isinstance(item, SimulatedSource):
            continue
        spec = item.simulated.model_dump(mode="json")
        if spec["generator"] not in known:
            continue
        have = _simulated_channels(spec)
        for fault in _missing(needs, have or []) if have is not None else ():
            problems.add(f"flights[{i}].simulated", fault)


def _simulated_channels(spec: Mapping[str, Any]) -> list[str] | None:
    """The channels a simulated flight carries: one flown for a tenth of a second."""
    from .synthetic import flight_spec, fly

    short = {**spec, "n_flights": 1, "duration": 10.0 / float(spec["sample_rate"])}
    try:
        return sorted(fly(flight_spec(short, 0)).channels)
    except (AeroidError, ValueError, KeyError):
        return None


def _check_files(
    config: CampaignConfig, base_dir: Path, needs: _Needs | None, problems: _Problems
) -> None:
    seen: set[tuple[Path, str]] = set()
    headers: dict[tuple[Path, str | None], _Header | None] = {}
    for i, item in enumerate(config.flights):
        if isinstance(item, SimulatedSource):
            continue
        spec = FileFlights(path=item) if isinstance(item, str) else item
        where = f"flights[{i}]" if isinstance(item, str) else f"flights[{i}].path"
        for key, unit_fault in _unit_faults(spec):
            problems.add(f"flights[{i}].{key}", unit_fault)
        raw = Path(spec.path).expanduser()
        pattern = str(raw if raw.is_absolute() else (base_dir / raw))
        if glob.has_magic(pattern) and not Path(pattern).is_file():
            paths = glob_files(pattern)
            if not paths:
                problems.add(where, f"the pattern {spec.path!r} matches no file")
                continue
        else:
            paths = [Path(pattern)]
        # a file named again with other loader options (another window) is another flight
        options = repr(sorted(spec.loader_options().items()))
        for path in paths:
            if (path, options) in seen:
                continue
            seen.add((path, options))
            fault = _not_a_flight_file(path)
            if fault is not None:
                problems.add(where, fault)
                continue
            uses_log_options = spec.window is not None or spec.segments is not None
            if (
                needs is None
                and spec.channels is None
                and spec.time_column is None
                and not uses_log_options
            ):
                continue
            try:
                header = headers.get((path, spec.time_column))
                if header is None or (uses_log_options and header.log is None):
                    header = headers[(path, spec.time_column)] = _header(
                        path,
                        spec.time_column,
                        bool(spec.allow_external_data),
                        names_only=not uses_log_options,
                    )
            except AeroidError as exc:
                problems.add(where, str(exc))
                continue
            except OSError as exc:
                problems.add(where, f"{path}: cannot read it ({exc.strerror or exc})")
                continue
            if header is None:
                continue  # a format whose channels cannot be listed without loading it
            for key in ("sample_rate", "max_gap"):
                if header.has_time and getattr(spec, key) is not None:
                    problems.add(
                        f"flights[{i}].{key}",
                        f"{path.name}: {key} applies to flight logs; this is a table already "
                        "on one time axis",
                    )
            for fault in _file_channel_faults(path, header, spec, needs):
                problems.add(where, fault)
            for key, unit_fault in _stated_unit_faults(path, header, spec):
                problems.add(f"flights[{i}].{key}", unit_fault)
            for key, window_fault in _window_faults(path, header, spec):
                problems.add(f"flights[{i}].{key}", window_fault)


def _not_a_flight_file(path: Path) -> str | None:
    """Why `path` cannot be a flight file (it is never opened here), or None."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        hint = ""
        try:
            with os.scandir(path.parent) as it:
                # a folder of millions of files is not listed whole for a hint
                siblings = [e.name for _, e in zip(range(2000), it, strict=False)]
            hint = _hint(path.name, siblings, "")
            if not hint.startswith("; did you mean"):
                hint = ""
        except OSError:
            pass
        return f"no such file: {path}{hint}"
    except OSError as exc:
        return f"{path}: cannot read it ({exc.strerror})"
    if stat.S_ISREG(st.st_mode):
        return None
    if stat.S_ISDIR(st.st_mode):
        what = "a directory"
    elif stat.S_ISFIFO(st.st_mode):
        what = "a FIFO (named pipe)"
    elif stat.S_ISCHR(st.st_mode) or stat.S_ISBLK(st.st_mode):
        what = "a device"
    else:
        what = "not a regular file"
    return f"{path} is {what}, not a flight file"


def _file_channel_faults(
    path: Path, header: _Header, spec: FileFlights, needs: _Needs | None
) -> list[str]:
    columns = header.columns
    faults: list[str] = []
    if header.has_time:
        if spec.time_column is not None and spec.time_column not in columns:
            faults.append(
                f"{path.name}: time column {spec.time_column!r} not found"
                + _column_hint(spec.time_column, columns)
            )
        elif spec.time_column is None and not any(c in columns for c in _TIME_CANDIDATES):
            faults.append(
                f"{path.name}: no time column (tried {', '.join(_TIME_CANDIDATES[:3])}, ...); "
                f"set time_column ({len(columns)} columns)"
            )
    time = spec.time_column or next((c for c in _TIME_CANDIDATES if c in columns), None)
    what = "column" if header.has_time else "log channel"
    if spec.channels is None:
        have = [c for c in columns if c != time]
    else:
        pairs = _picked(path, columns, spec.channels, faults)
        for col in dict.fromkeys(pairs.values()):
            if col not in columns:
                faults.append(
                    f"{path.name}: channels: {what} {col!r} not found" + _column_hint(col, columns)
                )
        have = list(pairs)
        if needs is not None:
            faults += _renamed_away(path, spec.channels, pairs, needs, what)
    if needs is not None:
        faults += [f"{path.name}: {f}" for f in _missing(needs, have)]
    return faults


def _renamed_away(
    path: Path, chosen: Any, pairs: Mapping[str, str], needs: _Needs, what: str
) -> list[str]:
    """A plain map read ``{channel: name}`` that renames a channel carrying a model name to
    a name the model lacks: the name is a channel on neither side, so it is far likelier a
    mistyped channel (``{alpha: aoa_deg}``) than a renaming that drops the model's alpha."""
    from ...io.channel_map import plain_pairs

    given = plain_pairs(chosen)
    if given is None or all(given.get(n) == c for n, c in pairs.items()):
        return []  # read as written, {name: channel}
    return [
        f"{path.name}: channels: {name!r} is neither a {what} of the file nor a name of "
        f"model {needs.model!r}, so the map reads {{{what}: name}} and renames the "
        f"{what} {channel!r} (the model's {channel!r}) to it; fix the name if it is a "
        f"mistyped {what}, or write the entry {{{name}: {{channel: {channel}}}}}"
        for name, channel in pairs.items()
        if name != channel and channel in needs.known and name not in needs.known
    ]


_NAME_LIKE = re.compile(r"[A-Za-z_][\w.\[\]()/ -]{0,63}")


def _name_like(columns: Iterable[str]) -> list[str] | None:
    """The columns when every one reads as a channel name, else None.

    A config can name any file as a flight; quoting a first line that is not a
    header of names (``AWS_SECRET=...``) would put it into the error and the CI log.
    """
    cols = [str(c) for c in columns]
    ok = all(_NAME_LIKE.fullmatch(c) and "=" not in c for c in cols)
    return cols if ok else None


def _column_hint(name: str, columns: Iterable[str]) -> str:
    """'; did you mean X?' or the channels, only from a header of names."""
    named = _name_like(columns)
    return _hint(name, named, "its channels") if named is not None else ""


def _mapped(chosen: Any) -> dict[str, str] | None:
    """``{model_name: channel}`` of a channel map with at least one full entry (its
    direction is then fixed); None for a list or a mapping of plain names."""
    if not isinstance(chosen, Mapping) or not any(
        isinstance(v, ChannelEntry) for v in chosen.values()
    ):
        return None
    return {
        str(k): (v.channel if isinstance(v, ChannelEntry) else str(v)) for k, v in chosen.items()
    }


def _unit_faults(spec: FileFlights) -> list[tuple[str, str]]:
    """(key path, fault) for every unit conversion of the channel map that is not known."""
    from ...io.channel_map import UNIT_CONVERSIONS

    if not isinstance(spec.channels, Mapping):
        return []
    known = sorted(UNIT_CONVERSIONS)
    out = []
    for name, entry in spec.channels.items():
        if isinstance(entry, ChannelEntry) and entry.unit is not None:
            if entry.unit not in UNIT_CONVERSIONS:
                close = difflib.get_close_matches(entry.unit, known, n=2, cutoff=0.6)
                hint = (
                    "; did you mean " + " or ".join(repr(c) for c in close) + "?" if close else ""
                )
                out.append(
                    (
                        f"channels.{name}.unit",
                        f"no known conversion from {entry.unit!r}{hint} "
                        f"(known units: {', '.join(known)})",
                    )
                )
    return out


def _stated_unit_faults(path: Path, header: _Header, spec: FileFlights) -> list[tuple[str, str]]:
    """(key path, fault) for a map unit that contradicts the unit the file states for its
    channel (`aeroid.apply_channel_map` refuses it at load: deg applied to rad values)."""
    from ...io.channel_map import UNIT_CONVERSIONS

    if not isinstance(spec.channels, Mapping) or not header.units:
        return []
    out = []
    for name, entry in spec.channels.items():
        if not isinstance(entry, ChannelEntry) or entry.unit is None:
            continue
        stated = header.units.get(entry.channel, "")
        if stated in UNIT_CONVERSIONS and stated != entry.unit:
            out.append(
                (
                    f"channels.{name}.unit",
                    f"{path.name}: unit {entry.unit!r} contradicts the unit {stated!r} the "
                    f"file states for {entry.channel!r}; drop the unit or fix it",
                )
            )
    return out


def _window_faults(path: Path, header: _Header, spec: FileFlights) -> list[tuple[str, str]]:
    """(key path, fault) for a window outside the log, or a window or segmentation the
    log cannot give (a mode or event it lacks, an input it does not carry)."""
    if header.log is None or (spec.window is None and spec.segments is None):
        return []
    from ...io.channel_map import flight_windows, resolve_window

    log = header.log
    names = list(log.channels)
    if spec.channels is None:
        sources = names
    else:
        sources = list(_picked(path, names, spec.channels, []).values())
    sources = [s for s in sources if s in log.channels]
    out: list[tuple[str, str]] = []
    if spec.window is not None:
        try:
            t0, t1, how = resolve_window(log, spec.window)
        except AeroidError as exc:
            return [("window", f"{path.name}: {exc}")]
        if sources:
            lo = max(float(log.channels[s].time[0]) for s in sources)
            hi = min(float(log.channels[s].time[-1]) for s in sources)
            if how["way"] != "time" and min(t1, hi) > max(t0, lo):
                t0, t1 = max(t0, lo), min(t1, hi)  # a mode or events window is clipped
            if t0 < lo or t1 > hi:
                out.append(
                    (
                        "window",
                        f"{path.name}: [{t0:.6g}, {t1:.6g}] s is not inside the span "
                        f"[{lo:.6g}, {hi:.6g}] s that the mapped channels cover",
                    )
                )
    if spec.segments is not None:
        try:
            found = flight_windows(log, spec.segments, channels=spec.channels)
        except AeroidError as exc:
            return [*out, ("segments", f"{path.name}: {exc}")]
        if not found:
            out.append(("segments", f"{path.name}: no manoeuvre window found"))
    return out


def _picked(path: Path, columns: list[str], chosen: Any, faults: list[str]) -> dict[str, str]:
    """``{name: channel}`` as the loader picks them: a list keeps its names, a map with a
    full entry reads ``{name: channel}``, a map of plain names the way round the file's
    channels decide (`aeroid.io.channel_map.orient`; one that reads both ways is a fault)."""
    from ...io.channel_map import orient

    if not isinstance(chosen, Mapping):
        return {str(c): str(c) for c in chosen}
    pairs = _mapped(chosen)
    if pairs is not None:
        return pairs
    try:
        return dict(orient(chosen, columns, where=path.name))
    except AeroidError as exc:
        faults.append(str(exc))
        return {}


# -- headers --------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Header:
    columns: list[str]
    has_time: bool = True  # the columns include the time column (a table, not a log)
    log: Any = None  # the log read (a FlightLog), for the checks of windows
    units: Mapping[str, str] | None = None  # the units the file states, by channel


def _header(
    path: Path,
    time_column: str | None = None,
    allow_external: bool = False,
    *,
    names_only: bool = False,
) -> _Header | None:
    """A flight file's column names, from its header only; None for an unknown format.
    With `names_only`, an HDF5 log's channels are named from their shapes, unread."""
    from ...errors import DataFormatError

    log = _log_listing(path, time_column, allow_external, names_only=names_only)
    if log is not None:
        return log
    suffix = path.suffix.lower()
    if suffix in _CSV_SUFFIXES:
        from ...io.data import stated_units

        return _Header(_csv_header(path), units=stated_units(path))
    if suffix in _PARQUET_SUFFIXES:
        try:
            import pyarrow.parquet as pq

            return _Header([str(n) for n in pq.read_schema(path).names])
        except ImportError:
            return None
        except Exception as exc:  # pyarrow raises many types for a corrupt file
            raise DataFormatError(f"{path}: not a readable Parquet file ({exc})") from None
    if suffix == ".mat":
        return _Header(_mat_header(path))
    return None


def _log_listing(
    path: Path, time_column: str | None, allow_external: bool, *, names_only: bool = False
) -> _Header | None:
    """A flight log's channels (`aeroid.list_channels`, where this aeroid reads logs);
    None when `path` is not a log (a table) or logs cannot be listed. With `names_only`
    an HDF5 file's datasets are named, not read (a check must not load gigabytes), and
    the header carries no log."""
    try:
        from ...io.logs import listing, read_selected, sniff_format
    except ImportError:
        return None
    fmt = sniff_format(path)  # the first bytes, then the suffix, as the loader decides
    if fmt is None:
        return None
    if names_only and fmt == "hdf5":
        log = read_selected(path, fmt, time_column, allow_external, ())
        return _Header([str(n) for n in log.metadata.get("unread", ())], has_time=False)
    log = read_selected(path, fmt, time_column, allow_external, None)
    names = listing(log).names
    # a log's time axis is the reader's business, not one of the channels
    units = {str(c.name): str(c.unit) for c in log.channels.values() if c.unit}
    return _Header([str(n) for n in names], has_time=False, log=log, units=units)


def _csv_header(path: Path) -> list[str]:
    """The first line of a CSV file that is not a comment, read without blocking."""
    from ...errors import DataFormatError

    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except OSError as exc:
        raise DataFormatError(f"{path}: cannot read it ({exc.strerror})") from None
    with os.fdopen(fd, "rb") as fh:
        if not stat.S_ISREG(os.fstat(fh.fileno()).st_mode):  # replaced since the stat
            raise DataFormatError(f"{path}: not a regular file")
        head = fh.read(_HEADER_BYTES)
    try:
        text = head.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        if exc.start < len(head) - 4:  # not merely a character cut at the end of the read
            raise DataFormatError(f"{path}: not a UTF-8 text file") from None
        text = head[: exc.start].decode("utf-8-sig")
    lines = text.splitlines()
    if len(head) == _HEADER_BYTES and lines:
        lines = lines[:-1]  # the last line read may be cut short
    for row in csv.reader(lines):
        if row and not row[0].lstrip().startswith("#"):
            return [h.strip() for h in row]
    raise DataFormatError(f"{path}: no header line (empty file, or only comments)")


def _mat_header(path: Path) -> list[str]:
    """The channels `aeroid.load_flight_test` makes of a MATLAB file, from its contents table."""
    import scipy.io

    from ...errors import DataFormatError

    try:
        table = scipy.io.whosmat(path)
    except Exception as exc:  # scipy raises ValueError/TypeError/NotImplementedError
        raise DataFormatError(
            f"{path}: not a readable MATLAB file ({exc}); v7.3 (HDF5) files are not supported"
        ) from None
    columns: list[str] = []
    for name, shape, kind in table:
        if name.startswith("__") or kind not in _MATLAB_NUMERIC:
            continue
        dims = [d for d in shape if d != 1]  # loaded with squeeze_me
        if len(dims) == 1 and dims[0] >= 2:
            columns.append(name)
        elif len(dims) == 2:
            # a matrix: one channel per column of its longer orientation
            columns += [f"{name}_{j}" for j in range(min(dims))]
    return columns
