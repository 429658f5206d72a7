"""FlightData and load_flight_test: immutability, validation and file formats."""

from __future__ import annotations

import warnings

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import scipy.io
from _sidpac_files import sidpac_mat

import aeroid
from aeroid import ChannelError, DataFormatError, FlightData, load_flight_test


def _data() -> FlightData:
    t = np.linspace(0.0, 1.0, 11)
    return FlightData(t, {"alpha": np.sin(t), "q": np.cos(t)}, {"alpha": "rad"})


def test_arrays_are_read_only_copies():
    t = np.linspace(0.0, 1.0, 5)
    a = np.arange(5.0)
    d = FlightData(t, {"a": a})
    # Trap 12d: the caller's arrays stay writable and are not aliased.
    a[0] = 99.0
    t[0] = -1.0
    assert d["a"][0] == 0.0 and d.time[0] == 0.0
    assert a.flags.writeable and t.flags.writeable
    with pytest.raises(ValueError):
        d["a"][0] = 1.0
    with pytest.raises(ValueError):
        d.time[0] = 1.0
    with pytest.raises(TypeError):
        d.channels["b"] = a  # type: ignore[index]
    assert d["a"].dtype == np.float64


def test_access_array_window():
    d = _data()
    assert d.array(["q", "alpha"]).shape == (11, 2)
    np.testing.assert_array_equal(d.array(["q", "alpha"])[:, 1], d["alpha"])
    w = d.window(0.2, 0.5)
    np.testing.assert_allclose(w.time, [0.2, 0.3, 0.4, 0.5])
    assert w.units["alpha"] == "rad"
    assert "alpha" in d and d.n_samples == 11 and d.is_uniform
    assert d.sample_rate == pytest.approx(10.0)
    assert "| alpha |" in d.summary()


def test_missing_channel_names_it_and_lists_present():
    d = _data()
    with pytest.raises(ChannelError) as err:
        d["beta"]
    msg = str(err.value)
    assert "'beta'" in msg and "alpha" in msg and "q" in msg
    assert isinstance(err.value, aeroid.AeroidError)


@pytest.mark.parametrize(
    ("time", "channels", "fragment"),
    [
        ([0.0, 1.0, 1.0, 2.0], {"a": [0, 1, 2, 3]}, "index 2"),
        ([0.0, 2.0, 1.0], {"a": [0, 1, 2]}, "index 2"),
        ([0.0, np.nan, 2.0], {"a": [0, 1, 2]}, "time: non-finite value at index 1"),
        ([0.0, 1.0, 2.0], {"a": [0, np.inf, 2]}, "channel 'a': non-finite value at index 1"),
        ([0.0, 1.0, 2.0], {"a": [0, 1]}, "channel 'a': length"),
        ([0.0], {"a": [0]}, "at least 2"),
    ],
)
def test_bad_data_raises_dataformaterror(time, channels, fragment):
    with pytest.raises(DataFormatError, match=fragment.replace("(", r"\(")):
        FlightData(time, channels)


def test_csv_roundtrip_keeps_headers_verbatim(tmp_path):
    path = tmp_path / "f.csv"
    path.write_text("time,Alpha (deg),q\n0,1.5,2\n0.1,1.6,2.1\n0.2,1.7,2.2\n")
    d = load_flight_test(path)
    # Trap 12c: headers are channel names verbatim.
    assert d.names == ("Alpha (deg)", "q")
    np.testing.assert_allclose(d["Alpha (deg)"], [1.5, 1.6, 1.7])
    renamed = load_flight_test(path, channels={"Alpha (deg)": "alpha"}, units={"alpha": "deg"})
    assert renamed.names == ("alpha",) and renamed.units["alpha"] == "deg"


@pytest.mark.parametrize(
    ("body", "fragment"),
    [
        ("0,1\n0.1,\n0.2,3\n", "row 3, column 'a': blank cell"),
        ("0,1\n0.1,abc\n0.2,3\n", "row 3, column 'a': non-numeric"),
        ("0,1\n0.1,nan\n0.2,3\n", "row 3, column 'a': non-finite"),
        ("0,1\n0.1,2,5\n0.2,3\n", "row 3 has 3 cells"),
        ("0,1\n0.1,2\n0.1,3\n", "not strictly increasing"),
    ],
)
def test_malformed_csv_names_row_and_column(tmp_path, body, fragment):
    # Trap 12c: a blank or non-numeric cell is an error, never a silent NaN or -1.
    path = tmp_path / "bad.csv"
    path.write_text("time,a\n" + body)
    with pytest.raises(DataFormatError) as err:
        load_flight_test(path)
    assert fragment in str(err.value) and "bad.csv" in str(err.value)


