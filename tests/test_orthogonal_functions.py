"""Multivariate orthogonal function modelling against the least squares it reduces to."""

from __future__ import annotations

import numpy as np
import pytest

import aeroid


def _grid() -> tuple[np.ndarray, np.ndarray]:
    alpha = np.deg2rad(np.arange(-4.0, 20.0, 1.0))
    mach = np.linspace(0.1, 0.9, 10)
    a, m = np.meshgrid(alpha, mach)
    return a.ravel(), m.ravel()


def _monomials(a, m, powers):
    return np.column_stack([a**i * m**j for i, j in powers])


def test_a_polynomial_truth_comes_back_exactly():
    a, m = _grid()
    z = 0.2 + 4.5 * a - 3.0 * a**2 + 0.8 * a * m - 0.5 * m**3
    data = {"alpha": a, "mach": m, "z": z}
    # noise-free: a bound on the noise near zero, or the PSE's penalty trades terms for fit
    res = aeroid.orthogonal_function_model(data, "z", ["alpha", "mach"], noise_variance=1e-14)
    truth = {"1": 0.2, "alpha": 4.5, "alpha^2": -3.0, "alpha*mach": 0.8, "mach^3": -0.5}
    assert set(res.parameter_names) == set(truth)
    for name, value in truth.items():
        assert res.parameters[name] == pytest.approx(value, abs=1e-8)
    np.testing.assert_allclose(res.fitted, z, atol=1e-9)
    np.testing.assert_allclose(res.predict({"alpha": a, "mach": m}), z, atol=1e-9)


def test_keeping_every_function_is_ordinary_least_squares_on_the_monomials():
    a, m = _grid()
    rng = np.random.default_rng(0)
    z = np.sin(2 * a) + m * a**2 - m**3 + 0.05 * rng.standard_normal(a.size)
    data = {"alpha": a, "mach": m, "z": z}
    full = aeroid.orthogonal_function_model(data, "z", ["alpha", "mach"], max_power=2, max_order=2)
    n_all = full.pse_history.size
    assert n_all == 6  # 1, a, m, a^2, a m, m^2
    res = aeroid.orthogonal_function_model(
        data, "z", ["alpha", "mach"], max_power=2, max_order=2, n_functions=n_all
    )
    powers = [tuple(p) for p in res.powers.tolist()]
    x = _monomials(a, m, powers)
    coef, *_ = np.linalg.lstsq(x, z, rcond=None)
    r = z - x @ coef
    s2 = r @ r / (z.size - n_all)
    np.testing.assert_allclose([res.parameters[n] for n in res.parameter_names], coef, rtol=1e-9)
    exact = s2 * np.linalg.inv(x.T @ x)
    np.testing.assert_allclose(res.covariance, exact, rtol=1e-8, atol=1e-10 * np.abs(exact).max())
    assert res.fit_error == pytest.approx(np.sqrt(s2), rel=1e-12)


def test_the_pse_chooses_the_number_of_functions():
    a, m = _grid()
    rng = np.random.default_rng(1)
    z = 0.1 + 2.0 * a - 1.5 * a**2 * m + 0.02 * rng.standard_normal(a.size)
    data = {"alpha": a, "mach": m, "z": z}
    res = aeroid.orthogonal_function_model(data, "z", ["alpha", "mach"])
    n = z.size
    zc = z - z.mean()
    assert res.noise_bound == pytest.approx(zc @ zc / (2 * n))
    assert res.n_functions == int(np.argmin(res.pse_history)) + 1
    assert res.pse == pytest.approx(res.pse_history[res.n_functions - 1])
    # each step's PSE: the fit error of the best j functions plus the complexity penalty
    j = res.n_functions
    fixed = aeroid.orthogonal_function_model(data, "z", ["alpha", "mach"], n_functions=j)
    assert fixed.pse == pytest.approx(res.pse)
    given = aeroid.orthogonal_function_model(data, "z", ["alpha", "mach"], noise_variance=4e-4)
    assert given.noise_bound == pytest.approx(25 * 4e-4)
    # the chosen polynomial predicts the truth to about the noise (its terms need not be
    # the truth's: a dropped small orthogonal component moves the others)
    truth = 0.1 + 2.0 * a - 1.5 * a**2 * m
    assert np.sqrt(np.mean((given.fitted - truth) ** 2)) < 0.02


