"""Equation error for a transfer function on a record's Fourier transforms.

Levy's method (Klein & Morelli sec. 7.3; SIDPAC's ``tfest``): multiplying
``Y = N(jω)/D(jω) U`` through by the monic denominator gives an equation linear
in the coefficients,

    (jω)^n Y = Σ_k b_k (jω)^k U − Σ_(k<n) a_k (jω)^k Y,

each frequency's divided by ``(jω)^(n-1)`` as SIDPAC's ``tfregr`` divides it
(the response is then ``jω Y`` at any order), and solved by least squares on
the transforms at the chosen frequencies: the
Fourier transform regression `equation_error` solves in the frequency domain,
with these columns, and its error bars (the frequency sandwich by default).
The output's noise enters the regressors too, so the estimates lean towards
zero as that noise grows (the equation-error bias output error avoids); in
return there is no start and no iteration. A record's ends add polynomials in
``jω`` to the same equation (`_end_basis`): with ``boundary`` they are
estimated as further regressors, and kept by ``"auto"`` only where a Wald test
finds them.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .._stats import wald_p_value
from ..errors import IdentificationError
from ..estimation.regression import fourier_regression
from ._rational_fit import (
    FourierFit,
    FourierRequest,
    _end_basis,
    fourier_record,
    record_transforms,
)
from ._response_records import TransferFunctionFit

_END = "end_"


def fit_levy(req: FourierRequest) -> TransferFunctionFit:
    """`fit_transfer_function(..., fourier=True, method="equation_error")`."""
    from .frequency_domain import _BOUNDARY_LEVEL

    if req.delay is not False:
        raise IdentificationError(
            "delay: equation error is linear in the coefficients and fits no time delay; "
            "pass delay=False (or method='output_error')"
        )
    if req.start is not None:
        raise IdentificationError("start: equation error is linear and needs no start values")
    rec = record_transforms(req)
    data, input, output = req.data, req.input, req.output
    error_bars, boundary = req.error_bars, req.boundary
    st, w, m, n = rec.st, rec.w, rec.m, rec.n
    # each frequency's equation over (jω)^(n-1), as SIDPAC's tfregr weights them: the
    # response is then jω Y whatever the order, and the high frequencies do not
    # outweigh the rest by ω^(n-1)
    weight = (1j * w) ** (1 - n)
    columns = np.concatenate([st.sb * rec.U[:, None], -st.sa * rec.Y[:, None]], axis=1)
    columns = columns * weight[:, None]
    response = st.sn * rec.Y * weight
    for name, value in rec.held.items():
        response = response - columns[:, st.names.index(name)] * value
    names = [nm for nm, f in zip(st.names, rec.free, strict=True) if f]
    x = columns[:, rec.free]
    dt = float(np.mean(np.diff(data.time)))
    pair = f"{input} -> {output}"

    def solve(basis: Any) -> Any:
        xt = x if basis is None else np.concatenate([x, basis], axis=1)
        labels = names + ([] if basis is None else [f"{_END}{k}" for k in range(basis.shape[1])])
        # every column has content here: the check compares a column with itself
        norms = np.sqrt(np.sum(np.abs(xt) ** 2, axis=0)) / (dt * np.sqrt(w.size))
        try:
            return fourier_regression(
                response,
                xt,
                norms,
                labels,
                f"{output}",
                np.asarray(data.time, dtype=np.float64),
                dt,
                w / (2.0 * np.pi),
                has_const=False,
                error_bars=error_bars,
                span=rec.span,
            )
        except IdentificationError as exc:
            raise IdentificationError(f"transfer-function fit {pair}: {exc}") from None

    basis = None if boundary == "ignore" else _end_basis(w, rec.span, max(m, n))
    if basis is not None:
        basis = basis * weight[:, None]
    if basis is not None and 2 * w.size <= len(names) + basis.shape[1]:
        if boundary == "estimate":
            raise IdentificationError(
                f"boundary='estimate': {w.size} frequencies cannot fit {len(names)} "
                f"parameters and {basis.shape[1]} record-end terms"
            )
        basis = None
    fit = solve(basis)
    if basis is not None and boundary == "auto":
        ends = [k for k in fit.parameter_names if k.startswith(_END)]
        idx = [fit.parameter_names.index(k) for k in ends]
        est = np.array([fit.parameters[k] for k in ends])
        blocks = [fit.covariance[np.ix_(idx, idx)], fit.covariance_white[np.ix_(idx, idx)]]
        if wald_p_value(est, blocks) >= _BOUNDARY_LEVEL:
            basis = None  # not different from zero: the fit without them
            fit = solve(None)
    # back to the structure's order, the held parameters with no uncertainty
    p_all = len(st.names)
    theta = np.zeros(p_all)
    cov = np.zeros((p_all, p_all))
    nu = np.full(p_all, np.inf)
    where = [st.names.index(k) for k in names]
    for k, v in rec.held.items():
        theta[st.names.index(k)] = v
    theta[where] = [fit.parameters[k] for k in names]
    order = [fit.parameter_names.index(k) for k in names]
    cov[np.ix_(where, where)] = fit.covariance[np.ix_(order, order)]
    nu[where] = [fit.degrees_of_freedom[k] for k in names]
    stacked = np.concatenate([x.real, x.imag])
    info = np.zeros((p_all, p_all))
    info[np.ix_(where, where)] = stacked.T @ stacked
    r = fit.residuals
    sse = float(np.sum(r.real**2 + r.imag**2))
    found = FourierFit(theta, cov, info, nu, fit.fit_error**2, sse)
    return fourier_record(
        req, st, rec.free, found, w, rec.h, "equation_error", ends=basis is not None
    )
