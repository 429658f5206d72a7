"""FVSysID chapter 6: least squares for the ATTAS aerodynamic coefficients.

Jategaonkar ch. 6 (attas_regLS.m, attasLon/Lat/LonLat_mV_LS.m): the elevator,
aileron and rudder manoeuvres (fAttasElv1, fAttasAil1, fAttasRud1) joined; CD,
CL, Cm, CY, Cl, Cn computed by umr_reg_attas.m (bias-corrected accelerations
moved to the CG, the book's smoother and 17-point differentiator per manoeuvre,
moments at the moment reference point) and regressed by ordinary least squares
on alpha, beta, the normalised rates and the controls plus a constant; LS_Stat.m
gives ``s^2 (X'X)^-1``. FVSysID saved no result: its method runs here in numpy
(`_fvsysid_ls`), so the SIDPAC columns hold FVSysID's estimate and LS_Stat's
standard deviation (no corrected bar). The multivariate scripts regress every
coefficient on one regressor set (``mvLon``, ``mvLat``, ``mv6`` rows).

Ours: ``aeroid.equation_error`` on the same regressors and responses, the three
manoeuvres given as a list of records (one parameter set; each record's residual
spectrum estimated apart), with its default (coloured) bars and with ``error_bars="white"`` (variant rows). Further
variant rows run the whole preprocessing as a user would with AeroID: ``ud.``
the book's coefficients with the angular accelerations from
``aeroid.differentiate`` (default Fourier smoother, per manoeuvre) in place of
the book's filters; ``uc.`` ``aeroid.smooth`` for alpha, beta, V and
``aeroid.coefficients_from_data`` (the density channel, the moments about the
moment reference point), with the asymmetric thrust's yaw added by hand (the API
has no differential thrust). The total
least squares scripts (attas*_TLS.m) have no AeroID equivalent.
"""

from __future__ import annotations

import pathlib
import sys
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import _fvsysid_ls as F
import _sidpac as S

CASE = "fvsysid_attas_ls"
SOURCE = "fvsysid"
# attas_regLS.m: each coefficient on its own regressors (a constant first)
MODELS: dict[str, tuple[str, ...]] = {
    "CD": ("alpha",),
    "CL": ("alpha",),
    "Cm": ("alpha", "q_hat", "delta_e"),
    "CY": ("beta",),
    "Cl": ("beta", "p_hat", "r_hat", "delta_a"),
    "Cn": ("beta", "p_hat", "r_hat", "delta_r"),
}
_LON = ("alpha", "q_hat", "delta_e")
_LAT = ("beta", "p_hat", "r_hat", "delta_a", "delta_r")
# the multivariate scripts: every coefficient of a group on the same regressors
MULTIVARIATE: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "mvLon": (("CD", "CL", "Cm"), _LON),
    "mvLat": (("CY", "Cl", "Cn"), _LAT),
    "mv6": (("CD", "CL", "Cm", "CY", "Cl", "Cn"), _LON + _LAT),
}


