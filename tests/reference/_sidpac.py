"""Shared helpers of the SIDPAC reference suite (not part of the library).

The suite compares AeroID, called through its public API as a user would,
with the results SIDPAC V2.0 saved for its text examples and demos. The data
are not ours to ship: each script reads them from the folder named by the
environment variable ``AEROID_SIDPAC_DIR`` (the SIDPAC V2.0 folder holding
``Text_Examples/`` and ``Demos/``) and skips cleanly when it is unset or a
file is missing.

Besides SIDPAC's numbers each case runs a Monte Carlo on its own residuals:
the fitted model's outputs plus phase-randomised surrogates of the flight's
residuals (one random phase per frequency shared by every output, so the
residual auto- and cross-spectra are kept exactly), refitted N times. The
scatter of the refits is the standard error this flight's noise really
produces.
"""

from __future__ import annotations

import argparse
import math
import os
import pathlib
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

ENV = "AEROID_SIDPAC_DIR"
# Jategaonkar's FVSysID flight data (the book's flt_data folder), for the ref_fvsysid_* cases
FVSYSID_ENV = "AEROID_FVSYSID_DIR"
SOURCES = {"sidpac": ENV, "fvsysid": FVSYSID_ENV}
KEYS = (
    "case",
    "parameter",
    "sidpac",
    "sidpac_se_white",
    "sidpac_se_corrected",
    "ours",
    "ours_se",
    "delta_sigma",
    "se_ratio",
    "mc_se",
    "mc_ratio",
    "seconds",
)

# the repository root, so a script run directly imports this checkout's aeroid
_ROOT = pathlib.Path(__file__).resolve().parents[2]
if str(_ROOT) not in sys.path:
    sys.path.insert(0, str(_ROOT))


class SkipCase(Exception):
    """Raised when a case cannot run here (data folder unset or a file missing)."""


def data_folder(source: str = "sidpac") -> pathlib.Path | None:
    """The data folder of `source` (``SOURCES``: its environment variable), or None when unset."""
    value = os.environ.get(SOURCES[source], "").strip()
    return pathlib.Path(value) if value else None


def need(folder: pathlib.Path, *relative: str, source: str = "sidpac") -> list[pathlib.Path]:
    """Paths of the files a case reads; SkipCase naming the first one missing."""
    what = {"sidpac": "the SIDPAC V2.0 folder", "fvsysid": "FVSysID's flt_data folder"}[source]
    paths = [folder / r for r in relative]
    for p in paths:
        if not p.is_file():
            raise SkipCase(f"{p} not found (is {SOURCES[source]} {what}?)")
    return paths


def loadmat(path: pathlib.Path) -> dict[str, Any]:
    """A ``.mat`` file as a dict of arrays (scipy's reader, structs as records)."""
    import scipy.io

    return dict(scipy.io.loadmat(str(path)))


def col(a: Any) -> np.ndarray:
    """A saved MATLAB vector as a flat float array."""
    return np.asarray(a, dtype=float).ravel()


def se(cov: Any) -> np.ndarray:
    """Standard errors from a saved covariance matrix."""
    return np.sqrt(np.diag(np.asarray(cov, dtype=float)))


def field(struct: Any, name: str) -> Any:
    """A field of a MATLAB struct as scipy reads it (1x1 record array)."""
    value = struct[name]
    while isinstance(value, np.ndarray) and value.dtype == object and value.size == 1:
        value = value.flat[0]
    if isinstance(value, np.ndarray) and value.size == 1:
        return float(value.ravel()[0])
    return value


def _ratio(a: float | None, b: float | None) -> float | None:
    if a is None or b is None or not np.isfinite(a) or not np.isfinite(b) or b == 0:
        return None
    return float(a) / float(b)


def row(
    case: str,
    parameter: str,
    *,
    sidpac: float | None,
    sidpac_se_white: float | None,
    sidpac_se_corrected: float | None,
    ours: float | None,
    ours_se: float | None,
    mc_se: float | None = None,
    seconds: float | None = None,
    note: str | None = None,
    delta_sigma: float | None = None,
    variant: bool = False,
) -> dict[str, Any]:
    """One table row with the derived columns filled in.

    ``variant`` marks a row for a non-default option (printed, left out of the
    case's summary, which judges the library's defaults).

    ``delta_sigma`` and ``se_ratio`` use SIDPAC's corrected standard error
    where it saved one, else its white one (a case with no SIDPAC error, compared
    with a truth, passes its own |delta|/sigma); ``mc_ratio`` is ours over the
    Monte Carlo scatter.
    """

    def f(v: Any) -> float | None:
        return None if v is None else float(v)

    ref = f(sidpac_se_corrected) if sidpac_se_corrected is not None else f(sidpac_se_white)
    delta = None
    if sidpac is not None and ours is not None and ref:
        delta = abs(float(ours) - float(sidpac)) / ref
    elif delta_sigma is not None:
        delta = abs(float(delta_sigma))
    out: dict[str, Any] = {
        "case": case,
        "parameter": parameter,
        "variant": bool(variant),
        "sidpac": f(sidpac),
        "sidpac_se_white": f(sidpac_se_white),
        "sidpac_se_corrected": f(sidpac_se_corrected),
        "ours": f(ours),
        "ours_se": f(ours_se),
        "delta_sigma": delta,
        "se_ratio": _ratio(f(ours_se), ref),
        "mc_se": f(mc_se),
        "mc_ratio": _ratio(f(ours_se), f(mc_se)),
        "seconds": f(seconds),
    }
    if note:
        out["note"] = note
    return out