def test_loader_errors(tmp_path):
    with pytest.raises(DataFormatError, match="no such file"):
        load_flight_test(tmp_path / "missing.csv")
    p = tmp_path / "x.xyz"
    p.write_text("1")
    with pytest.raises(DataFormatError, match="unknown file type"):
        load_flight_test(p)
    c = tmp_path / "c.csv"
    c.write_text("clock,a\n0,1\n1,2\n")
    with pytest.raises(ChannelError, match="no time column"):
        load_flight_test(c)
    assert load_flight_test(c, time_column="clock").names == ("a",)
    with pytest.raises(ChannelError, match="'b' not found"):
        load_flight_test(c, time_column="clock", channels=["b"])
    bad = tmp_path / "bad.parquet"
    bad.write_bytes(b"not parquet at all")
    with pytest.raises(DataFormatError, match=r"bad\.parquet"):
        load_flight_test(bad)


def test_parquet_and_mat(tmp_path):
    t = np.linspace(0, 1, 6)
    pq.write_table(pa.table({"time": t, "alpha": t**2}), tmp_path / "f.parquet")
    d = load_flight_test(tmp_path / "f.parquet")
    np.testing.assert_allclose(d["alpha"], t**2)
    nulls = pa.table({"time": t, "alpha": pa.array([0.0, None, 1, 2, 3, 4])})
    pq.write_table(nulls, tmp_path / "n.parquet")
    with pytest.raises(DataFormatError, match=r"row 1, column .alpha.: null"):
        load_flight_test(tmp_path / "n.parquet")
    scipy.io.savemat(tmp_path / "f.mat", {"t": t, "q": np.cos(t), "label": "flight 1"})
    m = load_flight_test(tmp_path / "f.mat")
    assert m.names == ("q",)
    np.testing.assert_allclose(m["q"], np.cos(t))
    (tmp_path / "broken.mat").write_bytes(b"garbage")
    with pytest.raises(DataFormatError, match=r"broken\.mat"):
        load_flight_test(tmp_path / "broken.mat")


def test_time_axis_error_prints_plain_numbers():
    with pytest.raises(DataFormatError, match=r"index 2 \(t\[1\]=0\.45, t\[2\]=0\.45\)$"):
        FlightData(np.array([0.0, 0.45, 0.45]), {"a": [0.0, 1.0, 2.0]})
    with pytest.raises(DataFormatError, match=r"got t0=3\.0, t1=1\.0$"):
        _data().window(np.float64(3.0), np.float64(1.0))


def test_complex_channel_is_refused_not_truncated():
    t = np.linspace(0.0, 1.0, 5)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no ComplexWarning on the way to the error
        with pytest.raises(DataFormatError, match="channel 'alpha': complex values"):
            FlightData(t, {"alpha": t + 1j, "q": t})
        with pytest.raises(DataFormatError, match="time: complex values"):
            FlightData(t + 0j, {"q": t})


def test_complex_mat_variable_is_refused_by_name(tmp_path):
    t = np.linspace(0.0, 1.0, 6)
    scipy.io.savemat(tmp_path / "c.mat", {"t": t, "alpha": t + 1j * t, "q": np.cos(t)})
    with pytest.raises(DataFormatError, match=r"c\.mat: column 'alpha' holds complex values"):
        load_flight_test(tmp_path / "c.mat")
    # a complex variable nobody asked for is no obstacle
    assert load_flight_test(tmp_path / "c.mat", channels=["q"]).names == ("q",)


@pytest.mark.parametrize("what", ["units", "metadata"])
@pytest.mark.parametrize("value", [5, ["rad"]])
def test_units_and_metadata_must_be_mappings(what, value):
    t = np.linspace(0.0, 1.0, 3)
    with pytest.raises(DataFormatError, match=f"{what}: expected a mapping"):
        FlightData(t, {"a": t}, **{what: value})


def test_units_and_metadata_may_be_none():
    t = np.linspace(0.0, 1.0, 3)
    d = FlightData(t, {"a": t}, None, None)
    assert dict(d.units) == {} and dict(d.metadata) == {}


