"""Run every SIDPAC reference case (``ref_*.py`` beside this file) and summarise.

Usage::

    AEROID_SIDPAC_DIR=/path/to/SIDPAC_V2.0 python tests/reference/run_all.py [--mc N] [--only CASE]

The ``ref_fvsysid_*`` cases (``SOURCE = "fvsysid"``) compare with Jategaonkar's
FVSysID on the book's flight data, read from ``AEROID_FVSYSID_DIR`` (the
``flt_data`` folder); the columns headed SIDPAC then hold FVSysID's figures.

Prints each case's table, then one summary line per case: the largest
``|ours - SIDPAC| / sigma_SIDPAC``, the range of our standard errors over
SIDPAC's (corrected where saved), over the Monte Carlo's, SIDPAC's over the
Monte Carlo's, ours over the Monte Carlo's first-order value (``ours/lin``:
the raw-periodogram sandwich of the same fit, `_sidpac.linear_mc`), and the
time of our fit; then how many rows meet each target, and of the rows
outside 0.8-1.25 of the Monte Carlo how many lie inside the 95 % range of
that first-order value's own degrees of freedom (``mc spread``: the Monte
Carlo's answer for this flight is a draw that far from the spectrum the
kernel estimates). Exits 0 with a message when the data folder is unset.
"""

from __future__ import annotations

import argparse
import importlib.util
import pathlib
import sys
import time
import traceback
from types import ModuleType
from typing import Any

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import _sidpac as S  # noqa: E402


def cases() -> list[ModuleType]:
    """Every ``ref_*.py`` module here, in file-name order."""
    mods = []
    for path in sorted(HERE.glob("ref_*.py")):
        spec = importlib.util.spec_from_file_location(path.stem, path)
        assert spec is not None and spec.loader is not None
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        if hasattr(mod, "run"):
            mods.append(mod)
    return mods


def _f(v: Any, w: int = 8) -> str:
    return S._fmt(v, w, 3)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mc", type=int, default=100, help="Monte Carlo refits per case (0 to skip)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--only", action="append", default=[], help="case name (repeatable)")
    ap.add_argument(
        "--check-mc",
        type=int,
        default=0,
        metavar="SEEDS",
        help="also run check_mc.py's known-truth study over SEEDS seeds (0 skips)",
    )
    args = ap.parse_args(argv)
    folders = {source: S.data_folder(source) for source in S.SOURCES}
    if all(f is None for f in folders.values()):
        print(
            f"skipped: set {S.ENV} to the SIDPAC V2.0 folder (and {S.FVSYSID_ENV} to "
            "FVSysID's flt_data folder) to run the reference suite"
        )
        return 0
    results: list[tuple[str, dict[str, Any] | str]] = []
    t_all = time.perf_counter()
    mods = cases()
    unknown = set(args.only) - {getattr(m, "CASE", m.__name__) for m in mods}
    if unknown:
        known = ", ".join(getattr(m, "CASE", m.__name__) for m in mods)
        print(f"unknown case(s) {', '.join(sorted(unknown))}; known: {known}")
        return 2
    for mod in mods:
        case = getattr(mod, "CASE", mod.__name__)
        if args.only and case not in args.only:
            continue
        source = getattr(mod, "SOURCE", "sidpac")
        folder = folders[source]
        if folder is None:
            print(f"\nskipped {case}: {S.SOURCES[source]} is unset")
            results.append((case, f"skipped: {S.SOURCES[source]} is unset"))
            continue
        t0 = time.perf_counter()
        try:
            with S.ColourRecorder() as rec:
                rows = mod.run(folder, mc=args.mc, seed=args.seed)
            rec.annotate(rows)
        except S.SkipCase as exc:
            print(f"\nskipped {case}: {exc}")
            results.append((case, f"skipped: {exc}"))
            continue
        except Exception as exc:  # one broken case must not hide the others
            traceback.print_exc()
            results.append((case, f"FAILED: {type(exc).__name__}: {exc}"))
            continue
        S.print_table(
            rows, title=f"{case}  ({time.perf_counter() - t0:.1f} s with the Monte Carlo)"
        )
        results.append((case, S.summary(rows)))
    print(f"\n== summary (--mc {args.mc}, {time.perf_counter() - t_all:.0f} s in all)")
    cols = (
        ("max_delta_sigma", "max|d|/sig"),
        ("se_min", "se/sid min"),
        ("se_max", "max"),
        ("deriv_corr_min", "drv/corr min"),
        ("deriv_corr_max", "max"),
        ("mc_min", "ours/mc min"),
        ("mc_max", "max"),
        ("sidpac_mc_min", "sid/mc min"),
        ("sidpac_mc_max", "max"),
        ("lin_min", "ours/lin min"),
        ("lin_max", "max"),
        ("seconds", "fit s"),
    )
    targets = (
        ("target_se", "drv se ok"),
        ("target_mc_drv", "drv mc ok"),
        ("target_mc_cb", "c/b mc ok"),
        ("mc_spread", "mc spread"),
        ("target_estimate", "est ok"),
    )
    print(
        f"{'case':<15}"
        + "".join(f"{h:>13}" for _, h in cols)
        + "".join(f"{h:>10}" for _, h in targets)
    )
    for case, s in results:
        if isinstance(s, str):
            print(f"{case:<15}  {s}")
            continue
        line = f"{case:<15}" + "".join(_f(s[k], 13) for k, _ in cols)
        print(line + "".join(f"{s[k]:>10}" for k, _ in targets))
    print(
        "se/sid: ours over SIDPAC's corrected se where saved, else its white; drv/corr: derivatives "
        "only, over SIDPAC's corrected (rows for non-default options are printed, not "
        "summarised); targets: drv se within 0.8-1.25 of SIDPAC's corrected, "
        "every se within 0.8-1.25 of the Monte Carlo (drv: derivatives, c/b: constants, "
        "biases and sensor parameters), |d|/sig <= 1 (rows meeting / rows); "
        "ours/lin: ours over the Monte Carlo's linear expectation (the raw-periodogram "
        "sandwich); mc spread: of the rows outside 0.8-1.25 of the Monte Carlo, those "
        "inside the 95 % range of the raw sandwich's own degrees of freedom"
    )
    _constants_and_biases(results)
    if args.check_mc:
        import check_mc

        print(f"\n== check_mc: the known-truth study over {args.check_mc} seeds")
        check_mc.main(["--seeds", str(args.check_mc)])
    return 0


