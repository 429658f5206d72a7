"""The campaign stage ``database`` (issue 51): fitted over the flights, files, incremental."""

from __future__ import annotations

from pathlib import Path

from aeroid.pipeline import open_store, plan, run
from aeroid.pipeline.plans.synthetic import _truth
from aeroid.uncertainty.database import AeroDatabase


def _config(tmp: Path, n: int, extra: str = "") -> Path:
    # flights 10 m/s apart from 60 m/s: one more flight leaves the others as they were
    cfg = tmp / "c.yaml"
    cfg.write_text(
        "model: short_period\nseed: 5\nstore: store\nreport: out/report.md\n"
        f"flights: [{{simulated: {{n_flights: {n}, seed: 1, duration: 6.0, airspeed: [60.0, {60.0 + 10.0 * (n - 1)}]}}}}]\n"
        "stages:\n  identify: {parameters: [Z_alpha, M_alpha, M_q, M_delta]}\n  validate: {}\n"
        "  database: {terms: [M_alpha, M_q], held_out: [sim-1], "
        + (extra or "keys: [airspeed]")
        + "}\n"
    )
    return cfg


def test_database_stage_fits_the_flights_and_writes_its_files(tmp_path: Path) -> None:
    cfg = _config(tmp_path, 7)
    s = run(cfg, workers=0)
    assert s.failed == 0, [st.error for st in s.statuses.values() if st.error]
    task = next(t for t in s.plan.tasks if t.stage == "database")
    db = open_store(tmp_path / "store").load(task.key, "database")
    assert isinstance(db, AeroDatabase)
    assert "sim-1" not in db.flights and len(db.flights) == 6
    assert {c.flight for c in db.held_out} == {"sim-1"}
    for v in (65.0, 90.0, 115.0):
        for term in ("M_alpha", "M_q"):
            value, se = db.predict(term, {"airspeed": v})
            assert abs(value[0] - _truth(v)[term]) < 4.5 * se[0] + 0.02 * abs(_truth(v)[term])
    folder = s.database_dir
    assert folder == tmp_path / "out" / "report_database"
    text = (folder / "database.md").read_text()
    assert "## Aerodynamic database" in text and "Held-out flights" in text
    assert "No JSBSim section" in text  # M_q is a dimensional derivative, not <C>_<regressor>
    assert (folder / "M_q.png").read_bytes()[:4] == b"\x89PNG"
    assert (folder / "database.parquet").is_file()


def test_adding_a_flight_computes_that_flight_and_the_campaign_steps_only(tmp_path: Path) -> None:
    run(_config(tmp_path, 6), workers=0)
    p = plan(_config(tmp_path, 7))
    store = open_store(tmp_path / "store")
    stored = store.stored((t.stage, t.key) for t in p.tasks)
    todo = [t for t in p.tasks if (t.stage, t.key) not in stored]
    per_flight = {t.flight for t in todo if t.stage not in ("database", "campaign_report")}
    assert per_flight == {"sim-6"}
    assert {t.stage for t in todo if t.flight not in ("sim-6",)} <= {"database", "campaign_report"}
    assert any(t.stage == "database" for t in todo)


def test_database_stage_names_the_flight_without_a_condition(tmp_path: Path) -> None:
    s = run(_config(tmp_path, 4, "keys: [airspeed, altitude]"), workers=0)
    task = next(t for t in s.plan.tasks if t.stage == "database")
    err = s.statuses[task.key].error or ""
    assert "has no condition 'altitude'" in err and "sim-" in err
    assert s.report_path is not None


def test_database_stage_names_a_term_no_flight_excites(tmp_path: Path) -> None:
    cfg = tmp_path / "c.yaml"
    _config(tmp_path, 3)
    cfg.write_text(cfg.read_text().replace("terms: [M_alpha, M_q]", "terms: [M_nothing]"))
    s = run(cfg, workers=0)
    task = next(t for t in s.plan.tasks if t.stage == "database")
    assert "no flight excites 'M_nothing'" in (s.statuses[task.key].error or "")


def test_the_replay_option_changes_no_key_and_the_section_says_what_it_flew(
    tmp_path: Path,
) -> None:
    plain = plan(_config(tmp_path, 4))
    cfg = _config(tmp_path, 4, "keys: [airspeed], replay: c172x")
    named = plan(cfg)
    assert [t.key for t in plain.tasks] == [t.key for t in named.tasks]
    s = run(cfg, workers=0)
    text = (s.database_dir / "database.md").read_text()
    # the short-period model's M_q has no JSBSim section to fly
    assert "### Held-out flights flown again with the database" in text
    assert "no JSBSim section" in text or "jsbsim is not installed" in text
    s = run(_config(tmp_path, 4), workers=0)
    assert "names no simulator" in (s.database_dir / "database.md").read_text()