def sidpac_mc_ratio(r: Mapping[str, Any]) -> float | None:
    """SIDPAC's standard error (corrected where saved) over the Monte Carlo one."""
    ref = r.get("sidpac_se_corrected")
    if ref is None:
        ref = r.get("sidpac_se_white")
    return _ratio(ref, r.get("mc_se"))


# ---------------------------------------------------------------- Monte Carlo


def phase_surrogate(residuals: Any, rng: np.random.Generator, *, low_bins: int = 3) -> np.ndarray:
    """A phase-randomised copy of residuals (n,) or (n, m).

    Every non-zero frequency below Nyquist is turned by one random phase
    shared by all columns, so each column's periodogram and every pair's
    cross-periodogram are kept exactly there; the Nyquist bin is kept. The
    zero-frequency bin, which a fitted bias empties, keeps its value plus a
    random real part with the power and cross-power, on average, of the
    `low_bins` lowest non-zero bins (else a bias would never move).
    """
    v = np.asarray(residuals, dtype=float)
    flat = v.ndim == 1
    v2 = v[:, None] if flat else v
    n = v2.shape[0]
    spectrum = np.fft.rfft(v2, axis=0)
    phase = np.exp(2j * np.pi * rng.random(spectrum.shape[0]))
    phase[0] = 1.0
    if n % 2 == 0:
        phase[-1] = 1.0
    out = spectrum * phase[:, None]
    k = min(low_bins, spectrum.shape[0] - 2 + n % 2)
    if k > 0:
        # sqrt(2/k) Re(X e^{i phi}) has mean outer product Re(X X*) / k per bin
        low = spectrum[1 : k + 1] * np.exp(2j * np.pi * rng.random(k))[:, None]
        out[0] = out[0] + np.sqrt(2.0 / k) * np.real(low).sum(axis=0)
    res = np.fft.irfft(out, n=n, axis=0)
    return res[:, 0] if flat else res


def monte_carlo(
    refit: Callable[[np.ndarray], Mapping[str, float]],
    fitted: Any,
    residuals: Any,
    n: int,
    *,
    seed: int = 0,
    draw: Callable[[np.random.Generator], np.ndarray] | None = None,
) -> dict[str, float]:
    """Standard error of each parameter over `n` refits of surrogate records.

    ``refit(z)`` fits the measured outputs ``z = fitted + surrogate`` (the
    shape of `fitted`) and returns the estimates by name; refits that raise
    are skipped (their count is printed). Empty when ``n < 2``. `draw`, when
    given, makes each record's noise instead (a known noise process; then
    `residuals` is not used).
    """
    if n < 2:
        return {}
    rng = np.random.default_rng(seed)
    y = np.asarray(fitted, dtype=float)
    draws: dict[str, list[float]] = {}
    failed = 0
    for _ in range(n):
        z = y + (phase_surrogate(residuals, rng) if draw is None else draw(rng))
        try:
            est = refit(z)
        except Exception as exc:  # a failed refit is counted, not fatal
            failed += 1
            if failed == 1:
                print(f"  (monte carlo refit failed: {type(exc).__name__}: {exc})")
            continue
        for k, val in est.items():
            draws.setdefault(k, []).append(float(val))
    if failed:
        print(f"  ({failed} of {n} monte carlo refits failed)")
    return {k: float(np.std(v, ddof=1)) for k, v in draws.items() if len(v) >= 2}