def fit_rows(
    label: str,
    ch: Mapping[str, np.ndarray],
    response: str,
    regressors: Sequence[str],
    bounds: np.ndarray,
    *,
    book: tuple[np.ndarray, np.ndarray] | None = None,
    mc: int,
    seed: int,
    variant: bool = False,
    white: bool = True,
    note: str | None = None,
) -> list[dict[str, Any]]:
    """FVSysID's LS (`book`: estimate and LS_Stat std, const first; computed from `ch`
    when None) next to ``aeroid.equation_error`` with default bars (rows marked
    `variant` when asked) and white bars (variant rows), the manoeuvres as a list of
    records, with a Monte Carlo of the refits on surrogates of each manoeuvre's
    residuals."""
    import aeroid

    reg = {k: ch[k] for k in regressors}
    z = np.asarray(ch[response])
    if book is None:
        x = np.column_stack([np.ones(z.size), *reg.values()])
        book = F.ls_stat(x, z)
    ref = dict(zip(("const", *regressors), zip(*book, strict=True), strict=True))
    segs = F.segments(bounds)

    def records(zz: np.ndarray) -> list[Any]:
        # one record per manoeuvre, as a user joins them: one parameter set, each
        # record's residual spectrum apart
        return [
            aeroid.FlightData(
                time=np.arange(s.stop - s.start) * F.DT,
                channels={**{k: v[s] for k, v in reg.items()}, "z": zz[s]},
            )
            for s in segs
        ]

    with S.Timer() as tm:
        res = aeroid.equation_error(records(z), "z", list(regressors))
    white_res = aeroid.equation_error(records(z), "z", list(regressors), error_bars="white")
    fitted = np.asarray(res.fitted)
    resid = z - fitted

    def refit(zz: np.ndarray) -> Mapping[str, float]:
        return aeroid.equation_error(
            records(zz), "z", list(regressors), error_bars="white"
        ).parameters

    def draw(rng: np.random.Generator) -> np.ndarray:
        return np.concatenate([S.phase_surrogate(resid[s], rng) for s in segs])

    mcs = S.monte_carlo(refit, fitted, resid, mc, seed=seed, draw=draw)
    rows = []
    for name, (p, w) in ref.items():
        for r, var in ((res, variant), (white_res, True)):
            if r is white_res and not white:
                continue
            tag = "" if r is res else "w."
            rows.append(
                S.row(
                    CASE,
                    f"{tag}{label}{response}_{name}",
                    sidpac=p,
                    sidpac_se_white=w,
                    sidpac_se_corrected=None,
                    ours=r.parameters[name],
                    ours_se=r.stderr[name],
                    mc_se=mcs.get(name),
                    seconds=tm.seconds,
                    variant=var,
                    note=note,
                )
            )
    return rows


def _per_segment(fn: Any, bounds: np.ndarray) -> F.Segmentwise:
    """A filter of one manoeuvre applied to each manoeuvre of the joined record."""

    def apply(x: np.ndarray, _: np.ndarray) -> np.ndarray:
        return np.concatenate([np.asarray(fn(x[s]), dtype=float) for s in F.segments(bounds)])

    return apply


def user_channels(data: np.ndarray, bounds: np.ndarray) -> dict[str, np.ndarray]:
    """The coefficients as a user computes them with AeroID: ``aeroid.smooth`` of the
    CG flow variables and ``aeroid.coefficients_from_data`` per manoeuvre (the
    density channel, the moments about the book's moment reference point), the
    asymmetric thrust's yaw added by hand; the regressors as the book normalises them."""
    import aeroid

    raw = F.preprocess(data, bounds)  # the flow at the CG and bias-corrected signals
    out: dict[str, list[np.ndarray]] = {}
    for seg in F.segments(bounds):
        n = seg.stop - seg.start
        ch = {k: raw[k][seg] for k in ("p", "q", "r", "ax", "ay", "az", "thrust")}
        ch.update(alpha=raw["alpha_raw"][seg], beta=raw["beta_raw"][seg], V=raw["V_raw"][seg])
        fd = aeroid.FlightData(time=np.arange(n) * F.DT, channels=ch)
        fd = aeroid.smooth(fd, ["alpha", "beta", "V"])
        const = aeroid.AircraftConstants(
            mass=F.MASS,
            Ixx=F.IX,
            Iyy=F.IY,
            Izz=F.IZ,
            Ixz=F.IXZ,
            S=F.SREF,
            b=F.BREF,  # the book's lateral reference length is the half span
            cbar=F.CREF,
            rho=float(np.mean(raw["rho"][seg])),  # nominal; the density channel rules
            accel_position=F.ACCEL,
            thrust_offset=F.ENGINE[2],
        )
        c = aeroid.coefficients_from_data(
            fd, const, thrust="thrust", density=raw["rho"][seg], moment_reference=F.AC
        ).channels
        qsb = np.asarray(c["qbar"]) * F.SREF * F.BREF
        seg_out = {
            "CD": c["CD"],
            "CL": c["CL"],
            "Cm": c["Cm"],
            "CY": c["CY"],
            "Cl": c["Cl"],
            "Cn": c["Cn"] - raw["thrust_diff"][seg] * F.ENGINE[1] / qsb,
            "alpha": c["alpha"],
            "beta": c["beta"],
            "p_hat": raw["p_hat"][seg] * raw["V"][seg] / c["V"],
            "q_hat": raw["q_hat"][seg] * raw["V"][seg] / c["V"],
            "r_hat": raw["r_hat"][seg] * raw["V"][seg] / c["V"],
        }
        for k in ("delta_e", "delta_a", "delta_r"):
            seg_out[k] = raw[k][seg]
        for k, v in seg_out.items():
            out.setdefault(k, []).append(np.asarray(v, dtype=float))
    return {k: np.concatenate(v) for k, v in out.items()}


