"""How far the variables of a MATLAB v5 file expand, measured before scipy reads them.

scipy allocates what a data element's own size tag says and decompresses into
it; the shape `whosmat` reports is a separate field. A variable declaring a
1x10 shape can still carry a tag and a zlib stream of gigabytes (a few MB of
file), so the shape check alone does not bound the memory a read takes.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Collection, Sequence
from pathlib import Path
from typing import Any

from ..errors import DataFormatError

_MI_COMPRESSED = 15
_CHUNK = 1 << 20  # compressed bytes read at a time
_OUT = 1 << 22  # decompressed bytes produced at a time (then dropped)


def check_mat_expansion(
    path: Path, listing: Sequence[tuple[str, Any, Any]], read: Collection[str], budget: int
) -> None:
    """Refuse a v5 file whose variables in `read` expand beyond `budget` bytes together.

    `listing` is `scipy.io.whosmat`'s, one entry per top-level element in file
    order. Compressed variables are inflated in bounded pieces and thrown away,
    so the check holds a few MB whatever the file claims. A v4 file (no v5
    header) stores its data uncompressed and is left alone.

    Raises
    ------
    DataFormatError
        Naming the variable that crosses the budget, or one whose element runs
        past the end of the file.
    """
    size = path.stat().st_size
    with open(path, "rb") as f:
        head = f.read(128)
        if len(head) < 128 or head[126:128] not in (b"IM", b"MI"):
            return
        order = "<" if head[126:128] == b"IM" else ">"
        pos, total = 128, 0
        for name, _, _ in listing:
            f.seek(pos)
            tag = f.read(8)
            if len(tag) < 8:
                raise DataFormatError(f"{path}: variable {name!r} is cut off (truncated file)")
            mdtype, nbytes = struct.unpack(order + "II", tag)
            end = pos + 8 + nbytes
            if end > size:
                raise DataFormatError(
                    f"{path}: variable {name!r} declares {nbytes} bytes, past the end of the "
                    f"{size}-byte file: truncated or corrupt"
                )
            if name in read:
                grown = (
                    _inflated_size(f, nbytes, budget - total)
                    if mdtype == _MI_COMPRESSED
                    else nbytes
                )
                total += grown
                if total > budget:
                    raise DataFormatError(
                        f"{path}: variable {name!r} expands beyond the {budget >> 20} MiB a "
                        "flight file may expand to (its size tags understate it, or the file "
                        "is a decompression bomb); not read"
                    )
            pos = end


def _inflated_size(f: Any, nbytes: int, allowed: int) -> int:
    """Bytes a zlib element of `nbytes` inflates to, counting stopped past `allowed`."""
    inflate = zlib.decompressobj()
    grown, left = 0, nbytes
    try:
        while left and grown <= allowed:
            data = f.read(min(left, _CHUNK))
            if not data:
                break
            left -= len(data)
            while data and grown <= allowed:
                grown += len(inflate.decompress(data, _OUT))
                data = inflate.unconsumed_tail
    except zlib.error:
        return grown  # scipy reports the corrupt stream when it reads it
    return grown
