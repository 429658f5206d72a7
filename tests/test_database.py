"""The aerodynamic database (issue 51): seeded recovery, band coverage, bad input."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from aeroid.errors import DataFormatError, IdentificationError
from aeroid.uncertainty.database import AeroDatabase, FlightCoefficients, aerodynamic_database

# truths over alpha (rad) and altitude (m): a lift curve with curvature, a roll damping
# falling with altitude, a constant yaw damping (lateral terms, not the short period)
TRUTH = {
    "CL": lambda a, h: 0.3 + 4.8 * a - 9.0 * a**2,
    "Cl_p": lambda a, h: -0.48 + 2.0e-5 * (h - 1000.0),
    "Cn_r": lambda a, h: -0.09 + 0.0 * a,
}
SIGMA = {"CL": 0.01, "Cl_p": 0.02, "Cn_r": 0.005}


def _flights(seed: int, n: int = 30, correlated: bool = True) -> list[FlightCoefficients]:
    rng = np.random.default_rng(seed)
    out = []
    terms = list(TRUTH)
    for i in range(n):
        a = rng.uniform(0.0, 0.175)
        h = float(rng.choice([500.0, 1000.0, 1500.0]))
        s = np.array([SIGMA[t] for t in terms]) * rng.uniform(0.5, 1.5, len(terms))
        rho = 0.6 * rng.uniform(-1, 1) if correlated else 0.0
        corr = np.eye(3)
        corr[0, 1] = corr[1, 0] = rho
        cov = corr * np.outer(s, s)
        noise = np.linalg.cholesky(cov) @ rng.standard_normal(3)
        est = {t: TRUTH[t](a, h) + noise[k] for k, t in enumerate(terms)}
        out.append(FlightCoefficients(f"flight_{i:02d}", {"alpha": a, "altitude": h}, est, cov))
    return out


def test_recovers_known_polynomial_truth() -> None:
    db = aerodynamic_database(_flights(1, n=60), held_out=("flight_00", "flight_01"))
    assert isinstance(db, AeroDatabase)
    assert db.keys == ("alpha", "altitude")
    assert db.structures["Cn_r"] == ("1",)
    assert "P2(alpha)" in db.structures["CL"]
    assert "P1(altitude)" in db.structures["Cl_p"]
    a = np.linspace(0.01, 0.165, 9)
    for h in (500.0, 1500.0):
        for t, f in TRUTH.items():
            value, se = db.predict(t, {"alpha": a, "altitude": h})
            assert np.all(np.abs(value - f(a, h)) < 4.5 * se + 1e-12), t
            assert np.all(se < SIGMA[t])  # the fit pools flights: tighter than one flight
    assert len(db.held_out) == 6
    assert all(abs(c.z) < 4.0 for c in db.held_out)
    text = db.summary()
    assert "Held out: 2 flights" in text and "CL" in text
    with pytest.raises(ValueError):
        db.parameters["CL"][0] = 1.0  # read-only


@pytest.mark.filterwarnings("ignore:.*outside the flown envelope")
def test_band_coverage_over_seeds() -> None:
    # one point per term per seed: 150 x 3 Bernoulli trials, sd of the rate about 0.010
    inside = total = 0
    a0, h0 = 0.12, 1000.0
    for seed in range(150):
        db = aerodynamic_database(_flights(100 + seed, n=20))
        for t, f in TRUTH.items():
            _, lo, hi = db.band(t, {"alpha": a0, "altitude": h0})
            inside += int(lo[0] <= f(a0, h0) <= hi[0])
            total += 1
    rate = inside / total
    assert 0.92 <= rate <= 0.995, rate


@pytest.mark.parametrize("main", [0.0, 0.1])
def test_an_interaction_enters_even_where_its_factors_explain_nothing(main: float) -> None:
    # an effect of Mach that reverses with alpha: no Mach main effect (and with main = 0
    # no alpha one either), so hierarchy held the product out one term at a time and the
    # between-flight variance swallowed a 20-sigma surface; the step that brings the
    # product with its factors finds it
    alpha, mach = np.linspace(0.0, 0.2, 5), np.linspace(0.3, 0.7, 5)

    def truth(a: Any, m: Any) -> Any:
        u, v = (a - 0.1) / 0.1, (m - 0.5) / 0.2
        return 1.0 + main * u + 0.2 * u * v

    rng = np.random.default_rng(0)
    flights = [
        FlightCoefficients.from_stderr(
            f"f{i}_{j}",
            {"alpha": a, "mach": m},
            {"CL_0": truth(a, m) + 0.01 * rng.standard_normal()},
            {"CL_0": 0.01},
        )
        for i, a in enumerate(alpha)
        for j, m in enumerate(mach)
    ]
    db = aerodynamic_database(flights)
    assert "P1(alpha)*P1(mach)" in db.structures["CL_0"]
    assert db.tau2["CL_0"] == pytest.approx(0.0, abs=1e-8)
    corners = {"alpha": np.array([0.0, 0.2, 0.0, 0.2]), "mach": np.array([0.3, 0.7, 0.7, 0.3])}
    _, lo, hi = db.band("CL_0", corners)
    true = truth(corners["alpha"], corners["mach"])
    assert np.all((lo <= true) & (true <= hi))


@pytest.mark.slow
def test_a_constant_term_takes_a_false_structure_at_the_entry_level() -> None:
    # the steps that bring factors along are extra chances for noise: with Bonferroni
    # over them a constant coefficient still takes a spurious term at about the one-term
    # level (5 %; 0.065 before such steps existed, on these 200 seeds)
    false = [
        aerodynamic_database(_flights(seed, n=60), terms=["Cn_r"]).structures["Cn_r"] != ("1",)
        for seed in range(200)
    ]
    rate = float(np.mean(false))
    assert rate <= 0.05 + 3.0 * np.sqrt(0.05 * 0.95 / 200), rate


def test_forced_slope_band_holds_a_slope_below_detection() -> None:
    # a pitch damping whose slope over the flown alpha (-0.4 over 0-10 deg) is smaller
    # than one flight's standard error (0.6): the structure forced to the truth's terms
    # keeps the slope's uncertainty in the band, which holds the truth at the range's
    # end at no less than the nominal rate (150 Bernoulli trials: the rate's sd about
    # 0.018 at 0.95, the bound three of them below)
    inside = 0
    for seed in range(150):
        rng = np.random.default_rng(500 + seed)
        a = rng.uniform(0.005, 0.175, 12)
        flights = []
        for i in range(12):
            se = 0.6 * rng.uniform(0.8, 1.2)
            value = -17.4 - 2.3 * a[i] + se * rng.standard_normal()
            condition = {"alpha": a[i], "altitude": float(rng.choice([500.0, 1000.0, 1500.0]))}
            flights.append(
                FlightCoefficients.from_stderr(f"f{i}", condition, {"Cm_q": value}, {"Cm_q": se})
            )
        db = aerodynamic_database(flights, structures={"Cm_q": ["1", "alpha"]})
        assert db.basis["Cm_q"] == ("1", "P1(alpha)")
        end = db.centres["alpha"] + db.half_ranges["alpha"]
        _, lo, hi = db.band("Cm_q", {"alpha": end, "altitude": 1000.0})
        inside += int(lo[0] <= -17.4 - 2.3 * end <= hi[0])
    assert inside / 150 >= 0.895, inside / 150


def test_forced_structure_and_exports() -> None:
    flights = _flights(3, n=25)
    db = aerodynamic_database(flights, structures={"CL": ["1", "alpha", "alpha^2"]})
    assert db.structures["CL"] == ("1", "P1(alpha)", "P2(alpha)")
    f = db.as_function()
    out = f(alpha=np.array([0.05]), altitude=np.array([1000.0]))
    assert set(out) == set(TRUTH)
    assert abs(out["CL"][0] - TRUTH["CL"](0.05, 1000.0)) < 0.02
    table = db.table(n=5)
    assert len(table["term"]) == 3 * 25
    assert all(
        lo <= v <= hi
        for lo, v, hi in zip(table["lower"], table["value"], table["upper"], strict=True)
    )


@pytest.mark.filterwarnings("ignore:.*outside the flown envelope")
def test_constant_model_is_the_random_effects_mean_in_closed_form() -> None:
    # one term, constant model: the REML between-flight variance solves its fixed point
    # τ² = Σ w²((z − μ)² − v) / Σ w² + 1 / Σ w, w = 1 / (v + τ²); the estimate is the
    # weighted mean; its variance the Knapp-Hartung one, its band Student's t on n − 1
    vals, ses = np.array([1.0, 2.0, 4.0, 2.5]), np.array([0.1, 0.2, 0.4, 0.1])
    flights = [
        FlightCoefficients.from_stderr(f"f{i}", {"alpha": 0.05}, {"Cm_q": v}, {"Cm_q": s})
        for i, (v, s) in enumerate(zip(vals, ses, strict=True))
    ]
    db = aerodynamic_database(flights)
    tau2 = db.tau2["Cm_q"]
    w = 1.0 / (ses**2 + tau2)
    mean = float(np.sum(w * vals) / np.sum(w))
    fixed = np.sum(w**2 * ((vals - mean) ** 2 - ses**2)) / np.sum(w**2) + 1.0 / np.sum(w)
    assert tau2 == pytest.approx(fixed, rel=1e-3)
    value, se = db.predict("Cm_q", {"alpha": 0.05})
    assert value[0] == pytest.approx(mean, rel=1e-9)
    q = max(1.0, float(np.sum(w * (vals - mean) ** 2)) / 3)
    assert se[0] == pytest.approx(np.sqrt(q / np.sum(w)), rel=1e-9)
    _, lo, hi = db.band("Cm_q", {"alpha": 0.05})
    assert (hi[0] - lo[0]) / 2 == pytest.approx(3.182446305 * se[0], rel=1e-6)  # t(3), 97.5 %
    # stated variances that explain the scatter leave τ² at zero: the inverse-variance mean
    calm = [
        FlightCoefficients.from_stderr(f"g{i}", {"alpha": 0.05}, {"Cm_q": v}, {"Cm_q": 1.0})
        for i, v in enumerate([1.0, 1.2, 0.9])
    ]
    db = aerodynamic_database(calm)
    assert db.tau2["Cm_q"] == 0.0
    assert db.predict("Cm_q", {"alpha": 0.0})[0][0] == pytest.approx(31.0 / 30.0)


def _scattered(seed: int, tau: dict[str, float], n: int = 14) -> list[FlightCoefficients]:
    """A lateral campaign whose flights scatter about the truth by `tau` beyond their
    stated errors (each flight's model-structure error), the stated errors unequal."""
    rng = np.random.default_rng(seed)
    truth = {
        "Cn_beta": lambda a: 0.065 - 0.08 * a,
        "Cl_p": lambda a: -0.47 + 0.0 * a,
        "Cl_delta_a": lambda a: 0.23 - 0.3 * a**2,
    }
    out = []
    for i in range(n):
        a = 0.175 * i / (n - 1)
        sd = {"Cn_beta": 0.001, "Cl_p": 0.01, "Cl_delta_a": 0.004}
        sd = {k: x * rng.uniform(0.3, 1.5) for k, x in sd.items()}
        est = {
            k: f(a) + tau[k] * rng.standard_normal() + sd[k] * rng.standard_normal()
            for k, f in truth.items()
        }
        h = float(rng.choice([500.0, 1500.0]))
        out.append(FlightCoefficients.from_stderr(f"f{i}", {"alpha": a, "altitude": h}, est, sd))
    return out


_TAU = {"Cn_beta": 0.003, "Cl_p": 0.03, "Cl_delta_a": 0.0}
_LATERAL = {
    "Cn_beta": lambda a: 0.065 - 0.08 * a,
    "Cl_p": lambda a: -0.47 + 0.0 * a,
    "Cl_delta_a": lambda a: 0.23 - 0.3 * a**2,
}


@pytest.mark.slow
def test_bands_cover_a_surface_the_flights_scatter_about() -> None:
    # flights that scatter by τ (3 times their stated error) about a known surface: the
    # 95 % bands cover it at 95 % of (seed, term, point) triples, and the two held-out
    # flights' estimates fall inside their prediction bands as often. 120 seeds x 3 terms
    # x 2 points: 720 trials each, the rate's sd about 0.008 (more where trials of one
    # seed correlate). The fit of release 0.5.0 (stated errors, Birge factor) covered
    # 0.73-0.85 here and held 0.65 of the held-out estimates
    inside = held = total = n_held = 0
    tau2: dict[str, list[float]] = {k: [] for k in _TAU}
    for seed in range(120):
        db = aerodynamic_database(_scattered(seed, _TAU, n=16), held_out=("f3", "f12"))
        for t, f in _LATERAL.items():
            tau2[t].append(db.tau2[t])
            for a in (0.03, 0.14):
                _, lo, hi = db.band(t, {"alpha": a, "altitude": 1000.0})
                inside += int(lo[0] <= f(a) <= hi[0])
                total += 1
        held += sum(c.inside for c in db.held_out)
        n_held += len(db.held_out)
    assert 0.92 <= inside / total <= 0.99, inside / total
    assert 0.92 <= held / n_held <= 0.99, held / n_held
    # REML recovers the between-flight variance (its mean over seeds, within 4 standard
    # errors of that mean, plus REML's small-sample bias on 14 flights)
    for t in ("Cn_beta", "Cl_p"):
        est = np.array(tau2[t])
        bound = 4 * est.std() / np.sqrt(est.size) + 0.2 * _TAU[t] ** 2
        assert abs(est.mean() - _TAU[t] ** 2) < bound, (t, est.mean())


def test_a_flight_scatter_widens_the_band_and_the_held_out_check() -> None:
    flights = _scattered(7, _TAU, n=16)
    db = aerodynamic_database(flights, held_out=("f3", "f12"))
    calm = aerodynamic_database(_scattered(7, dict.fromkeys(_TAU, 0.0), n=16))
    assert db.tau2["Cl_p"] > 10 * calm.tau2["Cl_p"]
    assert (
        db.predict("Cl_p", {"alpha": 0.1, "altitude": 1000.0})[1][0]
        > 2 * calm.predict("Cl_p", {"alpha": 0.1, "altitude": 1000.0})[1][0]
    )
    for c in db.held_out:
        spread = np.sqrt(c.stderr**2 + db.tau2[c.term] + c.band_stderr**2)
        assert c.z == pytest.approx((c.estimate - c.prediction) / spread)
        assert c.limit == pytest.approx(db.quantile(c.term))
    assert "τ" in db.summary()


def test_bad_input_names_flight_and_term() -> None:
    flights = _flights(4, n=6)
    no_cond = FlightCoefficients("flight_x", {}, {"CL": 0.3}, np.eye(1) * 1e-4)
    with pytest.raises(DataFormatError, match="flight_x"):
        aerodynamic_database([*flights, no_cond], keys=("alpha", "altitude"))
    lacking = FlightCoefficients("flight_y", {"alpha": 0.1}, {"CL": 0.3}, np.eye(1) * 1e-4)
    with pytest.raises(DataFormatError, match=r"flight_y.*altitude"):
        aerodynamic_database([*flights, lacking], keys=("alpha", "altitude"))
    nan = [
        FlightCoefficients(
            f.name, f.condition, {**f.estimates, "Cm_de": np.nan}, np.pad(f.covariance, (0, 1))
        )
        for f in flights
    ]
    with pytest.raises(IdentificationError, match="no flight excites 'Cm_de'"):
        aerodynamic_database(nan)
    same_alt = [
        FlightCoefficients(f.name, {**f.condition, "altitude": 1000.0}, f.estimates, f.covariance)
        for f in flights
    ]
    with pytest.raises(IdentificationError, match=r"'Cl_p' is unidentifiable.*altitude"):
        aerodynamic_database(same_alt, structures={"Cl_p": ["1", "altitude"]})
    with pytest.raises(IdentificationError, match=r"'CL'.*2 flight"):
        aerodynamic_database(flights[:2], structures={"CL": ["1", "alpha", "alpha^2"]})
    with pytest.raises(DataFormatError, match="nowhere"):
        aerodynamic_database(flights, held_out=("nowhere",))
    # a key that does not vary offers no candidate: the auto fit still works
    db = aerodynamic_database(same_alt)
    assert all("altitude" not in s for st in db.structures.values() for s in st)


def _c172x_with(section: str, root: Path) -> str:
    """A copy of JSBSim's c172x under `root` with its aerodynamics replaced."""
    jsbsim = pytest.importorskip("jsbsim")
    from aeroid.uncertainty.database_export import replace_aerodynamics

    src = Path(jsbsim.get_default_root_dir())
    for sub in ("engine", "systems"):
        shutil.copytree(src / sub, root / sub)
    shutil.copytree(src / "aircraft" / "c172x", root / "aircraft" / "c172x")
    xml = root / "aircraft" / "c172x" / "c172x.xml"
    xml.write_text(replace_aerodynamics(xml.read_text(), section))
    return str(root)


def _flying(section: str, root: Path, *, feet: float, knots: float, alpha: float) -> Any:
    """The c172x with `section` for its aerodynamics, initialised and one step flown."""
    jsbsim = pytest.importorskip("jsbsim")
    fdm = jsbsim.FGFDMExec(_c172x_with(section, root), None)
    fdm.set_debug_level(0)
    assert fdm.load_model("c172x")
    fdm["ic/h-sl-ft"] = feet
    fdm["ic/vc-kts"] = knots
    fdm["ic/alpha-deg"] = alpha
    fdm.run_ic()
    fdm.run()
    return fdm


def test_jsbsim_reads_the_exported_tables_back(tmp_path: Path) -> None:
    pytest.importorskip("jsbsim")
    rng = np.random.default_rng(7)
    flights = []
    for i in range(16):
        a, m = rng.uniform(0.0, 0.17), rng.uniform(0.10, 0.18)
        est = {
            "CL_0": 0.3 + 4.8 * a - 9.0 * a**2,
            "CL_alpha": 4.8 - 18 * a,
            "Cm_0": 0.0,
            "Cm_alpha": -1.8 + 3 * a,
            "Cm_q": -12.4,
            "Cm_delta_e": -1.1 + 2.0 * m,
            "CD_0": 0.03 + 0.3 * a**2,
            "Cl_p": -0.48,
            "Cl_beta": -0.09,
            "Cl_delta_a": 0.23,
            "Cn_beta": 0.065,
            "Cn_r": -0.09,
            "Cn_delta_r": -0.06,
            "CY_beta": -0.39,
        }
        noise = {k: v + 1e-4 * rng.standard_normal() for k, v in est.items()}
        flights.append(
            FlightCoefficients.from_stderr(
                f"f{i}", {"alpha": a, "mach": m}, noise, dict.fromkeys(est, 1e-4)
            )
        )
    db = aerodynamic_database(flights)
    section = db.to_jsbsim(tmp_path / "aero.xml", n=31)
    assert (tmp_path / "aero.xml").read_text() == section
    assert "aero/coefficient/aeroid-CL_alpha" not in section  # the slope of CL_0's table
    assert "<property>aero/ci2vel</property>" in section
    fdm = _flying(section, tmp_path / "root", feet=3000.0, knots=90.0, alpha=4.0)
    for _ in range(4):
        fdm.run()
    cond = {"alpha": fdm["aero/alpha-rad"], "mach": fdm["velocities/mach"]}
    for term in ("CL_0", "Cm_delta_e", "Cm_q", "Cl_p", "Cn_r"):
        assert fdm[f"aero/aeroid/{term}"] == pytest.approx(db.predict(term, cond)[0][0], abs=2e-3)
    qs = fdm["aero/qbar-area"]
    assert fdm["aero/coefficient/aeroid-CL_0"] == pytest.approx(
        qs * fdm["aero/aeroid/CL_0"], rel=1e-9
    )
    # the moments JSBSim flies about the centre of gravity are the database's, whatever
    # the c172x's aerodynamic reference point (24 in above the cg): its forces' arms are
    # cancelled (database_export notes); at a state with pitch and roll rate and sideslip
    fdm["ic/beta-deg"] = 3.0
    fdm["ic/q-rad_sec"] = 0.1
    fdm["ic/p-rad_sec"] = 0.2
    fdm.run_ic()
    fdm.run()
    cond = {"alpha": fdm["aero/alpha-rad"], "mach": fdm["velocities/mach"]}
    qs, c, b = fdm["aero/qbar-area"], fdm["metrics/cbarw-ft"], fdm["metrics/bw-ft"]
    at = {t: db.predict(t, cond)[0][0] for t in db.terms}
    q_hat = fdm["aero/ci2vel"] * fdm["velocities/q-aero-rad_sec"]
    cm = at["Cm_0"] + at["Cm_q"] * q_hat + at["Cm_delta_e"] * fdm["fcs/elevator-pos-rad"]
    assert fdm["moments/m-aero-lbsft"] / (qs * c) == pytest.approx(cm, rel=1e-6)
    # the ailerons' mean deflection, what a record holds (the c172x's left aileron alone
    # moves 15 deg up and 20 deg down)
    fdm["fcs/aileron-cmd-norm"] = 0.3
    fdm["fcs/rudder-cmd-norm"] = -0.2
    for _ in range(60):
        fdm.run()
    assert abs(fdm["fcs/effective-aileron-pos"]) > 0.05
    cond = {"alpha": fdm["aero/alpha-rad"], "mach": fdm["velocities/mach"]}
    qs = fdm["aero/qbar-area"]
    at = {t: db.predict(t, cond)[0][0] for t in db.terms}
    p_hat = fdm["aero/bi2vel"] * fdm["velocities/p-aero-rad_sec"]
    r_hat = fdm["aero/bi2vel"] * fdm["velocities/r-aero-rad_sec"]
    beta = fdm["aero/beta-rad"]
    cl = (
        at["Cl_p"] * p_hat
        + at["Cl_beta"] * beta
        + at["Cl_delta_a"] * fdm["fcs/effective-aileron-pos"]
    )
    assert fdm["moments/l-aero-lbsft"] / (qs * b) == pytest.approx(cl, rel=1e-6)
    cn = at["Cn_beta"] * beta + at["Cn_r"] * r_hat + at["Cn_delta_r"] * fdm["fcs/rudder-pos-rad"]
    assert fdm["moments/n-aero-lbsft"] / (qs * b) == pytest.approx(cn, rel=1e-6)


def test_parquet_table_round_trip(tmp_path: Path) -> None:
    pq = pytest.importorskip("pyarrow.parquet")
    db = aerodynamic_database(_flights(5, n=15))
    db.to_parquet(tmp_path / "db.parquet", n=4)
    table = pq.read_table(tmp_path / "db.parquet").to_pydict()
    assert set(table) >= {"term", "alpha", "altitude", "value", "stderr", "lower", "upper"}
    assert len(table["term"]) == 3 * 16
    i = table["term"].index("CL")
    v, _ = db.predict("CL", {"alpha": table["alpha"][i], "altitude": table["altitude"][i]})
    assert table["value"][i] == pytest.approx(v[0])


def test_condition_keys_are_one_list() -> None:
    # the stage's default keys, the report's rows and plots, the JSBSim export: one list
    from aeroid.pipeline.stages._campaign_tables import condition_text
    from aeroid.pipeline.stages.database_stage import CONDITION_KEYS as STAGE_KEYS
    from aeroid.support import CONDITION_KEYS, CONDITION_NAMES
    from aeroid.uncertainty.database_export import CONDITION_PROPERTIES

    assert STAGE_KEYS == CONDITION_NAMES == tuple(k.name for k in CONDITION_KEYS)
    assert set(CONDITION_PROPERTIES) == set(CONDITION_NAMES)
    text = condition_text({"airspeed": 45.0, "alpha": 0.0299, "altitude": 500.0, "x": 1.0})
    assert text == "alpha 1.713 deg, airspeed 45 m/s, altitude 500 m"


def test_a_term_over_three_keys_is_a_jsbsim_three_dimensional_table(tmp_path: Path) -> None:
    # multilinear in alpha, mach and altitude: JSBSim's linear interpolation is exact
    pytest.importorskip("jsbsim")
    rng = np.random.default_rng(11)
    flights = []
    for i in range(20):
        a, m, h = rng.uniform(0.0, 0.17), rng.uniform(0.10, 0.18), rng.uniform(300.0, 1500.0)
        value = -12.0 + 8.0 * a + 5.0 * m + 1e-3 * h + 0.02 * a * h
        flights.append(
            FlightCoefficients.from_stderr(
                f"f{i}", {"alpha": a, "mach": m, "altitude": h}, {"Cm_q": value}, {"Cm_q": 0.01}
            )
        )
    db = aerodynamic_database(
        flights, structures={"Cm_q": ["1", "alpha", "mach", "altitude", "alpha*altitude"]}
    )
    section = db.to_jsbsim(n=5)
    assert '<independentVar lookup="table">position/h-sl-ft</independentVar>' in section
    fdm = _flying(section, tmp_path / "root", feet=2500.0, knots=95.0, alpha=3.0)
    cond = {
        "alpha": fdm["aero/alpha-rad"],
        "mach": fdm["velocities/mach"],
        "altitude": fdm["position/h-sl-ft"] * 0.3048,
    }
    assert fdm["aero/aeroid/Cm_q"] == pytest.approx(db.predict("Cm_q", cond)[0][0], abs=1e-6)


def test_a_product_term_flies_as_the_product_of_its_regressors(tmp_path: Path) -> None:
    # drag with the square of the sideslip (an aircraft model's "beta*beta" term, named
    # CD_beta_beta): JSBSim's drag at a sideslip is q S (CD_0 + CD_beta_beta beta^2)
    from aeroid.uncertainty.database_export import split_term

    assert split_term("CD_beta_beta") == ("CD", "beta_beta")
    assert split_term("CL_alpha_delta_e") == ("CL", "alpha_delta_e")
    assert split_term("Cm_delta_e") == ("Cm", "delta_e")
    for bad in ("CD_beta_gamma", "CD_beta_", "CD_delta"):
        with pytest.raises(DataFormatError, match=bad):
            split_term(bad)
    pytest.importorskip("jsbsim")
    flights = [
        FlightCoefficients.from_stderr(
            f"f{i}",
            {"alpha": a},
            {"CD_0": 0.03 + 0.2 * a, "CD_beta_beta": 3.5},
            {"CD_0": 1e-4, "CD_beta_beta": 0.05},
        )
        for i, a in enumerate(np.linspace(0.0, 0.15, 8))
    ]
    db = aerodynamic_database(flights)
    section = db.to_jsbsim(n=11)
    assert section.count("<property>aero/beta-rad</property>") == 2
    fdm = _flying(section, tmp_path / "root", feet=3000.0, knots=90.0, alpha=4.0)
    fdm["ic/beta-deg"] = 4.0
    fdm.run_ic()
    fdm.run()
    cond = {"alpha": fdm["aero/alpha-rad"]}
    beta = fdm["aero/beta-rad"]
    assert abs(beta) > 0.05
    cd = db.predict("CD_0", cond)[0][0] + db.predict("CD_beta_beta", cond)[0][0] * beta**2
    assert fdm["forces/fwx-aero-lbs"] / fdm["aero/qbar-area"] == pytest.approx(cd, rel=1e-4)


def test_an_absolute_term_flies_through_jsbsims_abs(tmp_path: Path) -> None:
    # drag and pitch V-shaped in the sideslip (an aircraft model's "abs(beta)", named
    # CD_abs_beta): the section's function is q S CD_abs_beta |beta| (times the chord for
    # the pitch), as the callable's value gives it, at sideslips of both signs
    from aeroid.uncertainty.database_export import split_term

    assert split_term("CD_abs_beta") == ("CD", "abs_beta")
    assert split_term("CD_abs_beta_alpha") == ("CD", "abs_beta_alpha")
    assert split_term("Cn_abs_delta_a") == ("Cn", "abs_delta_a")
    for bad in ("CD_abs_", "CD_abs_gamma", "CD_abs"):
        with pytest.raises(DataFormatError, match=bad):
            split_term(bad)
    pytest.importorskip("jsbsim")
    flights = [
        FlightCoefficients.from_stderr(
            f"f{i}",
            {"alpha": a},
            {"CD_0": 0.03 + 0.2 * a, "CD_abs_beta": 0.17 + 0.5 * a, "Cm_abs_beta": 0.07},
            {"CD_0": 1e-4, "CD_abs_beta": 0.005, "Cm_abs_beta": 0.003},
        )
        for i, a in enumerate(np.linspace(0.0, 0.15, 8))
    ]
    db = aerodynamic_database(flights)
    # the tidy table names the term as the model does
    table = db.table(n=3)
    rows = [i for i, t in enumerate(table["term"]) if t == "CD_abs_beta"]
    assert len(rows) == 3
    v = db.predict("CD_abs_beta", {"alpha": table["alpha"][rows[1]]})[0][0]
    assert table["value"][rows[1]] == pytest.approx(v)
    section = db.to_jsbsim(n=11)
    assert section.count("<abs><property>aero/beta-rad</property></abs>") == 2
    f = db.as_function()
    fdm = _flying(section, tmp_path / "root", feet=3000.0, knots=90.0, alpha=4.0)
    seen = []
    for beta_deg in (-6.0, -2.5, 1.0, 3.0, 6.0):
        fdm["ic/beta-deg"] = beta_deg
        fdm.run_ic()
        fdm.run()
        beta, qs = fdm["aero/beta-rad"], fdm["aero/qbar-area"]
        seen.append(np.sign(beta))
        at = f(alpha=fdm["aero/alpha-rad"])
        drag = fdm["aero/coefficient/aeroid-CD_abs_beta"]
        assert drag == pytest.approx(qs * at["CD_abs_beta"][0] * abs(beta), rel=1e-4)
        pitch = fdm["aero/coefficient/aeroid-Cm_abs_beta"] / fdm["metrics/cbarw-ft"]
        assert pitch == pytest.approx(qs * at["Cm_abs_beta"][0] * abs(beta), rel=1e-4)
    assert set(seen) == {-1.0, 1.0}


# -- speed terms and their trim-speed reference ---------------------------------------------

_WEIGHT, _AREA = 11000.0, 16.2  # N, m^2


def _trim_speed(a: Any, h: Any) -> Any:
    """The speed at which the lift 0.5 rho V^2 S (0.3 + 4.8 alpha) holds the weight."""
    rho = 1.225 * (1.0 - 2.2558e-5 * np.asarray(h)) ** 4.256
    return np.sqrt(2.0 * _WEIGHT / (rho * _AREA * (0.3 + 4.8 * np.asarray(a))))


def _speed_flights(seed: int, sigma: float = 1e-3) -> list[FlightCoefficients]:
    """Flights at their trims over alpha and altitude with a known Cm_V(alpha)."""
    rng = np.random.default_rng(seed)
    out = []
    grid = zip(np.linspace(0.0, 0.17, 18), [500.0, 1200.0, 2000.0] * 6, strict=True)
    for i, (a, h) in enumerate(grid):
        truth = {"Cm_V": 0.02 + 0.3 * a, "Cm_q": -12.0, "Cm_0": -0.05 - 0.2 * a}
        est = {k: v + sigma * rng.standard_normal() for k, v in truth.items()}
        cond = {"alpha": a, "altitude": h, "airspeed": float(_trim_speed(a, h))}
        out.append(FlightCoefficients.from_stderr(f"f{i}", cond, est, dict.fromkeys(est, sigma)))
    return out


def test_speed_terms_carry_the_trim_speed_they_refer_to(tmp_path: Path) -> None:
    pq = pytest.importorskip("pyarrow.parquet")
    flights = _speed_flights(3)
    db = aerodynamic_database(flights, keys=("alpha", "altitude"))
    assert db.speed_terms == ("Cm_V",)
    assert db.speed_reference is not None
    # the trims' lift balances the weight: 1/V0^2 is rho(h) CL(alpha), nearly bilinear;
    # the model holds the flights' trim speeds and the curve between them
    assert db.speed_reference.rms < 0.01
    a, h = np.array([0.03, 0.08, 0.15]), np.array([700.0, 1500.0, 1900.0])
    v0, se = db.trim_speed({"alpha": a, "altitude": h})
    np.testing.assert_allclose(v0, _trim_speed(a, h), rtol=2e-3)
    assert np.all(se < 0.01 * v0)
    # the speed derivative itself: its band covers the truth (sigma 1e-3 per flight)
    value, lo, hi = db.band("Cm_V", {"alpha": a, "altitude": h})
    assert np.all((lo <= 0.02 + 0.3 * a) & (0.02 + 0.3 * a <= hi))
    assert np.all(hi - lo < 0.005)
    out = db.as_function()(alpha=a, altitude=h)
    np.testing.assert_allclose(out["V0"], v0)
    np.testing.assert_allclose(out["Cm_V"], value)
    assert "Speed terms (Cm_V) fly as C_V (V/V0 − 1)" in db.summary()
    db.to_parquet(tmp_path / "db.parquet", n=3)
    table = pq.read_table(tmp_path / "db.parquet").to_pydict()
    i = table["term"].index("V0")
    assert table["value"][i] == pytest.approx(
        db.trim_speed({"alpha": table["alpha"][i], "altitude": table["altitude"][i]})[0][0]
    )
    assert table["term"].count("V0") == 9
    # a plain database has no reference to ask for
    plain = aerodynamic_database(flights, terms=("Cm_q",), keys=("alpha", "altitude"))
    assert plain.speed_reference is None
    with pytest.raises(IdentificationError, match="no speed term"):
        plain.trim_speed({"alpha": 0.1, "altitude": 1000.0})


def test_the_speed_term_about_the_trim_curve_keeps_the_slope_at_fixed_speed() -> None:
    # a truth linear in speed about a fixed 40 m/s: Cm = -0.1 - 1.5 alpha + k (V - 40)/40.
    # Each flight reads at its trim Cm_0 (the trim's Cm), Cm_alpha -1.5 and
    # Cm_V = k V0/40 (per V/V0 - 1). The static table over alpha follows the trim curve,
    # so its slope is -1.5 + k V0'/40; the speed term about V0(alpha) takes the share back
    # (module notes): at a fixed speed the database's slope over alpha is -1.5 again
    k = 0.1

    def cm(a: Any, v: Any) -> Any:
        return -0.1 - 1.5 * a + k * (v - 40.0) / 40.0

    flights = []
    for i, a in enumerate(np.linspace(0.0, 0.17, 15)):
        v0 = float(_trim_speed(a, 1000.0))
        est = {"Cm_0": float(cm(a, v0)), "Cm_V": k * v0 / 40.0}
        flights.append(
            FlightCoefficients.from_stderr(
                f"f{i}", {"alpha": a}, est, {"Cm_0": 1e-5, "Cm_V": 1e-5}, trim_speed=v0
            )
        )
    # quintics: the curves in 1/sqrt(CL) leave a cubic's slope 0.04 off at the ends
    db = aerodynamic_database(flights, max_degree=5)
    f = db.as_function()

    def flown(a: Any, v: Any) -> Any:
        out = f(alpha=a)
        return out["Cm_0"] + out["Cm_V"] * (v / out["V0"] - 1.0)

    a, da = np.array([0.04, 0.09, 0.13]), 1e-3
    v = 1.2 * _trim_speed(a, 1000.0)  # off the trim curve
    np.testing.assert_allclose(flown(a, v), cm(a, v), atol=1e-4)
    assert np.all(np.abs(f(alpha=a)["Cm_0"] - cm(a, v)) > 0.015)  # the term is 0.02-0.03
    slope = (flown(a + da, v) - flown(a - da, v)) / (2 * da)
    np.testing.assert_allclose(slope, -1.5, atol=0.02)
    # the static table alone: its slope at a fixed speed is the trim curve's
    static = (f(alpha=a + da)["Cm_0"] - f(alpha=a - da)["Cm_0"]) / (2 * da)
    assert np.all(static - -1.5 < -0.15)


def test_a_speed_term_needs_its_flights_trim_speed() -> None:
    flights = _speed_flights(5)
    bare = FlightCoefficients.from_stderr(
        "flight_v", {"alpha": 0.1, "altitude": 900.0}, {"Cm_V": 0.05}, {"Cm_V": 1e-3}
    )
    with pytest.raises(DataFormatError, match=r"flight_v.*Cm_V.*trim speed"):
        aerodynamic_database([*flights, bare], keys=("alpha", "altitude"))
    with pytest.raises(DataFormatError, match=r"flight_w.*trim speed"):
        FlightCoefficients.from_stderr("flight_w", {}, {"Cm_V": 0.0}, {}, trim_speed=-3.0)
    # an airspeed that is not a speed gives no reference: named where a speed term needs it
    odd = FlightCoefficients.from_stderr(
        "flight_z", {"alpha": 0.1, "altitude": 900.0, "airspeed": -3.0}, {"Cm_V": 0.05}, {}
    )
    assert odd.trim_speed is None
    from aeroid.uncertainty.database_export import split_term

    assert split_term("Cm_V") == ("Cm", "V")
    # over the airspeed, the static table's slope is the speed's effect: no speed term
    # flies again beside it (as CL_alpha beside a table over alpha)
    by_speed = [
        FlightCoefficients.from_stderr(
            f"s{i}",
            {"airspeed": v},
            {"Cm_0": 0.001 * v, "Cm_V": 0.04},
            {"Cm_0": 1e-4, "Cm_V": 1e-3},
        )
        for i, v in enumerate(np.linspace(30.0, 60.0, 7))
    ]
    section = aerodynamic_database(by_speed).to_jsbsim(n=5)
    assert "aeroid-Cm_V" not in section and "aeroid-Cm_0" in section


def test_jsbsim_flies_the_speed_term_about_the_trim_speed(tmp_path: Path) -> None:
    pytest.importorskip("jsbsim")
    from aeroid.uncertainty.database_export import TRIM_SPEED

    db = aerodynamic_database(_speed_flights(8), keys=("alpha", "altitude"))
    section = db.to_jsbsim(n=31)
    assert section.index(TRIM_SPEED) < section.index("aeroid-Cm_V")
    # 90 kt at 4 deg: about 10 % above the trim speed there
    fdm = _flying(section, tmp_path / "root", feet=3000.0, knots=90.0, alpha=4.0)
    fdm["ic/q-rad_sec"] = 0.1
    fdm.run_ic()
    fdm.run()
    ft = 0.3048
    cond = {"alpha": fdm["aero/alpha-rad"], "altitude": fdm["position/h-sl-ft"] * ft}
    v0 = db.trim_speed(cond)[0][0]
    # JSBSim interpolates the 31 x 31 table linearly; the trim speed curves in alpha
    # (a breakpoint's spacing 0.0057 rad: h^2 V0''/8 is about 1e-4 of V0)
    assert fdm[TRIM_SPEED] * ft == pytest.approx(v0, rel=5e-4)
    ratio = fdm["velocities/vt-fps"] / fdm[TRIM_SPEED] - 1.0
    assert ratio == pytest.approx(fdm["velocities/vt-fps"] * ft / v0 - 1.0, abs=1e-3)
    assert abs(ratio) > 0.05
    at = {t: db.predict(t, cond)[0][0] for t in db.terms}
    q_hat = fdm["aero/ci2vel"] * fdm["velocities/q-aero-rad_sec"]
    cm = at["Cm_0"] + at["Cm_q"] * q_hat + at["Cm_V"] * ratio
    qs, c = fdm["aero/qbar-area"], fdm["metrics/cbarw-ft"]
    assert fdm["moments/m-aero-lbsft"] / (qs * c) == pytest.approx(cm, rel=1e-4, abs=1e-6)
    assert fdm["aero/coefficient/aeroid-Cm_V"] / (qs * c) == pytest.approx(
        at["Cm_V"] * ratio, rel=1e-4
    )


def _line_flights() -> list[FlightCoefficients]:
    return [
        FlightCoefficients.from_stderr(
            f"f{i}", {"alpha": a}, {"CL_0": 0.3 + 4.8 * a}, {"CL_0": 0.01}
        )
        for i, a in enumerate(np.linspace(0.0, 0.2, 6))
    ]


@pytest.mark.parametrize(
    ("make", "error", "says"),
    [
        (lambda: aerodynamic_database(5), DataFormatError, "expected a sequence"),
        (lambda: aerodynamic_database([1, 2]), DataFormatError, r"flights\[0\]"),
        (
            lambda: aerodynamic_database(_line_flights(), confidence="0.9"),
            IdentificationError,
            "confidence",
        ),
        (
            lambda: aerodynamic_database(_line_flights(), max_degree=2.5),
            IdentificationError,
            "max_degree",
        ),
        (lambda: aerodynamic_database(_line_flights(), f_in=-1), IdentificationError, "f_in"),
        (
            lambda: FlightCoefficients.from_stderr("x", {"alpha": "a"}, {"CL_0": 1.0}, {}),
            DataFormatError,
            "flight 'x': condition 'alpha'",
        ),
        (
            lambda: FlightCoefficients.from_stderr(
                "x", {"alpha": 0.1}, {"CL_0": 1.0}, {"CL_0": -0.01}
            ),
            DataFormatError,
            "negative standard error of CL_0",
        ),
        (  # an estimate given without uncertainty was dropped in silence
            lambda: FlightCoefficients.from_stderr(
                "x", {"alpha": 0.1}, {"CL_0": 1.0}, {"CL_0": 0.0}
            ),
            DataFormatError,
            "standard error 0 of CL_0",
        ),
        (
            lambda: FlightCoefficients.from_stderr("x", {"alpha": 0.1}, {"CL_0": 1.0}, {"Cm": 0.1}),
            DataFormatError,
            "given for Cm, which it does not estimate",
        ),
        (
            lambda: FlightCoefficients("x", {"alpha": 0.1}, {"CL_0": np.inf}, np.eye(1)),
            DataFormatError,
            "infinite",
        ),
        (
            lambda: FlightCoefficients(
                "x", {"alpha": 0.1}, {"a": 1.0, "b": 2.0}, np.array([[1e-4, 1.0], [1.0, 0.25]])
            ),
            DataFormatError,
            "not positive semi-definite",
        ),
        (
            lambda: FlightCoefficients(
                "x", {"alpha": 0.1}, {"a": 1.0, "b": 2.0}, np.array([[1e-4, 4e-3], [0.0, 0.25]])
            ),
            DataFormatError,
            "not symmetric",
        ),
    ],
)
def test_bad_flights_and_options_are_named(make, error, says):
    with pytest.raises(error, match=says):
        make()


def test_a_condition_that_is_no_number_and_a_one_point_grid_are_refused():
    db = aerodynamic_database(_line_flights())
    for value, says in (("a", "alpha: expected numbers"), (np.nan, "alpha: expected finite")):
        with pytest.raises(DataFormatError, match=says):
            db.predict("CL_0", {"alpha": value})
    with pytest.raises(DataFormatError, match="n"):
        db.grid("alpha", n=0)
    with pytest.raises(DataFormatError, match="n"):
        db.to_jsbsim(n=1)


def test_a_prediction_outside_the_flown_envelope_warns_naming_the_key() -> None:
    import warnings

    db = aerodynamic_database(_flights(1, n=60))
    lo, hi = db.envelope["alpha"]
    assert lo == pytest.approx(min(f.condition["alpha"] for f in _flights(1, n=60)))
    assert db.envelope["altitude"] == (500.0, 1500.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        db.predict("CL", {"alpha": np.linspace(lo, hi, 5), "altitude": 1000.0})
        db.table(n=5)  # its grid spans the envelope
    with pytest.warns(UserWarning, match=r"CL: altitude = 3000 lies outside .*\[500, 1500\]"):
        db.predict("CL", {"alpha": 0.1, "altitude": 3000.0})
    with pytest.warns(UserWarning, match=r"Cn_r: alpha = 0.3 lies outside the flown envelope"):
        db.band("Cn_r", {"alpha": 0.3, "altitude": 1000.0})
