"""Which way round a plain channel map reads: one rule for every reader of a file.

A mapping of names to names, ``{"elevator": "de"}``, is written either way round:
``{name: channel}`` (a `ChannelMap`'s reading, the model's name first) or ``{channel:
name}`` (a table's columns renamed, as `load_flight_test` has always read them). The
file decides, the same way in `load_flight_test` (tables and logs), `load_mapped`,
`apply_channel_map` and a campaign's file flights: the side whose names are all the
file's channels (its columns, a log's channels) is the channel side.

A map whose two sides both name the file's channels (a swap, a cycle, a column renamed
onto another column's name) reads both ways, and is refused: read the wrong way it
would be applied silently the wrong way round. One that pairs each name with itself
reads the same both ways. One whose sides both miss channels is read the way that
misses fewer (``{name: channel}`` on a tie), and its caller names the missing ones.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping
from typing import Any

from ..errors import DataFormatError


def plain_pairs(mapping: Any) -> dict[str, str] | None:
    """A mapping of strings only (the direction of which the file decides), else None."""
    if isinstance(mapping, Mapping) and all(
        isinstance(k, str) and isinstance(v, str) for k, v in mapping.items()
    ):
        return dict(mapping)
    return None


def orient_pairs(
    pairs: Mapping[str, str], available: Collection[str], where: str, sources: str = "channels"
) -> tuple[dict[str, str], list[str]]:
    """``{name: channel}`` from a plain map (module notes) and the channels of that
    reading the file lacks (for the caller to name in its own words).

    Raises
    ------
    DataFormatError
        Both sides name the file's `sources` (the map reads both ways), or two of
        them are renamed to one name (one would be dropped silently).
    """
    pairs = {str(k): str(v) for k, v in pairs.items()}
    if all(k == v for k, v in pairs.items()):
        return pairs, [v for v in pairs.values() if v not in available]
    keys_out = [k for k in pairs if k not in available]
    values_out = [v for v in pairs.values() if v not in available]
    if not keys_out and not values_out:
        shown = ", ".join(f"{k}: {v}" for k, v in pairs.items() if k != v)
        raise DataFormatError(
            f"{where}: channels: the map {{{shown}}} names {sources} of the file on both "
            "sides, so it reads both ways ({name: channel} or {channel: name}); give "
            "names that are not among its " + sources + " on one side (or, in a channel "
            "map, the entry form {name: {channel: ...}})"
        )
    if values_out and len(keys_out) < len(values_out):
        # {channel: name}: two channels given one name would leave one out silently
        by_name: dict[str, list[str]] = {}
        for channel, name in pairs.items():
            by_name.setdefault(name, []).append(channel)
        for name, channels in by_name.items():
            if len(channels) > 1:
                raise DataFormatError(
                    f"{where}: channels: {sources} {channels} are all renamed to {name!r}; "
                    f"give each its own channel name"
                )
        return {name: channel for channel, name in pairs.items()}, keys_out
    return pairs, values_out
