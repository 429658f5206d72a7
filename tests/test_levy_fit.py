"""A transfer function by equation error on a record's transforms (Levy; SIDPAC's tfest)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import aeroid
from aeroid.frequency._rational_fit import FourierRequest, record_transforms

DT = 0.02


def _mass_spring(noise: float = 0.0, seed: int = 0, t_end: float = 30.0) -> aeroid.FlightData:
    """y'' + 2 zeta wn y' + wn^2 y = k u: a mass-spring-damper (not an aircraft mode),
    from rest, driven by a sum of sines that fades to zero before the end."""
    wn, zeta, k = 2.5, 0.3, 4.0
    t = np.arange(0.0, t_end + 1e-9, DT)

    def u(tt):
        fade = np.clip((t_end - 4.0 - tt) / 4.0, 0.0, 1.0)
        return fade * (np.sin(1.1 * tt) + 0.7 * np.sin(2.3 * tt + 1) + 0.5 * np.sin(4.1 * tt + 2))

    sol = solve_ivp(
        lambda tt, s: [s[1], k * u(tt) - 2 * zeta * wn * s[1] - wn**2 * s[0]],
        (0.0, t_end),
        [0.0, 0.0],
        t_eval=t,
        rtol=1e-11,
        atol=1e-13,
    )
    y = sol.y[0] + noise * np.random.default_rng(seed).standard_normal(t.size)
    return aeroid.FlightData(time=t, channels={"u": u(t), "y": y})


TRUTH = {"b0": 4.0, "a0": 2.5**2, "a1": 2 * 0.3 * 2.5}
OPTIONS = {"input": "u", "output": "y", "numerator_order": 0, "denominator_order": 2}


def _fit(data, **kw):
    return aeroid.fit_transfer_function(
        data, **OPTIONS, delay=False, fourier=True, method="equation_error", **kw
    )


def test_it_is_levys_regression_on_the_records_transforms():
    """The estimate and white bars are ordinary least squares of (jw)^2 Y on U, -Y and
    -jw Y, each frequency's row over jw (SIDPAC's tfregr), with real coefficients,
    each complex residual two real observations."""
    data = _mass_spring(noise=0.01)
    fit = _fit(data, boundary="ignore", error_bars="white")
    ask = FourierRequest(
        data, "u", "y", 0, 2, False, None, fit.frequency, None, None, "white", "ignore"
    )
    rec = record_transforms(ask)
    s = 1j * rec.w
    # each frequency's equation over (jw)^(n-1), SIDPAC's tfregr weighting
    x = np.stack([rec.U, -rec.Y, -s * rec.Y], axis=1) / s[:, None]  # b0, a0, a1
    z = s * rec.Y
    xs, zs = np.concatenate([x.real, x.imag]), np.concatenate([z.real, z.imag])
    theta = np.linalg.solve(xs.T @ xs, xs.T @ zs)
    v = zs - xs @ theta
    se = np.sqrt(np.diag(v @ v / (zs.size - 3) * np.linalg.inv(xs.T @ xs)))
    for j, name in enumerate(("b0", "a0", "a1")):
        assert fit.parameters[name] == pytest.approx(theta[j], rel=1e-10)
        assert fit.standard_errors[name] == pytest.approx(se[j], rel=1e-8)
    assert fit.weighting == "equation_error" and not fit.ends_estimated
    np.testing.assert_allclose(fit.denominator, [1.0, theta[2], theta[1]], rtol=1e-10)


def test_noise_free_it_recovers_the_truth():
    fit = _fit(_mass_spring())
    for name, value in TRUTH.items():
        assert fit.parameters[name] == pytest.approx(value, rel=2e-3)


def test_a_fixed_coefficient_moves_to_the_response():
    data = _mass_spring(noise=0.01)
    free = _fit(data, boundary="ignore")
    held = _fit(data, boundary="ignore", fixed={"b0": free.parameters["b0"]})
    for name in ("a0", "a1"):
        assert held.parameters[name] == pytest.approx(free.parameters[name], rel=1e-9)
    assert held.standard_errors["b0"] == 0.0
    assert held.covariance[0, 0] == 0.0


def test_over_seeds_the_intervals_cover_with_light_output_noise():
    """Light output noise, where equation error's bias is small against its bars: the
    default (sandwich) 95 % intervals cover the truth in 0.95 +- 3 binomial sigma of
    60 seeds' 180 intervals (measured 0.944, and 0.944 with noise 25 times heavier)."""
    hits = []
    for seed in range(60):
        fit = _fit(_mass_spring(noise=0.002, seed=seed))
        iv = fit.interval()
        hits += [iv[k][0] < v < iv[k][1] for k, v in TRUTH.items()]
    assert abs(np.mean(hits) - 0.95) < 3 * np.sqrt(0.95 * 0.05 / len(hits))


@pytest.mark.parametrize(
    ("options", "match"),
    [
        ({"delay": True}, "delay: equation error .* fits no time delay"),
        ({"delay": False, "start": {"b0": 1.0}}, "start: equation error is linear"),
        ({"delay": False, "method": "levy"}, "method: expected one of"),
    ],
)
def test_bad_options_are_named(options, match):
    kw = {"fourier": True, "method": "equation_error", **options}
    with pytest.raises(aeroid.IdentificationError, match=match):
        aeroid.fit_transfer_function(_mass_spring(), **OPTIONS, **kw)


def test_method_needs_the_records_transforms():
    data = _mass_spring(noise=0.01)
    resp = aeroid.composite_response(data, inputs=["u"], outputs=["y"])
    with pytest.raises(aeroid.IdentificationError, match="method applies to fourier=True only"):
        aeroid.fit_transfer_function(
            resp, numerator_order=0, denominator_order=2, method="equation_error"
        )


def test_left_unset_the_delay_follows_the_method():
    data = _mass_spring(noise=0.01)
    ee = aeroid.fit_transfer_function(data, **OPTIONS, fourier=True, method="equation_error")
    assert "tau" not in ee.parameters and ee.delay == 0.0
    oe = aeroid.fit_transfer_function(data, **OPTIONS, fourier=True)
    assert "tau" in oe.parameters  # output error fits it unless told not to