def test_loader_path_errors_name_the_path(tmp_path):
    with pytest.raises(DataFormatError, match="path: expected a file path"):
        load_flight_test(None)  # type: ignore[arg-type]
    with pytest.raises(DataFormatError, match=r"path: expected a file path .* got int"):
        load_flight_test(5)  # type: ignore[arg-type]
    with pytest.raises(DataFormatError, match=f"{tmp_path.name}: is a directory"):
        load_flight_test(tmp_path)
    (tmp_path / "d.csv").mkdir()
    with pytest.raises(DataFormatError, match=r"d\.csv: is a directory"):
        load_flight_test(tmp_path / "d.csv")
    with pytest.raises(DataFormatError, match=r"missing\.csv: no such file"):
        load_flight_test(str(tmp_path / "missing.csv"))


def test_two_columns_renamed_alike_are_refused(tmp_path):
    path = tmp_path / "f.csv"
    path.write_text("time,alpha,q\n0,1,2\n0.1,1.1,2.1\n")
    with pytest.raises(DataFormatError, match=r"columns \['alpha', 'q'\] are all renamed to 'x'"):
        load_flight_test(path, channels={"alpha": "x", "q": "x"})
    # a single name is one column, not its letters
    assert load_flight_test(path, channels="alpha").names == ("alpha",)


def test_parquet_time_types_become_seconds(tmp_path):
    ns = np.array([0, 50_000_000, 100_000_000], dtype=np.int64)
    epoch = 1_700_000_000 * 10**9  # a real date: seconds count from the first sample
    columns = {
        "stamp": pa.array(ns + epoch, pa.timestamp("ns")),
        "stamp_utc": pa.array(ns + epoch, pa.timestamp("ns", tz="UTC")),
        "elapsed": pa.array([2000, 2050, 2100], pa.duration("ms")),
        "clock": pa.array([3_600_000_000, 3_600_050_000, 3_600_100_000], pa.time64("us")),
    }
    for name, col in columns.items():
        pq.write_table(pa.table({name: col, "alpha": [1.0, 2.0, 3.0]}), tmp_path / "f.parquet")
        d = load_flight_test(tmp_path / "f.parquet", time_column=name)
        expected = {"elapsed": [2.0, 2.05, 2.1], "clock": [3600.0, 3600.05, 3600.1]}
        np.testing.assert_allclose(d.time, expected.get(name, [0.0, 0.05, 0.1]), rtol=1e-12)
        assert d.names == ("alpha",)


def test_datetime_time_axis_becomes_seconds_since_first_sample():
    t = np.array(["2024-05-01T12:00:00", "2024-05-01T12:00:01"], dtype="datetime64[ns]")
    d = FlightData(t, {"a": [0.0, 1.0]})
    np.testing.assert_array_equal(d.time, [0.0, 1.0])
    d = FlightData(np.array([10, 20], dtype="timedelta64[ms]"), {"a": [0.0, 1.0]})
    np.testing.assert_array_equal(d.time, [0.01, 0.02])


def test_csv_comments_bom_spaces_quotes_and_crlf(tmp_path):
    path = tmp_path / "export.csv"
    body = '# exported by the FTI\n\n# units: s, deg\n"time", Alpha (deg) ,q\r\n0, 1.5,"2"\r\n0.1,1.6 ,2.1\r\n'
    path.write_bytes(b"\xef\xbb\xbf" + body.encode())
    with pytest.warns(UserWarning, match=r"line 3: units comment not read \(not JSON"):
        d = load_flight_test(path)  # the FTI's "# units: s, deg" declares no unit
    assert d.names == ("Alpha (deg)", "q") and dict(d.units) == {}
    np.testing.assert_array_equal(d.time, [0.0, 0.1])
    np.testing.assert_array_equal(d["Alpha (deg)"], [1.5, 1.6])
    np.testing.assert_array_equal(d["q"], [2.0, 2.1])


def test_csv_values_are_exact_read_only_and_owned(tmp_path):
    # 60k rows span several pyarrow blocks: the columns are stitched from chunks
    rng = np.random.default_rng(0)
    t = np.arange(60_000) * 0.01
    x = rng.standard_normal(t.size)
    path = tmp_path / "big.csv"
    with open(path, "w") as f:
        f.write("time,x\n")
        f.writelines(f"{a!r},{b!r}\n" for a, b in zip(t.tolist(), x.tolist(), strict=True))
    d = load_flight_test(path)
    np.testing.assert_array_equal(d.time, t)  # repr round-trips doubles exactly
    np.testing.assert_array_equal(d["x"], x)
    for arr in (d.time, d["x"]):
        assert not arr.flags.writeable and type(arr) is np.ndarray
        with pytest.raises(ValueError):
            arr.setflags(write=True)  # a view: the record's owner cannot be reached