def test_flight_data_gets_coloured_bars_and_tables_white():
    t = np.arange(0.0, 20.0, 0.05)
    a = 0.1 * np.sin(0.7 * t) + 0.05 * np.sin(2.3 * t)
    rng = np.random.default_rng(2)
    noise = np.convolve(rng.standard_normal(t.size), np.ones(8) / 8, mode="same") * 0.01
    fd = aeroid.FlightData(t, {"alpha": a, "CL": 0.3 + 5.0 * a + noise})
    res = aeroid.orthogonal_function_model(fd, "CL", ["alpha"], max_power=3, max_order=3)
    assert res.error_bars == "colored"
    white = aeroid.orthogonal_function_model(
        fd, "CL", ["alpha"], max_power=3, max_order=3, error_bars="white"
    )
    assert white.error_bars == "white"
    assert res.stderr["alpha"] > 1.5 * white.stderr["alpha"]  # smoothed noise: coloured


@pytest.mark.parametrize(
    ("options", "match"),
    [
        ({"max_power": 9}, "at most 8"),
        ({"max_power": [2]}, "one per variable"),
        ({"max_power": {"beta": 2}}, "beta"),
        ({"max_power": "2"}, "max_power"),
        ({"max_order": 0}, "max_order"),
        ({"noise_variance": -1.0}, "noise_variance"),
        ({"noise_variance": "bogus"}, "noise_variance"),
        ({"n_functions": 999}, "n_functions"),
        ({"error_bars": "reml"}, "error_bars"),
    ],
)
def test_bad_options_are_named(options, match):
    a, m = _grid()
    data = {"alpha": a, "mach": m, "z": a + m}
    with pytest.raises(aeroid.DataFormatError, match=match):
        aeroid.orthogonal_function_model(data, "z", ["alpha", "mach"], **options)


def test_bad_data_is_named():
    a, m = _grid()
    with pytest.raises(aeroid.IdentificationError, match="'mach' is constant"):
        aeroid.orthogonal_function_model(
            {"alpha": a, "mach": np.ones_like(a), "z": a}, "z", ["alpha", "mach"]
        )
    with pytest.raises(aeroid.ChannelError, match="'beta'"):
        aeroid.orthogonal_function_model(
            aeroid.FlightData(np.arange(a.size) * 0.1, {"alpha": a, "z": a}), "z", ["beta"]
        )
    few = {"alpha": np.array([0.1, 0.2, 0.4]), "mach": np.array([0.5, 0.3, 0.6]), "z": a[:3]}
    with pytest.raises(aeroid.IdentificationError, match="3 samples"):
        aeroid.orthogonal_function_model(few, "z", ["alpha", "mach"], max_power=1, max_order=1)
    # two distinct values hold a line and no more: alpha^2 is left out, and its products
    two = {"alpha": np.tile([0.1, 0.2], 10), "z": np.tile([1.0, 3.0], 10)}
    line = aeroid.orthogonal_function_model(two, "z", ["alpha"], max_power=3, max_order=3)
    assert line.pse_history.size == 2
    assert line.parameters["alpha"] == pytest.approx(20.0)
    assert line.parameters["1"] == pytest.approx(-1.0)
    res = aeroid.orthogonal_function_model(
        {"alpha": a, "mach": m, "z": a + m}, "z", ["alpha", "mach"]
    )
    with pytest.raises(aeroid.DataFormatError, match="mach"):
        res.predict({"alpha": a})
    assert not res.covariance.flags.writeable
    assert "Orthogonal function model of z" in res.summary()


