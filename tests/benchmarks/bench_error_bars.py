"""Honesty of the coloured-residual error bars on a strongly coloured case.

Run as a script: ``python tests/benchmarks/bench_error_bars.py [--seeds N]``.

A model whose two outputs are linear in 14 control derivatives, with a bias
on each (16 parameters), is fitted by `aeroid.identify` to 40 s records at
50 Hz whose noise is an AR(1) disturbance with phi = 0.99 (correlation time
199 samples, N/tau = 10) plus white sensor noise. For every parameter it
prints the Monte Carlo standard deviation of the estimates over the seeds
(the truth the error bars should match), the root-mean-square of our
corrected standard errors, of SIDPAC-colores-style ones (the plain formula:
full-record sample auto/cross-correlation of the residuals, every lag, no
window, no degrees-of-freedom factor) and of the classical white-residual
bounds, with each one's 95 % coverage. Then the time of the correction
itself (first and warm call, median of several) on a large record.
"""

from __future__ import annotations

import argparse
import time
import tracemalloc
from collections.abc import Mapping
from typing import Any

import numpy as np
from _timing import median_time
from scipy.signal import butter, lfilter

import aeroid
from aeroid._threads import small_blas
from aeroid.estimation._noise_model import _colored_covariance

FS = 50.0
N_A, N_B = 8, 6
TRUTH = np.array([1.0 + 0.1 * i for i in range(N_A)] + [-0.5 + 0.2 * i for i in range(N_B)])
BIAS = np.array([0.3, -0.2])
NAMES = [f"a{i}" for i in range(N_A)] + [f"b{i}" for i in range(N_B)]
LABELS = [*NAMES, "bias y0", "bias y1"]


def _measurement(t: float, x: np.ndarray, u: np.ndarray, p: Mapping[str, Any]) -> np.ndarray:
    y0 = sum(p[f"a{i}"] * u[i] for i in range(N_A))
    y1 = sum(p[f"b{i}"] * u[i] for i in range(N_B))
    return np.array([y0 + 0.0 * x[0], y1 + 0.0 * x[0]])


MODEL = aeroid.Model(
    states=["s"],
    controls=[f"u{i}" for i in range(N_A)],
    parameters=dict.fromkeys(NAMES, 0.0),
    dynamics=lambda t, x, u, p: 0.0 * x,
    outputs=["y0", "y1"],
    measurement=_measurement,
    name="linear_regression",
)


def _inputs(rng: np.random.Generator, n: int) -> np.ndarray:
    u = np.empty((n, N_A))
    for i, fc in enumerate(np.geomspace(0.1, 2.0, N_A)):
        b, a = butter(2, fc / (FS / 2))
        x = lfilter(b, a, rng.standard_normal(n + 500))[500:]
        u[:, i] = x / x.std()
    return u


def _noise(rng: np.random.Generator, n: int) -> np.ndarray:
    phi = 0.99
    w = rng.standard_normal((n, 2)) @ np.linalg.cholesky([[1.0, 0.6], [0.6, 1.0]]).T
    w[0] /= np.sqrt(1.0 - phi**2)
    e = lfilter([1.0], [1.0, -phi], w, axis=0) * np.sqrt(1.0 - phi**2)
    return e * [0.5, 1.0] + 0.05 * rng.standard_normal((n, 2))


def _jacobian(u: np.ndarray) -> np.ndarray:
    """Residual Jacobian (n, 2, 16) of the linear model: minus the regressors."""
    n = u.shape[0]
    jac = np.zeros((n, 2, N_A + N_B + 2))
    jac[:, 0, :N_A] = -u
    jac[:, 1, N_A : N_A + N_B] = -u[:, :N_B]
    jac[:, 0, -2] = -1.0
    jac[:, 1, -1] = -1.0
    return jac