def transfer_monte_carlo(
    refit: Callable[[np.ndarray, np.ndarray], Mapping[str, float]],
    fit: Any,
    time: Any,
    u: Any,
    y: Any,
    n: int,
    *,
    seed: int = 0,
) -> dict[str, float]:
    """`monte_carlo` for a transfer function fitted to a record's transforms.

    The fitted ``T(s) e^{-tau s}`` (`fit`: a ``TransferFunctionFit``) is
    driven by the input with its straight-line trend removed, as the fit
    removes it, through a zero-padded FFT (the linear convolution from rest,
    improper numerators included); the residual is the detrended output less
    that response. Where the fit estimated the record's ends, the response
    starts from the initial state that fits the record best (least squares
    over the transfer function's free responses). ``refit(u, z)`` fits the
    detrended input and a surrogate output ``z`` and returns the estimates by
    name.
    """
    t = np.asarray(time, dtype=float) - float(time[0])
    dt = float(t[1] - t[0])

    def detrend(x: Any) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        return np.asarray(x - np.polyval(np.polyfit(t, x, 1), t), dtype=float)

    ud, yd = detrend(u), detrend(y)
    size = 4 * ud.size
    s = 2j * np.pi * np.fft.rfftfreq(size, dt)
    num = np.asarray(fit.numerator, dtype=float)
    den = np.asarray(fit.denominator, dtype=float)
    gain = np.polyval(num, s) / np.polyval(den, s) * np.exp(-s * float(fit.delay))
    yhat = np.fft.irfft(gain * np.fft.rfft(ud, size), size)[: ud.size]
    if fit.ends_estimated:
        # a fit that estimated the record's ends: its time response starts from the
        # initial state that best explains the record, not from rest (else the
        # surrogates would turn the record's initial transient into noise)
        import scipy.signal

        proper = np.polydiv(num, den)[1] if num.size >= den.size else num
        a, _, c, _ = scipy.signal.tf2ss(proper, den)
        free = np.column_stack(
            [
                scipy.signal.lsim((a, np.zeros((a.shape[0], 1)), c, [[0.0]]), None, t, X0=x0)[1]
                for x0 in np.eye(a.shape[0])
            ]
        )
        yhat = yhat + free @ np.linalg.lstsq(free, yd - yhat, rcond=None)[0]
    return monte_carlo(lambda z: refit(ud, z), yhat, yd - yhat, n, seed=seed)


class ColourRecorder:
    """``with ColourRecorder() as rec: ...`` records every call of the library's
    coloured-residual kernel (``aeroid._colour.colored_covariance``) made inside,
    with the Monte Carlo's linear expectation (`linear_mc`) of the same fit.

    `annotate` then adds to each row whose standard error is one the kernel
    returned: ``lin_se`` (that expectation), ``lin_dof`` (its degrees of
    freedom), ``ours_dof`` (the kernel's Satterthwaite ones), and ``mc_lev``
    and ``sid_lev`` (`leverage_ratio`: how low the fit's leverage alone makes
    the Monte Carlo and SIDPAC's colores read, were the noise white).
    """

    def __init__(self) -> None:
        self.calls: list[tuple[np.ndarray, ...]] = []

    def __enter__(self) -> ColourRecorder:
        import aeroid._colour as colour
        import aeroid.estimation._regression_fits as fits

        self._saved = [(colour, colour.colored_covariance), (fits, fits.colored_covariance)]
        original = colour.colored_covariance

        def recorded(sens: Any, resid: Any, m_inv: Any, **kw: Any) -> Any:
            cov, nu = original(sens, resid, m_inv, **kw)
            var, dof = linear_mc(sens, resid, m_inv)
            levs = (leverage_ratio(sens, m_inv), leverage_ratio(sens, m_inv, padded=True))
            self.calls.append((np.sqrt(np.abs(np.diag(cov))), nu, np.sqrt(var), dof, *levs))
            return cov, nu

        for mod, _ in self._saved:
            mod.colored_covariance = recorded  # type: ignore[attr-defined]
        return self

    def __exit__(self, *exc: object) -> None:
        for mod, fn in self._saved:
            mod.colored_covariance = fn  # type: ignore[attr-defined]

    def annotate(self, rows: Sequence[dict[str, Any]]) -> None:
        for r in rows:
            se_r = r.get("ours_se")
            if se_r is None or not np.isfinite(se_r) or se_r <= 0:
                continue
            for se_k, nu_k, lin_k, dof_k, mc_lev, sid_lev in reversed(self.calls):
                hit = np.flatnonzero(np.abs(se_k - se_r) <= 1e-9 * se_r)
                if hit.size:
                    j = int(hit[0])
                    r["ours_dof"] = float(nu_k[j])
                    r["lin_se"] = float(lin_k[j])
                    r["lin_dof"] = float(dof_k[j])
                    r["mc_lev"] = float(mc_lev[j])
                    r["sid_lev"] = float(sid_lev[j])
                    r["lin_ratio"] = _ratio(se_r, float(lin_k[j]))
                    break