def test_pruning_is_an_option_and_the_fit_error_is_the_returned_polynomials():
    """Morelli's 0.1 % rule dropped terms unannounced: all functions kept was then not
    least squares on the monomials, and the fit error was the unpruned model's."""
    rng = np.random.default_rng(102)
    v = rng.standard_normal((300, 2))
    z = 1.0 + v.sum(axis=1) + 0.3 * v[:, 0] ** 2 + 0.1 * rng.standard_normal(300)
    data = {"u": v[:, 0], "v": v[:, 1], "z": z}
    opts = {"max_power": 3, "max_order": 4, "n_functions": 13, "error_bars": "white"}
    pruned = aeroid.orthogonal_function_model(data, "z", ["u", "v"], **opts)
    resid = pruned.residuals
    assert pruned.fit_error**2 * (300 - 13) == pytest.approx(float(resid @ resid), rel=1e-12)
    whole = aeroid.orthogonal_function_model(data, "z", ["u", "v"], prune=0.0, **opts)
    assert len(whole.parameter_names) == 13 > len(pruned.parameter_names)
    x = _monomials(v[:, 0], v[:, 1], [tuple(p) for p in whole.powers.tolist()])
    coef, *_ = np.linalg.lstsq(x, z, rcond=None)
    np.testing.assert_allclose(
        [whole.parameters[n] for n in whole.parameter_names], coef, rtol=1e-8, atol=1e-10
    )


def test_repeated_or_response_variables_and_bad_predictions_are_named():
    a, m = _grid()
    data = {"alpha": a, "mach": m, "z": a + m}
    with pytest.raises(aeroid.DataFormatError, match="'alpha' is listed twice"):
        aeroid.orthogonal_function_model(data, "z", ["alpha", "alpha"])
    with pytest.raises(aeroid.DataFormatError, match="'z' is the response"):
        aeroid.orthogonal_function_model(data, "z", ["alpha", "z"])
    with pytest.raises(aeroid.DataFormatError, match="prune"):
        aeroid.orthogonal_function_model(data, "z", ["alpha", "mach"], prune=1.5)
    res = aeroid.orthogonal_function_model(data, "z", ["alpha", "mach"])
    with pytest.raises(aeroid.DataFormatError, match="do not match in shape"):
        res.predict({"alpha": np.array([0.1, 0.2]), "mach": np.array([0.5, 0.6, 0.7])})
    with pytest.raises(aeroid.DataFormatError, match="'alpha'"):
        res.predict({"alpha": np.array(["a"]), "mach": np.array([0.5])})


def test_the_model_does_not_depend_on_the_order_of_the_variables():
    # generated with b first, a weak b^2 function came before the strong a^2 one, whose
    # kept function then carried a b^2 share only the dropped one cancelled: an absent
    # b^2 in every model and coefficients up to 160 bars off, with the variables swapped
    truth = {"1": 1.0, "a": 2.0, "b": -0.5, "a^2": 0.8, "a*b": -1.2}
    for seed in range(20):
        rng = np.random.default_rng(seed)
        a, b = rng.uniform(-1, 1, 300), rng.uniform(0, 2, 300)
        z = 1 + 2 * a - 0.5 * b + 0.8 * a**2 - 1.2 * a * b + 0.05 * rng.standard_normal(300)
        data = {"a": a, "b": b, "z": z}
        one = aeroid.orthogonal_function_model(data, "z", ["a", "b"], max_power=3, max_order=4)
        two = aeroid.orthogonal_function_model(data, "z", ["b", "a"], max_power=3, max_order=4)
        # a term is named in the order the variables were listed (b*a for a*b)
        swapped = {"*".join(sorted(k.split("*"))): k for k in two.parameter_names}
        assert set(one.parameter_names) == set(swapped) == set(truth), seed
        for name, value in truth.items():
            other = swapped[name]
            assert two.parameters[other] == pytest.approx(one.parameters[name], rel=1e-9)
            assert abs(two.parameters[other] - value) < 4.5 * two.stderr[other], (seed, name)


def test_a_power_mapping_names_every_variable():
    a, m = _grid()
    data = {"alpha": a, "mach": m, "z": a + m}
    with pytest.raises(aeroid.AeroidError, match=r"no power given for \['mach'\]"):
        aeroid.orthogonal_function_model(data, "z", ["alpha", "mach"], max_power={"alpha": 2})
    res = aeroid.orthogonal_function_model(
        data, "z", ["alpha", "mach"], max_power={"alpha": 2, "mach": 0}
    )
    assert all(p[1] == 0 for p in res.powers)