def colores(jac: np.ndarray, v: np.ndarray, r: np.ndarray, m_inv: np.ndarray) -> np.ndarray:
    """SIDPAC-colores-style covariance: ``M^-1 [sum_ij S_i' R^-1 Rvv(i-j) R^-1 S_j] M^-1``
    with ``Rvv(k) = (1/N) sum_t v_t v_(t+k)'`` at every lag of the record (by FFT)."""
    n = v.shape[0]
    n_fft = int(2 ** np.ceil(np.log2(2 * n)))
    w = jac / r[None, :, None]
    wf = np.fft.fft(w, n=n_fft, axis=0)  # (F, n_y, p)
    vf = np.fft.fft(v, n=n_fft, axis=0)  # (F, n_y)
    a = np.einsum("fkp,fk->fp", wf, np.conj(vf))
    middle = np.real(a.T @ np.conj(a)) / (n * n_fft)
    return m_inv @ middle @ m_inv


def run(seeds: int, duration: float) -> None:
    n = int(duration * FS)
    t = np.arange(n) / FS
    truth = np.concatenate([TRUTH, BIAS])
    est, se_ours, se_col, se_white = [], [], [], []
    for seed in range(seeds):
        rng = np.random.default_rng(seed)
        u = _inputs(rng, n)
        y = np.column_stack([u @ TRUTH[:N_A], u[:, :N_B] @ TRUTH[N_A:]]) + BIAS + _noise(rng, n)
        channels = {f"u{i}": u[:, i] for i in range(N_A)} | {"y0": y[:, 0], "y1": y[:, 1]}
        res = aeroid.identify(
            MODEL, aeroid.FlightData(time=t, channels=channels), NAMES, estimate_bias=True
        )
        est.append([res.parameters[k] for k in NAMES] + [res.biases[0][o] for o in ("y0", "y1")])
        se_ours.append(
            [res.stderr[k] for k in NAMES]
            + [res.extra_stderr[f"bias[0].{o}"] for o in ("y0", "y1")]
        )
        jac = _jacobian(u)
        r = np.diag(res.noise_covariance)
        wj = jac / np.sqrt(r)[None, :, None]
        m_inv = np.linalg.inv(np.einsum("tkp,tkq->pq", wj, wj))
        v = np.asarray(res.residuals[0])
        se_col.append(np.sqrt(np.clip(np.diag(colores(jac, v, r, m_inv)), 0.0, None)))
        se_white.append(np.sqrt(np.diag(m_inv)))
    e = np.array(est) - truth
    mc = e.std(axis=0, ddof=1)
    print(
        f"{seeds} seeds, {duration:.0f} s at {FS:.0f} Hz, AR(1) phi = 0.99 + white sensor noise; "
        "standard errors as RMS over seeds, coverage of the 95 % interval"
    )
    print(
        f"{'parameter':>10} {'MC std':>10} {'ours':>10} {'colores':>10} {'white':>10} "
        f"{'ours/col':>9} {'ours/MC':>8} {'col/MC':>7} {'cov ours':>9} {'cov col':>8} "
        f"{'cov white':>9}"
    )
    rows = []
    for s in (se_ours, se_col, se_white):
        s_arr = np.array(s)
        rows.append(
            (np.sqrt(np.mean(s_arr**2, axis=0)), np.mean(np.abs(e) <= 1.96 * s_arr, axis=0))
        )
    (o_rms, o_cov), (c_rms, c_cov), (w_rms, w_cov) = rows
    ratio = np.median(np.array(se_ours) / np.array(se_col), axis=0)
    for j, lab in enumerate(LABELS):
        print(
            f"{lab:>10} {mc[j]:10.4g} {o_rms[j]:10.4g} {c_rms[j]:10.4g} {w_rms[j]:10.4g} "
            f"{ratio[j]:9.2f} {o_rms[j] / mc[j]:8.2f} {c_rms[j] / mc[j]:7.2f} "
            f"{o_cov[j]:9.3f} {c_cov[j]:8.3f} {w_cov[j]:9.3f}"
        )
    print(
        f"mean coverage: ours {o_cov.mean():.3f}, colores {c_cov.mean():.3f}, "
        f"white {w_cov.mean():.3f} (binomial s.e. of one {np.sqrt(0.95 * 0.05 / seeds):.3f})"
    )