@pytest.mark.parametrize(
    ("row", "cell", "fragment"),
    [
        (45_000, "", "row 45002, column 'x': blank cell"),
        (51_234, "1.2.3", "row 51236, column 'x': non-numeric ('1.2.3') cell"),
        (30_000, "inf", "row 30002, column 'x': non-finite value 'inf'"),
        (59_999, "4,5", "row 60001 has 3 cells, header has 2"),
    ],
)
def test_csv_bad_cell_deep_in_a_large_file_is_located(tmp_path, row, cell, fragment):
    lines = [f"{0.01 * i!r},{i % 7}.25" for i in range(60_000)]
    lines[row] = f"{0.01 * row!r},{cell}"
    path = tmp_path / "deep.csv"
    path.write_text("time,x\n" + "\n".join(lines) + "\n")
    with pytest.raises(DataFormatError) as err:
        load_flight_test(path)
    assert fragment in str(err.value) and "deep.csv" in str(err.value)


def test_csv_header_only_or_empty(tmp_path):
    empty = tmp_path / "empty.csv"
    empty.write_text("# nothing but a comment\n\n")
    with pytest.raises(DataFormatError, match=r"empty\.csv: empty file"):
        load_flight_test(empty)
    one = tmp_path / "one.csv"
    one.write_text("time,a\n0,1\n")
    with pytest.raises(DataFormatError, match="fewer than 2 data rows"):
        load_flight_test(one)
    with pytest.raises(
        DataFormatError, match="sample_rate, max_gap, t0 and t1 apply to flight logs"
    ):
        load_flight_test(one, sample_rate=10.0)


def test_csv_comment_lines_among_the_data_are_skipped(tmp_path):
    path = tmp_path / "notes.csv"
    path.write_text("time,a\n0,1\n# gear up\n0.1,2\n\n0.2,3\n# end of run\n")
    d = load_flight_test(path)
    np.testing.assert_array_equal(d["a"], [1.0, 2.0, 3.0])
    # the row named is the file line an editor shows, comment lines counted
    path.write_text("time,a\n0,1\n# gear up\n0.1,x\n0.2,3\n")
    with pytest.raises(DataFormatError, match=r"row 4, column 'a': non-numeric \('x'\)"):
        load_flight_test(path)
    path.write_text("time,a\n0,1\n# gear up\n0.1,2,9\n0.2,3\n")
    with pytest.raises(DataFormatError, match=r"notes\.csv: row 4 has 3 cells, header has 2"):
        load_flight_test(path)
    path.write_text("time,a\n")
    with pytest.raises(DataFormatError, match=r"notes\.csv: fewer than 2 data rows"):
        load_flight_test(path)