def linear_mc(
    sens: Sequence[Any], resid: Sequence[Any], m_inv: Any, *, low_bins: int = 3
) -> tuple[np.ndarray, np.ndarray]:
    """The Monte Carlo's variance to first order, and its degrees of freedom.

    A refit moves the estimate by ``M^-1 sum_t G_t' s_t`` for the surrogate
    ``s`` (`phase_surrogate`): on the n-point grid each bin's transform turned
    by its own random phase, so the variance is the raw-periodogram sandwich
    ``(1/n^2) sum_k |V~_k^H u~_k|^2`` (``V = G M^-1``; inner bins twice, the
    Nyquist bin, kept, nothing; bin 0 the mean real cross-power of the
    `low_bins` lowest bins). Its degrees of freedom are Satterthwaite's with
    each bin's term a periodogram bin (relative variance one): few where the
    sensitivity sits on few bins, as a constant's does, so the Monte Carlo's
    own answer is then a noisy draw around the spectrum's expectation.
    """
    m_inv = np.asarray(m_inv, dtype=float)
    p = m_inv.shape[0]
    total = np.zeros(p)
    squares = np.zeros(p)
    for g, u in zip(sens, resid, strict=True):
        g = np.asarray(g, dtype=float)
        u = np.asarray(u, dtype=float)
        n = u.shape[0]
        vf = np.fft.rfft(g, axis=0) @ m_inv  # (bins, n_y, p)
        uf = np.fft.rfft(u, axis=0)  # (bins, n_y)
        score = np.einsum("kap,ka->kp", vf.conj(), uf)
        terms = 2.0 * np.abs(score) ** 2 / n**2
        terms[0] = 0.0
        if n % 2 == 0:
            terms[-1] = 0.0
        k = min(low_bins, uf.shape[0] - 2 + n % 2)
        if k > 0:
            low = uf[1 : k + 1]
            s0 = np.einsum("ka,kb->ab", low, low.conj()).real / k
            v0 = vf[0].real
            terms[0] = np.einsum("ap,ab,bp->p", v0, s0, v0) / n**2
        total += terms.sum(axis=0)
        squares += (terms**2).sum(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        dof = np.where(squares > 0, 2.0 * total**2 / squares, np.inf)
    return total, dof


def leverage_ratio(
    sens: Sequence[Any], m_inv: Any, *, padded: bool = False, low_bins: int = 3
) -> np.ndarray:
    """What the fit's leverage alone does to a residual-based standard error.

    Were the noise white (unit variance, the weighting `sens` carries), the
    residuals ``u = (I - H) e`` would have ``E[u~_k u~_k^H] = n I - G~_k M^-1
    G~_k^H`` at bin k: the fit empties the bins where the sensitivities sit.
    Returned per parameter: the expectation of a raw-periodogram sandwich of
    those residuals over the true standard error, exactly. With ``padded``
    False it is the suite's Monte Carlo (`linear_mc`: the n-point grid, the
    Nyquist bin nothing, bin 0 filled from the `low_bins` lowest); with
    ``padded`` True, the sandwich over the residuals' biased autocorrelation at
    every lag (the 2n-point grid, bin 0 as it is), SIDPAC's colores. Below one
    where a parameter's sensitivity sits on few, strongly fitted bins (a
    constant's at w = 0, a slow regressor's on the lowest bins).
    """
    m_inv = np.asarray(m_inv, dtype=float)
    p = m_inv.shape[0]
    num = np.zeros(p)
    den = np.zeros(p)
    for g in sens:
        g = np.asarray(g, dtype=float)
        n = g.shape[0]
        size = 2 * n if padded else n
        gf = np.fft.rfft(g, size, axis=0)  # (bins, n_y, p)
        vf = gf @ m_inv
        keep = np.eye(g.shape[1])[None] - np.einsum("kap,pq,kbq->kab", gf, m_inv, gf.conj()) / n
        weight = np.full(gf.shape[0], 2.0)
        weight[0] = 1.0
        if size % 2 == 0:
            weight[-1] = 1.0
        total = np.einsum("kap,kap->kp", vf.conj(), vf).real * weight[:, None]
        kept = np.einsum("kap,kab,kbp->kp", vf.conj(), keep, vf).real * weight[:, None]
        if not padded:
            if size % 2 == 0:
                kept[-1] = 0.0
            k = min(low_bins, gf.shape[0] - 2 + size % 2)
            s0 = keep[1 : k + 1].real.mean(axis=0) if k > 0 else np.zeros_like(keep[0].real)
            v0 = vf[0].real
            kept[0] = np.einsum("ap,ab,bp->p", v0, s0, v0)
        num += kept.sum(axis=0) / size
        den += total.sum(axis=0) / size
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.asarray(np.sqrt(np.clip(num, 0.0, None) / den), dtype=np.float64)


def chi2_band(dof: float, level: float = 0.95) -> tuple[float, float]:
    """The central `level` range of ``sqrt(chi2_nu / nu)``: where a standard error
    resting on `dof` degrees of freedom falls about its expectation."""
    from scipy.stats import chi2

    if not np.isfinite(dof):
        return 1.0, 1.0
    lo, hi = chi2.ppf([(1 - level) / 2, (1 + level) / 2], dof)
    return float(np.sqrt(lo / dof)), float(np.sqrt(hi / dof))


class Timer:
    """``with Timer() as t: ...`` then ``t.seconds``."""

    seconds: float = 0.0

    def __enter__(self) -> Timer:
        self._t0 = time.perf_counter()
        return self

    def __exit__(self, *exc: object) -> None:
        self.seconds = time.perf_counter() - self._t0


# ---------------------------------------------------------------- printing


def _fmt(v: Any, width: int, digits: int = 4) -> str:
    if v is None:
        return "-".rjust(width)
    if isinstance(v, str):
        return v[:width].rjust(width)
    x = float(v)
    if not math.isfinite(x):
        return str(x).rjust(width)
    if x != 0 and (abs(x) >= 1e4 or abs(x) < 1e-3):
        return f"{x:.{digits - 1}e}".rjust(width)
    return f"{x:.{digits}g}".rjust(width)


_COLUMNS = (
    ("parameter", "parameter", 14),
    ("sidpac", "sidpac", 11),
    ("sidpac_se_white", "se white", 10),
    ("sidpac_se_corrected", "se corr", 10),
    ("ours", "ours", 11),
    ("ours_se", "ours se", 10),
    ("delta_sigma", "|d|/sig", 8),
    ("se_ratio", "se/sid", 7),
    ("mc_se", "mc se", 10),
    ("mc_ratio", "ours/mc", 8),
    ("sidpac_mc", "sid/mc", 7),
    ("lin_se", "mc lin", 10),
    ("lin_ratio", "ours/lin", 8),
    ("lin_dof", "lin nu", 7),
    ("mc_lev", "mc lev", 7),
    ("sid_lev", "sid lev", 7),
    ("ours_dof", "ours nu", 8),
)


def print_table(rows: Sequence[Mapping[str, Any]], *, title: str | None = None) -> None:
    """Print one case's rows (with SIDPAC/MC added) and any notes."""
    if title:
        print(f"\n== {title}")
    print(" ".join(h.rjust(w) if k != "parameter" else h.ljust(w) for k, h, w in _COLUMNS))
    for r in rows:
        cells = []
        for k, _, w in _COLUMNS:
            v = sidpac_mc_ratio(r) if k == "sidpac_mc" else r.get(k)
            cells.append(str(v)[:w].ljust(w) if k == "parameter" else _fmt(v, w))
        print(" ".join(cells))
    secs = {r.get("seconds") for r in rows if r.get("seconds") is not None}
    if secs:
        print(f"time of our fit: {max(secs):.2f} s")
    notes = dict.fromkeys(r["note"] for r in rows if r.get("note"))
    for n in notes:
        print(f"note: {n}")


BIAS_MARKERS = ("const", "bias", "b_")


def is_derivative(name: str) -> bool:
    """A stability or control derivative, not a bias, constant or sensor parameter."""
    base = name.split(":")[-1]
    stem = base.split("_", 1)[-1] if "_" in base else base
    if any(m in base for m in ("const", "bias")) or base.startswith(("b_", "k_", "tau_")):
        return False
    return not (base.endswith("_0") or stem == "0")


def summary(rows: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """One case in numbers: the largest |delta|/sigma, the ranges of the
    standard-error ratios (all rows; derivatives against SIDPAC's corrected
    errors), and how many rows meet the targets (derivative se within
    0.8-1.25 of SIDPAC's corrected, every se within 0.8-1.25 of the Monte
    Carlo, every estimate within 1 SIDPAC sigma); the Monte Carlo's figures
    also apart for constants, biases and sensor parameters (``cb_*``), where
    it is low by construction (`check_mc.py`)."""

    def span(vals: list[Any]) -> tuple[float | None, float | None]:
        v = [float(x) for x in vals if x is not None]
        return (min(v), max(v)) if v else (None, None)

    def inside(vals: list[Any], lo: float, hi: float) -> str:
        v = [float(x) for x in vals if x is not None]
        return f"{sum(lo <= x <= hi for x in v)}/{len(v)}" if v else "-"

    rows = [r for r in rows if not r.get("variant")]
    d = [r.get("delta_sigma") for r in rows if r.get("delta_sigma") is not None]
    deriv_corr = [
        _ratio(r.get("ours_se"), r.get("sidpac_se_corrected"))
        for r in rows
        if is_derivative(str(r.get("parameter"))) and r.get("sidpac_se_corrected") is not None
    ]
    se_lo, se_hi = span([r.get("se_ratio") for r in rows])
    dv_lo, dv_hi = span(deriv_corr)
    mc_lo, mc_hi = span([r.get("mc_ratio") for r in rows])
    sm_lo, sm_hi = span([sidpac_mc_ratio(r) for r in rows])
    secs = [r.get("seconds") for r in rows if r.get("seconds") is not None]
    ln_lo, ln_hi = span([r.get("lin_ratio") for r in rows])
    drv = [r for r in rows if is_derivative(str(r.get("parameter")))]
    cb = [r for r in rows if not is_derivative(str(r.get("parameter")))]
    cb_lo, cb_hi = span([r.get("mc_ratio") for r in cb])
    cbl_lo, cbl_hi = span([r.get("lin_ratio") for r in cb])
    cbn_lo, cbn_hi = span([r.get("lin_dof") for r in cb])
    cbm_lo, cbm_hi = span([r.get("mc_lev") for r in cb])
    cbs_lo, cbs_hi = span([r.get("sid_lev") for r in cb])
    # derivatives over SIDPAC's corrected bars with the fit's leverage taken out of them
    lev_rows = [
        r for r in drv if r.get("sidpac_se_corrected") is not None and r.get("sid_lev") is not None
    ]
    drv_lev = [_ratio(r.get("ours_se"), r["sidpac_se_corrected"] / r["sid_lev"]) for r in lev_rows]
    dl_lo, dl_hi = span(drv_lev)
    ds_lo, ds_hi = span([r["sid_lev"] for r in lev_rows])
    return {
        "cb_mclev_min": cbm_lo,
        "cb_mclev_max": cbm_hi,
        "cb_sidlev_min": cbs_lo,
        "cb_sidlev_max": cbs_hi,
        "drv_lev_min": dl_lo,
        "drv_lev_max": dl_hi,
        "drv_sidlev_min": ds_lo,
        "drv_sidlev_max": ds_hi,
        "target_se_lev": inside(drv_lev, 0.8, 1.25),
        "cb_mc_min": cb_lo,
        "cb_mc_max": cb_hi,
        "cb_lin_min": cbl_lo,
        "cb_lin_max": cbl_hi,
        "cb_nu_min": cbn_lo,
        "cb_nu_max": cbn_hi,
        "target_mc_drv": inside([r.get("mc_ratio") for r in drv], 0.8, 1.25),
        "target_mc_cb": inside([r.get("mc_ratio") for r in cb], 0.8, 1.25),
        "lin_min": ln_lo,
        "lin_max": ln_hi,
        "mc_spread": spread_explained(rows),
        "max_delta_sigma": max(d) if d else None,
        "se_min": se_lo,
        "se_max": se_hi,
        "deriv_corr_min": dv_lo,
        "deriv_corr_max": dv_hi,
        "mc_min": mc_lo,
        "mc_max": mc_hi,
        "sidpac_mc_min": sm_lo,
        "sidpac_mc_max": sm_hi,
        "seconds": max(secs) if secs else None,
        "target_se": inside(deriv_corr, 0.8, 1.25),
        "target_mc": inside([r.get("mc_ratio") for r in rows], 0.8, 1.25),
        "target_estimate": inside(d, 0.0, 1.0),
    }


def spread_explained(rows: Sequence[Mapping[str, Any]]) -> str:
    """Of the rows outside 0.8-1.25 of the Monte Carlo, those whose ratio to the
    Monte Carlo's linear expectation lies inside the 95 % range that expectation's
    own degrees of freedom give it (`chi2_band`): the Monte Carlo's answer for this
    flight is a draw that far from the spectrum the kernel estimates."""
    out = [r for r in rows if r.get("mc_ratio") is not None and not 0.8 <= r["mc_ratio"] <= 1.25]
    if not out:
        return "-"
    ok = 0
    for r in out:
        if r.get("lin_ratio") is None or r.get("lin_dof") is None:
            continue
        lo, hi = chi2_band(float(r["lin_dof"]))
        ok += lo <= 1.0 / float(r["lin_ratio"]) <= hi
    return f"{ok}/{len(out)}"


def arguments(argv: Sequence[str] | None = None, *, description: str = "") -> argparse.Namespace:
    """The common command line: ``--mc N`` (0 skips) and ``--seed``."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--mc", type=int, default=100, help="Monte Carlo refits (0 to skip)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the surrogates")
    return ap.parse_known_args(argv)[0]


def main(
    case: str,
    run: Callable[..., list[dict[str, Any]]],
    argv: Sequence[str] | None = None,
    *,
    source: str = "sidpac",
) -> int:
    """What a case script's ``__main__`` does: run it and print its table."""
    args = arguments(argv, description=f"{source} reference case {case}")
    folder = data_folder(source)
    if folder is None:
        print(f"skipped {case}: set {SOURCES[source]} to run the reference suite")
        return 0
    try:
        rows = run(folder, mc=args.mc, seed=args.seed)
    except SkipCase as exc:
        print(f"skipped {case}: {exc}")
        return 0
    print_table(rows, title=case)
    return 0


# ---------------------------------------------------------------- shared case bodies


def regression_rows(
    case: str,
    regressors: Mapping[str, Any],
    response: Any,
    sidpac: Mapping[str, tuple[float | None, float | None, float | None]],
    *,
    label: str = "",
    mc: int = 100,
    seed: int = 0,
    intercept: bool = True,
    note: str | None = None,
) -> list[dict[str, Any]]:
    """Equation error through ``aeroid.equation_error`` next to SIDPAC's lesq.

    `sidpac` maps our parameter name (``const`` for the bias) to SIDPAC's
    (estimate, white se, corrected se). The Monte Carlo keeps the regressors
    and refits the fitted response plus surrogates of our residuals.
    """
    import aeroid

    names = list(regressors)
    z = np.asarray(response, dtype=float).ravel()
    data = {k: np.asarray(v, dtype=float).ravel() for k, v in regressors.items()}
    data["__z"] = z
    with Timer() as t:
        res = aeroid.equation_error(data, "__z", names, intercept=intercept)
    fitted = np.asarray(res.fitted, dtype=float)
    resid = z - fitted

    def refit(zz: np.ndarray) -> Mapping[str, float]:
        d = dict(data)
        d["__z"] = zz
        return aeroid.equation_error(
            d, "__z", names, intercept=intercept, error_bars="white"
        ).parameters

    mcs = monte_carlo(refit, fitted, resid, mc, seed=seed)
    return fit_rows(case, sidpac, res, mcs, t.seconds, label=label, note=note)


def fit_rows(
    case: str,
    sidpac: Mapping[str, tuple[float | None, float | None, float | None]],
    res: Any,
    mcs: Mapping[str, float],
    seconds: float,
    *,
    label: str = "",
    note: str | None = None,
) -> list[dict[str, Any]]:
    """One row per parameter of a fit `res` (``.parameters``, ``.stderr``) next to
    SIDPAC's (estimate, white se, corrected se) by our name, with the Monte Carlo's se."""
    return [
        row(
            case,
            f"{label}{name}",
            sidpac=p,
            sidpac_se_white=sw,
            sidpac_se_corrected=sc,
            ours=res.parameters[name],
            ours_se=res.stderr[name],
            mc_se=mcs.get(name),
            seconds=seconds,
            note=note,
        )
        for name, (p, sw, sc) in sidpac.items()
    ]


def output_residuals(result: Any, outputs: Sequence[str], k: int = 0) -> np.ndarray:
    """Manoeuvre `k`'s residuals of an identification, columns in `outputs` order."""
    order = [list(result.output_names).index(o) for o in outputs]
    return np.asarray(result.residuals[k], dtype=float)[:, order]


def estimates_with_biases(result: Any) -> dict[str, float]:
    """Parameters plus first-manoeuvre biases as ``bias.<name>``."""
    out = {k: float(v) for k, v in result.parameters.items()}
    if result.biases:
        out.update({f"bias.{k}": float(v) for k, v in result.biases[0].items()})
    return out


def identify_monte_carlo(
    model: Any,
    flight: Callable[[np.ndarray], Any],
    z: Any,
    result: Any,
    outputs: Sequence[str],
    n: int,
    *,
    seed: int = 0,
    **options: Any,
) -> dict[str, float]:
    """Monte Carlo of an output-error fit: refit ``fitted + surrogate`` records.

    ``flight(z)`` builds the record from measured outputs (n, len(outputs));
    each refit starts at `result`'s estimates with the same `options`
    (``x0``, ``estimate_bias`` ...) and white error bars (only the estimates
    are used).
    """
    import aeroid

    zz = np.asarray(z, dtype=float)
    resid = output_residuals(result, outputs)
    start = dict(result.parameters)

    def refit(znew: np.ndarray) -> dict[str, float]:
        r = aeroid.identify(model, flight(znew), start, error_bars="white", **options)
        return estimates_with_biases(r)

    return monte_carlo(refit, zz - resid, resid, n, seed=seed)


# ---------------------------------------------------------------- SIDPAC's methods in numpy
# Used only where SIDPAC saved no result: our own numpy code following the
# algorithms of its lsims.m, oe.m, senest.m, estrr.m and m_colores.m.


def lsims(A: Any, B: Any, C: Any, D: Any, u: Any, t: Any, x0: Any) -> np.ndarray:
    """SIDPAC's linear simulation: a second-order step with the input averaged over the interval."""
    u = np.asarray(u, dtype=float)
    t = np.asarray(t, dtype=float).ravel()
    n = len(t)
    dt = 1.0 / round(2.0 / (t[2] - t[0]))
    x = np.zeros((n, A.shape[0]))
    x[0] = np.asarray(x0, dtype=float).ravel()
    umid = 0.5 * (u[:-1] + u[1:])
    for i in range(1, n):
        xi = x[i - 1]
        xh = xi + 0.5 * dt * (A @ xi + B @ u[i - 1])
        x[i] = xi + dt * (A @ xh + B @ umid[i - 1])
    return x @ C.T + u @ D.T


def _sensitivities(
    sim: Callable[[np.ndarray], np.ndarray], p: np.ndarray, rel: float = 0.01
) -> np.ndarray:
    """Central differences (n, no, np) with SIDPAC's steps: 1 % of |p|, at least 1e-4."""
    steps = np.where(np.abs(p) > 1e-4, np.abs(rel * p), 1e-4)
    cols = []
    for j, h in enumerate(steps):
        hi, lo = p.copy(), p.copy()
        hi[j] += 0.5 * h
        lo[j] -= 0.5 * h
        cols.append((sim(hi) - sim(lo)) / h)
    return np.stack(cols, axis=-1)


def np_output_error(
    sim: Callable[[np.ndarray], np.ndarray],
    p0: Any,
    z: Any,
    *,
    max_iterations: int = 50,
    tolerance: float = 1e-6,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Output error as SIDPAC's oe.m: Gauss-Newton on a diagonal noise covariance.

    ``sim(p)`` returns the outputs (n, no). The noise covariance is the
    diagonal of the residual covariance, re-estimated each iteration.
    Returns the estimates, the outputs, the Cramer-Rao covariance
    ``M^{-1}`` (white residuals) and the noise covariance.
    """
    z = np.asarray(z, dtype=float)
    p = np.asarray(p0, dtype=float).ravel().copy()
    y = sim(p)
    rr = np.diag(np.mean((z - y) ** 2, axis=0))
    cost = np.inf
    info = np.eye(len(p))
    for _ in range(max_iterations):
        w = 1.0 / np.diag(rr)
        s = _sensitivities(sim, p)
        v = z - y
        info = np.einsum("iap,a,iaq->pq", s, w, s)
        grad = np.einsum("iap,a,ia->p", s, w, v)
        step = np.linalg.lstsq(info, grad, rcond=None)[0]
        pn = p + step
        yn = sim(pn)
        # halve the step while the cost rises
        for _ in range(20):
            if 0.5 * np.sum((z - yn) ** 2 * w) <= 0.5 * np.sum(v**2 * w) * 1.0001:
                break
            step *= 0.5
            pn = p + step
            yn = sim(pn)
        p, y = pn, yn
        rr = np.diag(np.mean((z - y) ** 2, axis=0))
        new = 0.5 * np.sum((z - y) ** 2 / np.diag(rr))
        if abs(cost - new) <= tolerance * abs(new) and np.all(
            np.abs(step) <= 1e-6 + 1e-5 * np.abs(p)
        ):
            break
        cost = new
    w = 1.0 / np.diag(rr)
    s = _sensitivities(sim, p)
    info = np.einsum("iap,a,iaq->pq", s, w, s)
    return p, y, np.linalg.pinv(info), rr


def m_colores(sens: Any, residuals: Any, rr: Any) -> tuple[np.ndarray, np.ndarray]:
    """SIDPAC's m_colores.m: (corrected, white) covariance of an output-error fit.

    ``M^{-1} [sum_i sum_j S_i' R^-1 Rvv(|i-j|) R^-1 S_j] M^{-1}`` with
    ``Rvv(k)`` the unbiased residual auto/cross-correlation at lag k (the
    lag-k block used for both signs, as m_colores does), summed over every
    pair of samples; the double sum is done by FFT.
    """
    s = np.asarray(sens, dtype=float)  # (n, no, np)
    v = np.asarray(residuals, dtype=float)  # (n, no)
    n, no, npar = s.shape
    rinv = np.linalg.inv(np.asarray(rr, dtype=float))
    w = np.einsum("ab,ibp->iap", rinv, s)  # R^-1 S_i
    info = np.einsum("iap,iaq->pq", s, w)
    white = np.linalg.pinv(info)
    nfft = 1 << int(np.ceil(np.log2(2 * n)))
    lags = np.arange(n)
    fv = np.fft.rfft(v, nfft, axis=0)
    # Rvv[k][a, b] = sum_t v_a(t + k) v_b(t) / (n - k)
    rvv = np.fft.irfft(np.conj(fv)[:, None, :] * fv[:, :, None], nfft, axis=0)[:n]
    rvv /= (n - lags)[:, None, None]
    fw = np.fft.rfft(w.reshape(n, no * npar), nfft, axis=0)
    # C[k][(a,p),(b,q)] = sum_i w_i[a,p] w_{i+k}[b,q]
    cc = np.fft.irfft(np.conj(fw)[:, :, None] * fw[:, None, :], nfft, axis=0)[:n]
    cc = cc.reshape(n, no, npar, no, npar)
    # pairs j = i + k (k >= 0) and j = i - k (k > 0), same Rvv(k) block
    fwd = np.einsum("kab,kapbq->pq", rvv, cc)
    back = np.einsum("kab,kbqap->pq", rvv[1:], cc[1:])
    total = fwd + back
    return white @ total @ white, white


def r_colores(X: Any, z: Any) -> tuple[np.ndarray, np.ndarray]:
    """SIDPAC's r_colores.m: (corrected, white) covariance of a least-squares fit.

    ``(X'X)^-1 X' Rvv X (X'X)^-1`` with ``Rvv`` the Toeplitz matrix of the
    biased residual autocorrelation over every lag; white ``s^2 (X'X)^-1``.
    """
    import scipy.linalg

    X = np.asarray(X, dtype=float)
    z = np.asarray(z, dtype=float).ravel()
    n, npar = X.shape
    xtxi = np.linalg.pinv(X.T @ X)
    v = z - X @ (xtxi @ X.T @ z)
    white = float(v @ v) / (n - npar) * xtxi
    acf = np.correlate(v, v, mode="full")[n - 1 :] / n
    corrected = xtxi @ X.T @ scipy.linalg.toeplitz(acf) @ X @ xtxi
    return corrected, white
