"""One identifiability check, with one threshold, for every estimator and design tool.

The information (Fisher) matrix is scaled to unit diagonal, so that its
eigenvalues measure how well a combination of parameters is determined
relative to what the parameters' own sensitivities promise. A combination
whose relative eigenvalue is below `RCOND` has a standard error more than
``1 / sqrt(RCOND)`` (about 3e4) times those sensitivities suggest: the data
cannot separate its members, and it is reported by name rather than given a
huge (or, after truncation, a silently small) error bar. A parameter whose
own information is nil next to the others' (`NO_EFFECT`) is reported alone.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

__all__ = ["NO_EFFECT", "RCOND", "unidentifiable"]

FloatArray = NDArray[np.float64]

# Relative eigenvalue of the unit-diagonal information below which a direction is null.
RCOND = 1e-9
# A parameter whose sensitivity (root information) is below this fraction of the
# largest has no effect on the data to working precision.
NO_EFFECT = 1e-14
# The members of a null direction: the parameters whose share of it is at least a
# tenth of the largest share.
_MEMBER = 0.1


def unidentifiable(
    information: FloatArray, names: Sequence[str]
) -> tuple[list[tuple[str, ...]], NDArray[np.bool_]]:
    """The parameter groups the data cannot separate, and which parameters are in one.

    Parameters
    ----------
    information : (n, n) array
        The information (Fisher, or ``J^T W J``) matrix of the parameters.
    names : sequence of str
        The parameters' names, in the matrix's order.

    Returns
    -------
    combos : list of tuple of str
        Each group once: a parameter without effect alone, else the members of
        one near-null direction.
    null : (n,) bool array
        True for the parameters in any group.
    """
    m = np.asarray(information, dtype=np.float64)
    n = m.shape[0]
    d = np.sqrt(np.clip(np.diag(m), 0.0, None))
    zero = d <= 1e-300 + NO_EFFECT * (float(d.max()) if n else 0.0)
    combos: list[tuple[str, ...]] = [(names[j],) for j in np.flatnonzero(zero).tolist()]
    null = zero.copy()
    live = np.flatnonzero(~zero)
    if live.size:
        dl = d[live]
        mn = m[np.ix_(live, live)] / np.outer(dl, dl)
        evals, evecs = np.linalg.eigh(0.5 * (mn + mn.T))
        top = max(float(evals[-1]), 1e-300)
        for k in np.flatnonzero(evals < RCOND * top).tolist():
            share = np.abs(evecs[:, k])
            members = live[np.flatnonzero(share >= _MEMBER * share.max())].tolist()
            group = tuple(names[j] for j in members)
            # two near-null directions can share their members: one group is told once
            if group not in combos:
                combos.append(group)
                null[members] = True
    return combos, null
