"""Reading store entries: the store's own reader against zarr-python's ZipStore.

Both read an entry's attributes and every array (the digests, computed the
same way after either, are left out). Entries are a simulated flight and an
identification result, the two kinds a campaign reads most.

    python3 tests/benchmarks/bench_store_read.py
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from _timing import median_time

from aeroid import identify
from aeroid.models.catalog import short_period, short_period_flight
from aeroid.pipeline import ResultStore
from aeroid.pipeline.keys import canonical_json, sha256_hex
from aeroid.pipeline.storage.store import Entry

N_ENTRIES = 100  # each read 10 times: 1,000 reads per timing


def _fill(store: ResultStore) -> list[Entry]:
    data = short_period_flight(seed=3)
    fit = identify(short_period(), data, parameters=["M_alpha", "M_q"])
    entries = []
    for i in range(N_ENTRIES):
        task = {"i": i}
        key = sha256_hex(canonical_json(task))
        stage = "load" if i % 2 else "identify"
        store.commit(stage, key, data if i % 2 else fit, task=task)
        entries.append(Entry(key, stage, store.path_for(stage, key)))
    return entries


def _hand(store: ResultStore, entries: list[Entry]) -> None:
    from aeroid.pipeline.storage.store import _read_array

    for _ in range(10):
        for entry in entries:
            with store._members(entry) as read:
                meta = store._metadata(entry, read)
                for name in meta["digests"]:
                    _read_array(name, read)


def _zarr(entries: list[Entry]) -> None:
    import zarr

    for _ in range(10):
        for entry in entries:
            zipped = zarr.storage.ZipStore(entry.path, mode="r")
            group = zarr.open_group(store=zipped, mode="r", zarr_format=3)
            meta = group.attrs["aeroid"]
            for name in meta["digests"]:
                group[name][...]
            zipped.close()


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        store = ResultStore(Path(tmp) / "s")
        entries = _fill(store)
        hand = median_time(lambda: _hand(store, entries), 5, warm_up=True)
        via_zarr = median_time(lambda: _zarr(entries), 5, warm_up=True)
    reads = 10 * N_ENTRIES
    print(f"1,000 entry reads, hand reader: {hand:.3f} s ({1e3 * hand / reads:.3f} ms a read)")
    print(
        f"1,000 entry reads, zarr ZipStore: {via_zarr:.3f} s ({1e3 * via_zarr / reads:.3f} ms a read)"
    )
    print(f"zarr costs {via_zarr - hand:.2f} s more per 1,000 reads ({via_zarr / hand:.1f}x)")


if __name__ == "__main__":
    main()
