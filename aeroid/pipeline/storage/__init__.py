"""The store seam: results <-> entries. The result store (zip entries of Zarr v3
groups, the codec, digests), claims between runs, the index of entries checked
whole, and `commits.put`, a task's result written in one call."""
