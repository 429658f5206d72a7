"""The base class `aeroid.Model` derives from, below every module that takes one.

The integrators and the compiled paths (`_compiled`, `_jax`) sit below
`aeroid.models.model` (it calls them) yet must tell a `Model` from a stepped
simulator; they test against this base instead of importing `Model`.
"""

from __future__ import annotations

__all__ = ["ContinuousModel"]


class ContinuousModel:
    """A model with a continuous dynamics callable: `aeroid.Model` and its subclasses."""

    __slots__ = ()