def test_database_stage_leaves_the_time_delays_out(tmp_path: Path) -> None:
    # each flight's fit reports tau_elevator with its covariance; the database fits the
    # aerodynamic terms only (a delay is the recorder's, not a coefficient of the condition)
    from aeroid.pipeline.stages.database_stage import _COEFFICIENT

    cfg = _config(tmp_path, 5, "keys: [airspeed]")
    cfg.write_text(
        cfg.read_text().replace(
            "identify: {parameters: [Z_alpha, M_alpha, M_q, M_delta]}",
            "identify: {parameters: [Z_alpha, M_alpha, M_q, M_delta], time_delays: [elevator]}",
        )
    )
    s = run(cfg, workers=0)
    assert s.failed == 0, [st.error for st in s.statuses.values() if st.error]
    store = open_store(tmp_path / "store")
    ident = next(t for t in s.plan.tasks if t.stage == "identify")
    assert "tau_elevator" in store.load(ident.key, "identify").parameter_names
    db = store.load(next(t for t in s.plan.tasks if t.stage == "database").key, "database")
    assert set(db.structures) == {"M_alpha", "M_q"}
    assert _COEFFICIENT.match("Cl_p") and not _COEFFICIENT.match("tau_delta_a")


def test_the_stage_refers_speed_terms_to_each_flights_airspeed() -> None:
    # the briefs of flights trimmed along 1/V0^2 = 2.5e-4 (1 + 10 alpha): the stage takes
    # each flight's trim speed from its condition's airspeed, though the database's keys
    # are alpha alone, and the fitted reference returns those speeds
    import numpy as np

    from aeroid.pipeline.stages import StageContext
    from aeroid.pipeline.stages.database_stage import DatabaseOptions, _run_database

    names = ["Cm_0", "Cm_V"]
    alphas = np.linspace(0.0, 0.15, 8)
    ident, data = {}, {}
    for i, a in enumerate(alphas):
        ident[i] = {
            "names": names,
            "parameters": {"Cm_0": -0.1 * a, "Cm_V": 0.04 + 0.2 * a},
            "covariance": (np.eye(2) * 1e-6).tolist(),
        }
        data[i] = {"alpha": float(a), "airspeed": float(1.0 / np.sqrt(2.5e-4 * (1 + 10 * a)))}
    flights = tuple(f"f{i}" for i in range(len(alphas)))
    ctx = StageContext(
        options=DatabaseOptions(keys=["alpha"]),
        inputs={},
        flights=flights,
        briefs={"identification": ident, "data": data},
    )
    db = _run_database(ctx)
    assert db.keys == ("alpha",) and db.speed_terms == ("Cm_V",)
    v0, _ = db.trim_speed({"alpha": alphas})
    np.testing.assert_allclose(v0, [data[i]["airspeed"] for i in range(len(alphas))], rtol=1e-6)


def test_an_unchanged_rerun_writes_no_database_file_and_a_missing_one_again(
    tmp_path: Path,
) -> None:
    cfg = _config(tmp_path, 4)
    folder = run(cfg, workers=0).database_dir
    assert folder is not None
    plot = folder / "M_q.png"
    first = {p.name: (p.stat().st_mtime_ns, p.read_bytes()) for p in folder.iterdir()}
    assert run(cfg, workers=0).database_dir == folder
    assert {p.name: p.stat().st_mtime_ns for p in folder.iterdir()} == {
        k: v[0] for k, v in first.items()
    }
    # a plot removed (or cut short) is written again, the same bytes
    plot.unlink()
    (folder / "database.md").write_text("cut")
    run(cfg, workers=0)
    assert plot.read_bytes() == first["M_q.png"][1]
    assert (folder / "database.md").read_bytes() == first["database.md"][1]
    # an option outside the keys (the replay) writes the section again
    named = _config(tmp_path, 4, "keys: [airspeed], replay: c172x")
    run(named, workers=0)
    assert "names no simulator" not in (folder / "database.md").read_text()


def test_the_worker_that_fits_the_database_draws_its_plots(tmp_path: Path, monkeypatch) -> None:
    # the plots and the table come back with the database task's status: the run's own
    # process, which writes them after the last task, makes none of them (on the run's
    # critical path)
    from aeroid.pipeline.stages import database_stage

    TABLE = "database.parquet"

    def drawn_here(*args: object, **kwargs: object) -> list[bytes]:
        raise AssertionError("the run's own process drew the database's plots")

    monkeypatch.setattr(database_stage, "forked_map", drawn_here)
    monkeypatch.setattr(AeroDatabase, "to_parquet", _written_here(AeroDatabase.to_parquet))
    cfg = _config(tmp_path, 4)
    s = run(cfg, workers=0)
    task = next(t for t in s.plan.tasks if t.stage == "database")
    status = s.statuses[task.key]
    assert status.files is not None
    assert {"M_alpha.png", "M_q.png"} <= set(status.files) <= {*{"M_alpha.png", "M_q.png"}, TABLE}
    folder = s.database_dir
    assert folder is not None
    for name, png in status.files.items():
        assert (folder / name).read_bytes() == png
    # a stored database (files gone): this process makes them, the same bytes
    monkeypatch.undo()
    for name in status.files:
        (folder / name).unlink()
    again = run(cfg, workers=0)
    assert again.statuses[task.key].files is None
    for name, png in status.files.items():
        assert (folder / name).read_bytes() == png


def _written_here(to_parquet):
    """`AeroDatabase.to_parquet` that fails when the run's own process (no worker: the
    test's, where the run's pytest process is the main one) calls it after the tasks."""
    import inspect

    def guarded(self, path, **kwargs):
        callers = {f.function for f in inspect.stack()}
        if "write_database_files" in callers:
            raise AssertionError("the run's own process wrote the Parquet table")
        return to_parquet(self, path, **kwargs)

    return guarded
