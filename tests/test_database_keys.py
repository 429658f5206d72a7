"""The aerodynamic database's keys and terms: flights without a coefficient, a key some
flights lack, and a database without keys (a constant per term)."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import t as student_t

from aeroid.errors import IdentificationError
from aeroid.pipeline import run
from aeroid.uncertainty.database import FlightCoefficients, aerodynamic_database


def test_flights_without_a_coefficient_are_refused_naming_terms() -> None:
    empty = [
        FlightCoefficients(f"f{i}", {"airspeed": 60.0 + 10 * i}, {}, np.zeros((0, 0)))
        for i in range(5)
    ]
    with pytest.raises(IdentificationError, match=r"no flight estimates a coefficient.*terms="):
        aerodynamic_database(empty)
    one = [FlightCoefficients.from_stderr("f", {"mach": 0.3}, {"CL_0": 0.3}, {"CL_0": 0.01})]
    with pytest.raises(IdentificationError, match="terms must name at least one"):
        aerodynamic_database(one, terms=[])
    # one name is one term and one key, not their letters
    assert aerodynamic_database(one, terms="CL_0", keys="mach").terms == ("CL_0",)


def _mach_flights() -> list[FlightCoefficients]:
    return [
        FlightCoefficients.from_stderr(
            f"f{i}", {"mach": m}, {"CL_alpha": 4.0 + 2.0 * m**2}, {"CL_alpha": 0.01}
        )
        for i, m in enumerate(np.linspace(0.2, 0.8, 12))
    ]


def test_a_key_some_flights_lack_is_left_out_with_a_warning_naming_them() -> None:
    typo = FlightCoefficients.from_stderr(
        "typo", {"Mach": 0.5}, {"CL_alpha": 4.5}, {"CL_alpha": 0.01}
    )
    with pytest.warns(UserWarning) as caught:
        db = aerodynamic_database([*_mach_flights(), typo])
    said = [str(w.message) for w in caught]
    assert any("key 'mach' is left out" in m and "flight(s) typo lack it" in m for m in said)
    assert any("key 'Mach' is left out" in m and "f0, f1" in m for m in said)
    assert db.keys == ()
    # every flight gives mach: no warning, and mach is a key
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert aerodynamic_database(_mach_flights()).keys == ("mach",)


def test_a_database_without_keys_is_the_constant_everywhere(tmp_path: Path) -> None:
    # six flights within their stated errors (no scatter beyond them: τ² = 0), so the
    # constant is their mean 4.0 with standard error 0.01/√6 and the band t₅(0.975) of it
    flights = [
        FlightCoefficients.from_stderr(
            f"f{i}",
            {"mach": 0.2 + 0.1 * i},
            {"CL_alpha": 4.0 + 0.001 * (i - 2.5)},
            {"CL_alpha": 0.01},
        )
        for i in range(6)
    ]
    db = aerodynamic_database(flights, keys=[])
    assert db.keys == () and db.tau2["CL_alpha"] == 0.0
    se = 0.01 / math.sqrt(6.0)
    value, s = db.predict("CL_alpha", {})
    np.testing.assert_allclose([value[0], s[0]], [4.0, se], rtol=1e-9)
    v, lo, hi = db.band("CL_alpha", {"mach": 0.9})  # a key it does not use is ignored
    half = student_t.ppf(0.975, 5) * se
    np.testing.assert_allclose([v[0] - lo[0], hi[0] - v[0]], [half, half], rtol=1e-9)
    np.testing.assert_allclose(db.as_function()()["CL_alpha"], [4.0], rtol=1e-12)
    table = db.table()
    assert table["term"] == ["CL_alpha"] and table["value"] == pytest.approx([4.0])
    assert "<value>4</value>" in db.to_jsbsim()
    assert "condition keys none" in db.summary()


def test_the_database_stage_on_dimensional_derivatives_names_terms(tmp_path: Path) -> None:
    """short_period's parameters (Z_alpha, M_q) are no C<L,D,Y,l,m,n>_ coefficient: the
    stage's default terms select none, and it says so instead of numpy's concatenate."""
    cfg = tmp_path / "c.yaml"
    cfg.write_text(
        "model: short_period\nseed: 5\nstore: store\nreport: out/report.md\n"
        "flights: [{simulated: {n_flights: 3, seed: 1, duration: 6.0, airspeed: [60.0, 80.0]}}]\n"
        "stages:\n  identify: {parameters: [Z_alpha, M_alpha, M_q, M_delta]}\n  database: {}\n"
    )
    s = run(cfg, workers=0)
    task = next(t for t in s.plan.tasks if t.stage == "database")
    err = s.statuses[task.key].error or ""
    assert "no identified parameter is a coefficient" in err, err
    assert "M_alpha" in err and "stages.database.terms" in err
