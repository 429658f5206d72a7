"""FVSysID chapter 7: recursive least squares for the ATTAS aerodynamic coefficients.

Jategaonkar ch. 7 (attas_regLS_RLS.m, RLSff.m): the regressions of chapter 6's
attas_regLS (CD, CL, Cm, CY, Cl, Cn of the joined elevator, aileron and rudder
manoeuvres, preprocessed by chapter 7's umr_reg_attas.m, which subtracts the
1st edition's sensor biases) solved by recursive least squares with a
forgetting factor: start at zero with ``P0 = 1e6 I`` (``1e7 I`` for Cm),
``lambda = 1``, gain ``P x / (lambda + x'P x)``, ``P <- (P - K x'P) / lambda``;
LS_Stat on the last estimate gives the standard deviations. FVSysID saved no
result: RLSff runs here in numpy (`_fvsysid_ls.rls_ff`), so the SIDPAC columns
hold its last estimate and LS_Stat's standard deviation.

Ours: ``aeroid.recursive_least_squares`` on the same regressors with the same
start and ``forgetting=1`` (default coloured bars; white, variant ``w.`` rows).
Variant ``b.`` rows put our last estimate next to the batch least squares
(the book's backslash and LS_Stat); ``f.`` rows rerun both with
``lambda = 0.995`` (memory about 200 samples, 8 s). Each fit's note gives the
largest difference of the two histories over the record, in LS_Stat sigmas.
"""

from __future__ import annotations

import pathlib
import sys
from collections.abc import Mapping
from typing import Any

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import _fvsysid_ls as F
import _sidpac as S
from ref_fvsysid_attas_ls import MODELS

CASE = "fvsysid_attas_rls"
SOURCE = "fvsysid"
# attas_regLS_RLS.m's diffuse start: 1e6 on the diagonal, 1e7 for Cm
P0 = {"Cm": 1.0e7}
FORGET = 0.995


def _rows(
    label: str,
    names: tuple[str, ...],
    ref: tuple[np.ndarray, np.ndarray],
    fit: Any,
    mcs: Mapping[str, float],
    seconds: float,
    *,
    variant: bool,
    note: str,
) -> list[dict[str, Any]]:
    return [
        S.row(
            CASE,
            f"{label}{name}",
            sidpac=ref[0][j],
            sidpac_se_white=ref[1][j],
            sidpac_se_corrected=None,
            ours=fit.parameters[name],
            ours_se=fit.stderr[name],
            mc_se=mcs.get(name),
            seconds=seconds,
            variant=variant,
            note=note,
        )
        for j, name in enumerate(names)
    ]


def fit_rows(
    ch: Mapping[str, np.ndarray], response: str, regressors: tuple[str, ...], *, mc: int, seed: int
) -> list[dict[str, Any]]:
    """RLSff and LS_Stat next to ``aeroid.recursive_least_squares`` for one coefficient."""
    import aeroid

    reg = {k: ch[k] for k in regressors}
    z = np.asarray(ch[response])
    x = np.column_stack([np.ones(z.size), *reg.values()])
    names = ("const", *regressors)
    p0 = P0.get(response, 1.0e6)
    batch = F.ls_stat(x, z)
    sigma = batch[1]
    rows: list[dict[str, Any]] = []
    for lam, tag in ((1.0, ""), (FORGET, "f.")):
        hist = F.rls_ff(x, z, lam, p0 * np.eye(x.shape[1]), np.zeros(x.shape[1]))
        book = (hist[-1], F.ls_std(x, z, hist[-1]))
        with S.Timer() as tm:
            ours = aeroid.recursive_least_squares(
                reg, z, dict(reg), forgetting=lam, initial_covariance=p0
            )
        white = aeroid.recursive_least_squares(
            reg, z, dict(reg), forgetting=lam, initial_covariance=p0, error_bars="white"
        )
        ours_hist = np.column_stack([ours.parameter(n) for n in names])
        gap = np.max(np.abs(ours_hist - hist), axis=0) / sigma
        note = (
            f"{response} lambda={lam:g}: histories differ by at most "
            + ", ".join(f"{n} {g:.1e}" for n, g in zip(names, gap, strict=True))
            + " LS_Stat sigma"
        )
        mcs: Mapping[str, float] = {}
        if lam == 1.0:
            fitted = x @ ours_hist[-1]

            def refit(zz: np.ndarray) -> Mapping[str, float]:
                return aeroid.recursive_least_squares(
                    reg, zz, dict(reg), initial_covariance=p0, error_bars="white"
                ).parameters

            mcs = S.monte_carlo(refit, fitted, z - fitted, mc, seed=seed)
        label = f"{tag}{response}_"
        rows += _rows(label, names, book, ours, mcs, tm.seconds, variant=bool(tag), note=note)
        if lam == 1.0:
            rows += _rows(
                f"w.{label}", names, book, white, mcs, tm.seconds, variant=True, note=note
            )
            batch_note = f"{response}: b. rows: FVSysID's batch LS (backslash) vs our RLS's last"
            rows += _rows(
                f"b.{label}", names, batch, ours, {}, tm.seconds, variant=True, note=batch_note
            )
    return rows


def run(folder: pathlib.Path, *, mc: int = 100, seed: int = 0) -> list[dict[str, Any]]:
    data, bounds = F.load(folder)
    ch = F.preprocess(data, bounds, edition=1)
    rows: list[dict[str, Any]] = []
    for k, (resp, regs) in enumerate(MODELS.items()):
        rows += fit_rows(ch, resp, regs, mc=mc, seed=seed + k)
    return rows


if __name__ == "__main__":
    raise SystemExit(S.main(CASE, run, source="fvsysid"))