def _constants_and_biases(results: list[tuple[str, dict[str, Any] | str]]) -> None:
    """The constants' and biases' rows against the surrogate Monte Carlo, the
    derivatives against SIDPAC's corrected bars with the fit's leverage taken
    out, and why residual-based figures read low."""
    import check_mc

    def block(title: str, cols: tuple[tuple[str, str], ...], count: tuple[str, str]) -> None:
        print(f"\n== {title}")
        print(f"{'case':<15}" + "".join(f"{h:>13}" for _, h in cols) + f"{count[1]:>10}")
        for case, s in results:
            if isinstance(s, str) or s[count[0]] == "-":
                continue
            line = f"{case:<15}" + "".join(_f(s[k], 13) for k, _ in cols)
            print(line + f"{s[count[0]]:>10}")

    block(
        "constants, biases and sensor parameters against the surrogate Monte Carlo",
        (
            ("cb_mc_min", "ours/mc min"),
            ("cb_mc_max", "max"),
            ("cb_lin_min", "ours/lin min"),
            ("cb_lin_max", "max"),
            ("cb_nu_min", "lin nu min"),
            ("cb_nu_max", "max"),
            ("cb_mclev_min", "mc lev min"),
            ("cb_mclev_max", "max"),
            ("cb_sidlev_min", "sid lev min"),
            ("cb_sidlev_max", "max"),
        ),
        ("target_mc_cb", "c/b mc ok"),
    )
    block(
        "derivatives against SIDPAC's corrected bars, the fit's leverage taken out",
        (
            ("deriv_corr_min", "drv/corr min"),
            ("deriv_corr_max", "max"),
            ("drv_sidlev_min", "sid lev min"),
            ("drv_sidlev_max", "max"),
            ("drv_lev_min", "x lev min"),
            ("drv_lev_max", "max"),
        ),
        ("target_se_lev", "drv ok"),
    )
    print(
        "why: the Monte Carlo and SIDPAC's colores both work from the residuals, which "
        "the fit emptied where a parameter's sensitivity sits (a constant's at w = 0, a "
        "bias's and a slow regressor's on the lowest bins: the fit's leverage); the "
        "Monte Carlo fills bin 0 from the three lowest bins (an under-read under a peak "
        "at w = 0 narrower than them), colores sums the residuals' autocorrelation "
        "(nothing at w = 0). mc lev, sid lev: each one's expected standard error over "
        "the true one from the leverage alone, were the noise white "
        "(`_sidpac.leverage_ratio`, exact); x lev: ours over SIDPAC's corrected "
        "divided by sid lev. The Monte Carlo's own degrees of freedom there are few "
        "(lin nu), so for one flight it is also a noisy draw. On records with a known "
        "truth (check_mc.py, 1000 samples) each one's expected standard error over "
        "the true one, in closed form, white / AR(1) phi 0.9 / 0.99:"
    )
    for line in check_mc.structural_lines():
        print(line)
    print(
        "our default bars on the same records track the truth (run --check-mc 200 for "
        "the seeded table): a constant or bias within 0.8-1.25 of these figures is not "
        "the target a calibrated bar meets"
    )


if __name__ == "__main__":
    raise SystemExit(main())
