"""Handling-qualities boundaries: pinned to the reference file, and the levels they give."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

import aeroid
from aeroid.frequency import _criteria as crit

REFERENCE = Path(__file__).resolve().parents[2] / "shared" / "reference" / "handling-qualities.md"


def _reference() -> str:
    if not REFERENCE.is_file():
        pytest.skip(f"{REFERENCE} is not beside the checkout")
    return REFERENCE.read_text(encoding="utf-8")


def _numbers(text: str) -> list[float]:
    return [float(x) for x in re.findall(r"-?\d+(?:\.\d+)?", text)]


def test_short_period_limits_are_the_reference_files_numbers() -> None:
    text = _reference()
    table = {
        row.split("|")[1].strip(): _numbers("|".join(row.split("|")[2:]))
        for row in text.splitlines()
        if row.startswith("| ") and ("zeta" in row or "wn" in row or "tau" in row)
    }
    zeta = table["short-period damping zeta"]
    assert zeta == [0.35, 1.30, 0.25, 2.00, 0.15, 10.0]
    assert [v for pair in crit.SHORT_PERIOD_ZETA for v in pair] == zeta
    assert table["natural frequency wn (rad/s)"] == [1.0, 0.6, 0.0]
    assert list(crit.SHORT_PERIOD_OMEGA) == table["natural frequency wn (rad/s)"]
    assert list(crit.SHORT_PERIOD_OMEGA_T_THETA2) == table["wn * Ttheta2"]
    assert list(crit.SHORT_PERIOD_TAU) == table["equivalent time delay tau (s)"]


def test_bandwidth_boundaries_are_the_reference_files_numbers() -> None:
    text = _reference()
    for marker, points in (
        ("Level 1 / Level 2 boundary:", crit.BANDWIDTH_LEVEL_1),
        ("Level 2 / Level 3 boundary:", crit.BANDWIDTH_LEVEL_2),
    ):
        start = text.index(marker) + len(marker)
        block = text[start : text.index("\n-", start) if "\n-" in text[start:] else None]
        block = block.split("\n\n")[0]
        pairs = re.findall(r"\((-?\d+(?:\.\d+)?), (-?\d+(?:\.\d+)?)\)", block)
        assert [(float(a), float(b)) for a, b in pairs] == [tuple(p) for p in points]


def test_muad_envelopes_are_the_reference_files_numbers() -> None:
    text = _reference()
    rows = {
        row.split("|")[1].strip(): [_numbers(row.split("|")[2]), _numbers(row.split("|")[3])]
        for row in text.splitlines()
        if row.startswith("| lower") or row.startswith("| upper")
    }
    names = {
        "lower gain (dB)": "lower_gain_db",
        "upper gain (dB)": "upper_gain_db",
        "lower phase (deg)": "lower_phase_deg",
        "upper phase (deg)": "upper_phase_deg",
    }
    for label, key in names.items():
        num, den = crit.MUAD_ENVELOPES[key]
        assert [list(num), list(den)] == rows[label], label


def _milstd(omega: float, zeta: float, t_theta2: float, tau: float) -> int:
    # SIDPAC's milstd.m level logic, written out as the reference
    if 0.35 < zeta < 1.30:
        z = 1
    elif 0.25 < zeta < 2.00:
        z = 2
    else:
        z = 3
    w = 1 if omega >= 1.0 else 2 if omega >= 0.6 else 3
    wt = omega * t_theta2
    t2 = 1 if wt >= 1.85 else 2 if wt >= 1.0 else 3
    d = 1 if tau <= 0.1 else 2 if tau <= 0.2 else 3
    return max(z, w, t2, d)


def test_short_period_levels_are_milstds_over_a_grid() -> None:
    rng = np.random.default_rng(0)
    for _ in range(2000):
        omega = float(rng.uniform(0.1, 6.0))
        zeta = float(rng.uniform(0.05, 3.0))
        t_theta2 = float(rng.choice([-1.0, 1.0]) * rng.uniform(0.05, 3.0))
        tau = float(rng.uniform(-0.05, 0.35))
        got = aeroid.short_period_level(omega, zeta, t_theta2, tau)
        assert got.level == _milstd(omega, zeta, t_theta2, tau)


@pytest.mark.parametrize(
    ("args", "level", "criterion", "beyond"),
    [
        ((2.0, 0.3501, 2.0, 0.05), 1, "zeta", ()),
        ((2.0, 0.35, 2.0, 0.05), 2, "zeta", ()),
        ((2.0, 1.2999, 2.0, 0.05), 1, "zeta", ()),
        ((2.0, 0.15, 2.0, 0.05), 3, "zeta", ("zeta",)),
        ((1.0, 0.7, 2.0, 0.05), 1, "omega", ()),
        ((0.9999, 0.7, 2.0, 0.05), 2, "omega", ()),
        ((0.5999, 0.7, 4.0, 0.05), 3, "omega", ()),
        ((2.0, 0.7, 0.925, 0.05), 1, "omega*T_theta2", ()),
        ((2.0, 0.7, 0.9, 0.05), 2, "omega*T_theta2", ()),
        ((2.0, 0.7, -0.5, 0.05), 3, "omega*T_theta2", ("omega*T_theta2",)),
        ((2.0, 0.7, 2.0, 0.10), 1, "tau", ()),
        ((2.0, 0.7, 2.0, 0.2001), 3, "tau", ()),
        ((2.0, 0.7, 2.0, 0.2501), 3, "tau", ("tau",)),
    ],
)
def test_each_short_period_boundary_just_inside_and_outside(args, level, criterion, beyond):
    got = aeroid.short_period_level(*args)
    assert got.criteria[criterion] == level
    assert got.beyond_level_3 == beyond
    if beyond:
        assert "beyond the Level 3 limits" in got.summary()
    assert "milstd" in got.source


def test_bandwidth_levels_never_worsen_with_more_bandwidth_or_less_delay() -> None:
    assert aeroid.bandwidth_level(7.0, 0.04).level == 1
    assert aeroid.bandwidth_level(7.0, 0.05).level == 2  # above the boundary at 7 rad/s
    assert aeroid.bandwidth_level(6.49, 0.0).level == 2
    assert aeroid.bandwidth_level(0.99, 0.0).level == 3
    assert aeroid.bandwidth_level(2.0, 0.16).level == 3
    grid_w = np.linspace(0.5, 15.0, 60)
    grid_t = np.linspace(0.0, 0.2, 41)
    levels = np.array([[aeroid.bandwidth_level(w, t).level for t in grid_t] for w in grid_w])
    assert np.all(np.diff(levels, axis=0) <= 0)  # more bandwidth: never worse
    assert np.all(np.diff(levels, axis=1) >= 0)  # more phase delay: never better
    assert "unchecked" in aeroid.bandwidth_level(7.0, 0.04).source


def test_levels_refuse_what_is_not_a_number() -> None:
    with pytest.raises(aeroid.IdentificationError, match="zeta"):
        aeroid.short_period_level(2.0, "0.7", 1.0, 0.1)  # type: ignore[arg-type]
    with pytest.raises(aeroid.IdentificationError, match="phase_delay"):
        aeroid.bandwidth_level(5.0, float("nan"))


def test_equivalent_system_carries_its_level_flags_and_envelopes() -> None:
    # a second-order pitch response with a zero and a delay, fitted by its own form
    num, den, tau = [4.0, 4.0 * 1.2], [1.0, 2 * 0.6 * 3.0, 9.0], 0.05
    fit = aeroid.equivalent_system((num, den, tau))
    level = fit.level
    assert level is not None and level.level == 1
    np.testing.assert_allclose(level.values["omega"], 3.0, rtol=1e-3)
    assert "Level 1" in fit.summary() and not fit.flags
    env = fit.mismatch_envelopes()
    assert set(env) >= {"gain_db", "phase_deg", "lower_gain_db", "upper_gain_db"}
    assert np.all(env["lower_gain_db"] <= env["upper_gain_db"])
    # an exact fit: the mismatch lies inside the gain envelope everywhere it is defined
    inside = (env["gain_db"] >= env["lower_gain_db"]) & (env["gain_db"] <= env["upper_gain_db"])
    assert np.all(inside)
    rhp = aeroid.equivalent_system(([4.0, -4.0 * 1.2], den, tau))
    assert any("right-half-plane" in f for f in rhp.flags)
    assert rhp.level is not None and rhp.level.level == 3
    assert "Warning: right-half-plane" in rhp.summary()
    assert aeroid.equivalent_system(([2.0], [1.0, 3.0]), kind="roll").level is None


def test_bandwidth_result_has_a_level_and_draws_the_boundaries_by_default() -> None:
    import matplotlib

    matplotlib.use("Agg")
    res = aeroid.bandwidth(([4.0], [1.0, 2 * 0.7 * 4.0, 16.0, 0.0], 0.02))
    assert res.level is not None and res.level.level in (1, 2, 3)
    assert f"Level {res.level.level}" in res.summary()
    fig = res.plot()
    labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert "Level 1 (Category A)" in labels and "Level 2 (Category A)" in labels
    assert "unchecked" in fig.axes[0].get_title(loc="left")


def test_the_campaign_table_names_levels_and_a_right_half_plane_zero() -> None:
    from aeroid.pipeline.stages.analysis_stages import hq_table

    briefs = [
        {"omega": 3.0, "1/T_theta2": 1.2, "tau": 0.05, "LOES level": 1.0},
        {"omega": 3.0, "1/T_theta2": -18.0, "tau": 0.05, "LOES level": 3.0},
    ]
    text = "\n".join(hq_table(["f1", "f2"], ["a", "b"], briefs))
    assert "| LOES level [MIL-STD-1797A] |" in text
    assert "f2: 1/T_theta2 = -18 1/s is a right-half-plane zero" in text
    assert "f1: 1/T_theta2" not in text