def differentiation_note(data: np.ndarray, bounds: np.ndarray) -> str:
    """How far ``aeroid.differentiate`` (Fourier, per manoeuvre) is from the book's
    smoother-plus-differentiator, on the bias-corrected rates."""
    import aeroid

    ch = F.preprocess(data, bounds)
    parts = []
    for r in ("p", "q", "r"):
        book = F.book_rate_derivative(ch[r], bounds)
        ours = _per_segment(lambda x: aeroid.differentiate(x, dt=F.DT), bounds)(ch[r], bounds)
        inner = np.concatenate([np.arange(s.start + 9, s.stop - 9) for s in F.segments(bounds)])
        rel = np.std((ours - book)[inner]) / np.std(book[inner])
        ends = np.max(np.abs(ours - book)) / np.std(book)
        cut = [aeroid.optimal_cutoff(ch[r][s], dt=F.DT, order=1) for s in F.segments(bounds)]
        parts.append(
            f"{r}_dot rms diff {100 * rel:.1f}% inside, max {100 * ends:.0f}% of its std "
            f"(our cut-offs {', '.join(f'{c:.2f}' for c in cut)} Hz)"
        )
    return (
        "differentiate vs ndiff_Filter08(smoothMulTS): "
        + "; ".join(parts)
        + f"; the book's smoother passes half amplitude at {_book_half_amplitude():.2f} Hz"
    )


def _book_half_amplitude() -> float:
    """Where the 15-point smoother's gain (a zero-phase FIR) falls to one half, Hz."""
    f = np.linspace(0.0, 0.5 / F.DT, 2001)
    k = np.arange(-7, 8)
    gain = np.abs(np.cos(2 * np.pi * np.outer(f, k) * F.DT) @ F._SMOOTH15)
    return float(f[np.argmax(gain < 0.5)])


def run(folder: pathlib.Path, *, mc: int = 100, seed: int = 0) -> list[dict[str, Any]]:
    import aeroid

    data, bounds = F.load(folder)
    ch = F.preprocess(data, bounds)
    rows: list[dict[str, Any]] = []
    k = 0
    for resp, regs in MODELS.items():
        rows += fit_rows("", ch, resp, regs, bounds, mc=mc, seed=seed + k)
        k += 1
    for label, (responses, regs) in MULTIVARIATE.items():
        x = np.column_stack([np.ones(len(ch["CD"])), *(ch[r] for r in regs)])
        par = np.linalg.lstsq(x, np.column_stack([ch[c] for c in responses]), rcond=None)[0]
        for j, resp in enumerate(responses):
            book = (par[:, j], F.ls_std(x, ch[resp], par[:, j]))
            rows += fit_rows(f"{label}.", ch, resp, regs, bounds, book=book, mc=mc, seed=seed + k)
            k += 1
    # the user's preprocessing, against the book's estimates and bars
    diffed = F.preprocess(
        data,
        bounds,
        rate_derivative=_per_segment(lambda x: aeroid.differentiate(x, dt=F.DT), bounds),
    )
    user = user_channels(data, bounds)
    note = differentiation_note(data, bounds)
    for label, alt in (("ud.", diffed), ("uc.", user)):
        for resp, regs in MODELS.items():
            x = np.column_stack([np.ones(len(ch[resp])), *(ch[r] for r in regs)])
            rows += fit_rows(
                label,
                alt,
                resp,
                regs,
                bounds,
                book=F.ls_stat(x, ch[resp]),
                mc=0,
                seed=seed,
                variant=True,
                white=False,
                note=note,
            )
    return rows


if __name__ == "__main__":
    raise SystemExit(S.main(CASE, run, source="fvsysid"))