def test_time_jitter_below_one_percent_is_uniform_sampling_with_a_note():
    # stamps rounded as in SIDPAC's Example 7.2: 1e-4 of the 0.1 s interval
    rng = np.random.default_rng(0)
    n = 3050
    exact = np.arange(n) * 0.1
    t = exact + rng.uniform(-1e-5, 1e-5, n)
    t[0], t[-1] = exact[0], exact[-1]
    d = FlightData(t, {"u": np.sin(t), "y": np.cos(t)})
    assert d.is_uniform and d.sample_rate == pytest.approx(10.0, rel=1e-12)
    note = d.metadata["time_jitter"]
    assert "taken as uniform" in note and "0.01 %" in note
    # a grid exact to rounding makes no note; a caller's own note is kept
    assert "time_jitter" not in FlightData(exact, {"u": np.sin(exact)}).metadata
    mine = FlightData(t, {"u": np.sin(t)}, metadata={"time_jitter": "known"})
    assert mine.metadata["time_jitter"] == "known"
    # just under and just over 1 % of the interval
    for frac, uniform in ((0.009, True), (0.011, False), (0.05, False)):
        s = exact.copy()
        s[n // 2] += frac * 0.1
        rec = FlightData(s, {"u": np.sin(s)})
        assert rec.is_uniform is uniform
        assert ("time_jitter" in rec.metadata) is uniform


def test_jittered_record_reaches_the_frequency_tools_and_larger_jitter_is_refused():
    from aeroid import composite_response, frequency_response
    from aeroid.models import catalog

    rng = np.random.default_rng(1)
    sp = catalog.short_period_flight(duration=20.0, seed=0)
    t = sp.time + rng.uniform(-2e-5, 2e-5, sp.n_samples) * (np.arange(sp.n_samples) % 3 > 0)
    jittered = FlightData(t, dict(sp.channels))
    assert "time_jitter" in jittered.metadata
    res = composite_response(jittered, "elevator", "q")
    clean = composite_response(sp, "elevator", "q")
    np.testing.assert_allclose(res.channels[0].response, clean.channels[0].response, rtol=1e-6)
    with pytest.warns(UserWarning):  # a doublet: few resolved frequencies
        frequency_response(catalog.short_period(), jittered, nperseg=128)
    t2 = sp.time.copy()
    t2[100] += 0.02 * 0.02  # 2 % of the 0.02 s interval
    with pytest.raises(DataFormatError, match="uniform"):
        frequency_response(catalog.short_period(), FlightData(t2, dict(sp.channels)))
    with pytest.raises(DataFormatError, match="uniform"):
        composite_response(FlightData(t2, dict(sp.channels)), "elevator", "q")


def test_sidpac_example_7p2_time_stamps_are_taken_as_uniform():
    mat = sidpac_mat("Text_Examples", "example_7p2_results.mat")
    t = mat["t"][:, 0]
    steps = np.diff(t)
    assert np.ptp(steps) / np.mean(steps) > 1e-4  # rounded stamps: refused before
    d = FlightData(t, {"u": mat["u"][:, 0], "z": mat["z"][:, 0]})
    assert d.is_uniform and d.sample_rate == pytest.approx(10.0, rel=1e-6)
    assert "time_jitter" in d.metadata


def test_to_csv_round_trips_exactly_and_refuses_unwritable_names(tmp_path):
    from aeroid.models import catalog

    data = catalog.short_period_flight(seed=3, duration=2.0)
    path = data.to_csv(tmp_path / "f.csv")
    back = load_flight_test(path)
    assert back.names == data.names
    np.testing.assert_array_equal(back.time, data.time)
    for name in data.names:
        np.testing.assert_array_equal(back[name], data[name])
    assert dict(back.units) == dict(data.units) and data.units  # the units too
    renamed = load_flight_test(path, channels={"alpha": "aoa"}, units={"aoa": "deg"})
    assert dict(renamed.units) == {"aoa": "deg"}  # given units win, under the new name
    assert not list(tmp_path.glob("*.part"))
    bad = tmp_path / "bad.csv"
    # another tool's comment, or one cut short or hand edited: no units, and a warning
    # naming the file and the line (the units would vanish without a word)
    for line, why in [
        ("# units: alpha=rad", "not JSON"),
        ('# note\n# units: {"alpha": "deg"', "not JSON"),
        ("# units: [1, 2]", "not a JSON object"),
        ('# units: {"alpha": 5}', "the unit of 'alpha' is not a string"),
    ]:
        bad.write_text(line + "\ntime,alpha\n0,1\n1,2\n")
        at = line.count("\n") + 1
        with pytest.warns(
            UserWarning, match=rf"bad.csv: line {at}: units comment not read \({why}"
        ):
            assert dict(load_flight_test(bad).units) == {}
    odd = FlightData(np.arange(3.0), {"a,b": np.zeros(3)})
    with pytest.raises(DataFormatError, match=r"'a,b'"):
        odd.to_csv(tmp_path / "g.csv")
    assert not (tmp_path / "g.csv").exists()
    with pytest.raises(DataFormatError, match="cannot write"):
        data.to_csv(tmp_path / "missing" / "h.csv")


def test_a_log_is_loaded_between_t0_and_t1_around_a_gap_outside_them():
    from pathlib import Path

    log = Path(__file__).parent / "data" / "px4" / "sample_log_small.ulg"
    chans = {"y": "vehicle_angular_velocity.xyz[0]", "u": "actuator_controls_0.control[0]"}
    with pytest.raises(DataFormatError, match=r"gap of 0\.16"):
        load_flight_test(log, channels=chans, sample_rate=100)
    data = load_flight_test(log, channels=chans, sample_rate=100, t0=21.0, t1=26.0)
    assert data.time[0] == pytest.approx(21.0) and data.time[-1] <= 26.0 + 1e-9
    with pytest.raises(DataFormatError, match="t0 applies only with sample_rate"):
        load_flight_test(log, channels=chans, t0=21.0)


@pytest.mark.parametrize("suffix", [".mat", ".parquet"])
def test_a_file_declaring_more_than_the_limit_is_refused_before_reading(
    tmp_path, monkeypatch, suffix
):
    # a small compressed file can declare gigabytes: the declared size is checked first
    import aeroid.io._table_files as table_files

    n = 2000
    t = np.arange(n) * 0.01
    path = tmp_path / f"big{suffix}"
    if suffix == ".mat":
        scipy.io.savemat(path, {"time": t, "q": np.zeros(n)}, do_compression=True)
    else:
        pq.write_table(pa.table({"time": t, "q": np.zeros(n)}), path, compression="zstd")
    assert load_flight_test(path).n_samples == n
    monkeypatch.setattr(table_files, "_MAX_DECLARED_BYTES", 8 * n - 1)
    with pytest.raises(DataFormatError, match=r"declares .* over the 0 MiB"):
        load_flight_test(path)


def test_hostile_csv_encodings_name_the_file_and_row(tmp_path, capfd):
    from aeroid import load_flight_test

    mac = tmp_path / "mac.csv"
    mac.write_bytes(b"time,a\r0,1\r0.1,2\r0.2,3\r")
    with pytest.raises(DataFormatError, match=r"mac\.csv: lines end in a carriage return alone"):
        load_flight_test(mac)
    for body in (b"0.1,2,\xff\n", b"0.1,\xff\n"):  # a ragged row, a bad cell
        bad = tmp_path / "latin.csv"
        bad.write_bytes(b"time,a\n0,1\n" + body + b"0.2,3\n")
        with pytest.raises(DataFormatError, match=r"latin\.csv: row 3: byte \d+ .*not UTF-8"):
            load_flight_test(bad)
    # pyarrow prints, rather than raises, an error met in its row callback
    assert "Traceback" not in capfd.readouterr().err


def test_wrong_types_in_the_loader_and_the_record_are_named(tmp_path):
    from aeroid import load_flight_test

    d = FlightData([0.0, 0.1, 0.2], {"a": [1.0, 2.0, 3.0]})
    path = d.to_csv(tmp_path / "ok.csv")
    for units in (["rad"], "rad", 3):
        with pytest.raises(DataFormatError, match="units: expected a mapping"):
            load_flight_test(path, units=units)
    with pytest.raises(DataFormatError, match="window: t0 must be a number, got 'a'"):
        d.window("a", 1.0)  # type: ignore[arg-type]
    with pytest.raises(DataFormatError, match="window: t1 must be a number"):
        d.window(0.0, float("nan"))
    with pytest.raises(DataFormatError, match="channel 'a': not numeric"):
        FlightData([0.0, 1.0], {"a": [0, 10**400]})
    # the loader strips the spaces round a header cell, so such a name cannot round-trip
    with pytest.raises(DataFormatError, match="channel name ' a' cannot be a CSV column"):
        FlightData([0.0, 0.1], {" a": [1.0, 2.0]}).to_csv(tmp_path / "spaced.csv")


def test_channel_names_of_the_wrong_type_are_named():
    d = FlightData([0.0, 1.0, 2.0], {"alpha": [1.0, 2.0, 3.0], "q": [0.0, 1.0, 2.0]})
    with pytest.raises(ChannelError, match="expected a list of names, got 123"):
        d.array(123)  # type: ignore[arg-type]
    with pytest.raises(ChannelError, match=r"channel name \['alpha'\]: expected a string"):
        d[["alpha"]]  # type: ignore[index]
    assert d.array(iter(["alpha", "q"])).shape == (3, 2)  # an iterator is read once


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_a_file_name_that_is_not_utf8_is_read(tmp_path, suffix):
    """pyarrow cannot encode such a name (a bare UnicodeEncodeError for CSV; "not a
    readable Parquet file" for a valid one)."""
    import os

    name = os.fsdecode(os.path.join(os.fsencode(tmp_path), b"vol_\xff\xfe" + suffix.encode()))
    if suffix == ".csv":
        with open(name, "w") as fh:
            fh.write("time,a\n0,1\n0.1,2\n0.2,4\n")
    else:
        with open(name, "wb") as fh:
            pq.write_table(pa.table({"time": [0.0, 0.1, 0.2], "a": [1.0, 2.0, 4.0]}), fh)
    data = load_flight_test(name)
    np.testing.assert_array_equal(data["a"], [1.0, 2.0, 4.0])
