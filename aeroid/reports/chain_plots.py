"""Walker traces of an ensemble sampler's chain (`SamplerRun.plot`, `EnsembleRun.plot`)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from .plotting import _cn, figure

__all__ = ["plot_chain"]


def plot_chain(chain: Any, names: Sequence[str], *, max_walkers: int = 32) -> Figure:
    """Each parameter's walkers against the kept step, one panel a parameter.

    Parameters
    ----------
    chain : array_like, shape (n_kept, n_walkers, n_dim)
        The kept walker positions.
    names : sequence of str
        A label per parameter (``n_dim`` of them).
    max_walkers : int, optional
        Most walkers drawn a panel (evenly picked): more only darken the band.

    Returns
    -------
    matplotlib.figure.Figure
    """
    c = np.asarray(chain, dtype=np.float64)
    every = max(1, -(-c.shape[1] // max(1, int(max_walkers))))
    fig, axes = figure(len(names), height=1.4, hgap=0.35, sharex=True)
    for j, name in enumerate(names):
        ax = axes[j, 0]
        ax.plot(c[:, ::every, j], lw=0.4, color=_cn(0), alpha=0.4)
        ax.set_ylabel(name, fontsize=8)
    axes[-1, 0].set_xlabel("kept step")
    return fig