def time_correction(n: int, n_y: int, n_par: int, *, as_in_identify: bool = False) -> None:
    """Time `_colored_covariance` alone; `as_in_identify` runs it under `small_blas`,
    the one-BLAS-thread setting `identify` (which calls it) runs in."""
    rng = np.random.default_rng(0)
    jac = rng.standard_normal((n, n_y, n_par))
    v = lfilter([1.0], [1.0, -0.99], rng.standard_normal((n, n_y)), axis=0)
    r = np.mean(v**2, axis=0)
    wj = jac / np.sqrt(r)[None, :, None]
    m_inv = np.linalg.inv(np.einsum("tkp,tkq->pq", wj, wj))
    fn = small_blas(_colored_covariance) if as_in_identify else _colored_covariance
    t0 = time.perf_counter()
    fn([jac], [v], r, m_inv)
    first = time.perf_counter() - t0
    warm = median_time(lambda: fn([jac], [v], r, m_inv), repeats=5)
    how = " (under small_blas, as in identify)" if as_in_identify else ""
    print(
        f"_colored_covariance, N = {n}, {n_y} outputs, {n_par} parameters{how}: "
        f"first {first:.3f} s, warm {warm:.3f} s (median of 5)"
    )


def time_kernel(n: int, n_y: int, n_par: int, phi: float) -> None:
    """Time `colored_covariance` (the kernel estimator of equation error, stepwise
    regression and data compatibility) alone, on AR(1) residuals of coefficient `phi`."""
    from aeroid._colour import colored_covariance

    rng = np.random.default_rng(0)
    g = rng.standard_normal((n, n_y, n_par))
    v = lfilter([1.0], [1.0, -phi], rng.standard_normal((n, n_y)), axis=0)
    m_inv = np.linalg.inv(np.einsum("tkp,tkq->pq", g, g))
    t0 = time.perf_counter()
    colored_covariance([g], [v], m_inv)
    first = time.perf_counter() - t0
    warm = median_time(lambda: colored_covariance([g], [v], m_inv), repeats=5)
    tracemalloc.start()
    colored_covariance([g], [v], m_inv)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    print(
        f"colored_covariance, N = {n}, {n_y} outputs, {n_par} parameters, phi = {phi}: "
        f"first {first:.3f} s, warm {warm:.3f} s (median of 5), "
        f"peak {peak / 2**20:.0f} MiB allocated ({peak / n / 1024:.2f} kB a sample)"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seeds", type=int, default=100)
    parser.add_argument("--duration", type=float, default=40.0)
    parser.add_argument(
        "--large", action="store_true", help="also time N = 100000, 10 outputs, 30 parameters"
    )
    parser.add_argument(
        "--kernel-only", action="store_true", help="only the kernel's time and memory"
    )
    args = parser.parse_args()
    if args.kernel_only:
        for n in (20_000, 100_000, 200_000):
            for phi in (0.0, 0.9):
                time_kernel(n, 1, 2, phi)
        return
    run(args.seeds, args.duration)
    time_correction(2_000, 2, 16)
    time_correction(20_000, 4, 18)
    # long records with many outputs (issue 28): the spectral REML and the blocked sandwich
    for n in (5_000, 20_000):
        time_correction(n, 7, 20)
        time_correction(n, 7, 20, as_in_identify=True)
    for n, n_y, n_par in ((2_000, 2, 16), (20_000, 4, 18), (100_000, 1, 3)):
        for phi in (0.0, 0.99):
            time_kernel(n, n_y, n_par, phi)
    if args.large:
        time_correction(100_000, 10, 30)


if __name__ == "__main__":
    main()
