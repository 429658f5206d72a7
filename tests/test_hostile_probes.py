"""Probes of issue 49 that earlier fixes left open: a ULog with corrupt definitions,
unit labels that contradict the log or the model, a store prefix left half-made."""

from __future__ import annotations

import struct
import warnings
from pathlib import Path

import numpy as np
import pytest

from aeroid import FlightData, identify, load_flight_test, read_log
from aeroid.errors import DataFormatError, IdentificationError
from aeroid.models import catalog

ULOG = Path(__file__).parent / "data" / "px4" / "sample_log_small.ulg"


def _garble_definition(raw: bytes, topic: bytes) -> bytes:
    """The ULog with the field list of `topic`'s format message overwritten."""
    pos = 16  # after the file header
    while pos < len(raw):
        size, kind = struct.unpack_from("<HB", raw, pos)
        if kind == ord("A"):  # the data section starts: no such topic
            break
        body = raw[pos + 3 : pos + 3 + size]
        if kind == ord("F") and body.startswith(topic + b":"):
            out = bytearray(raw)
            at = pos + 3 + len(topic) + 6  # inside the first field type
            out[at : at + 10] = b"\xff" * 10
            return bytes(out)
        pos += 3 + size
    raise AssertionError(f"no format message for {topic!r}")


def test_a_ulog_with_corrupt_definitions_says_so_not_channel_not_found(tmp_path):
    pytest.importorskip("pyulog")
    bad = tmp_path / "corrupt.ulg"
    bad.write_bytes(_garble_definition(ULOG.read_bytes(), b"vehicle_angular_velocity"))
    log = read_log(bad)  # the other topics are still read
    assert "sensor_combined.gyro_rad[0]" in log
    assert "corrupt" in log.metadata["corrupt"]
    with pytest.raises(
        DataFormatError, match=r"corrupt\.ulg: channel .* message definitions are corrupt"
    ):
        load_flight_test(bad, channels={"vehicle_angular_velocity.xyz[1]": "q"})
    # a channel whose topic survived still loads; the intact file still names near misses
    ok = load_flight_test(bad, channels={"sensor_combined.gyro_rad[1]": "q"})
    assert ok.n_samples > 100
    from aeroid import ChannelError

    with pytest.raises(ChannelError, match="not found in the log"):
        load_flight_test(ULOG, channels={"vehicle_angular_velocity.xyz[7]": "q"})


def test_a_unit_label_contradicting_the_logs_own_is_refused():
    pytest.importorskip("pyulog")
    gyro = "sensor_combined.gyro_rad[1]"
    with pytest.raises(
        DataFormatError, match=r"units\['q'\] = 'deg/s' contradicts the unit 'rad/s'"
    ):
        load_flight_test(ULOG, channels={gyro: "q"}, units={"q": "deg/s"})
    same = load_flight_test(ULOG, channels={gyro: "q"}, units={"q": "rad/s"})
    assert same.units["q"] == "rad/s"
    # a unit the log does not state, or one AeroID does not know, is the caller's label
    assert (
        load_flight_test(ULOG, channels={gyro: "q"}, units={"q": "rad/sec"}).units["q"] == "rad/sec"
    )


def _lateral_record():
    from aeroid.models.aircraft import lateral_linear

    truth = {
        **{"Y_beta": -0.2, "Y_delta_r": 0.03, "L_beta": -15.0, "L_p": -8.0, "L_r": 2.0},
        **{"L_delta_a": 30.0, "L_delta_r": 2.0, "N_beta": 6.0, "N_p": -0.5, "N_r": -1.5},
        **{"N_delta_a": -1.0, "N_delta_r": -5.0},
    }
    model = lateral_linear(V0=30.0, outputs=["beta", "p", "r"], parameters=truth)
    t = np.arange(0.0, 8.0, 0.02)
    da = np.where((t > 1.0) & (t < 2.0), 0.05, 0.0) - np.where((t > 2.0) & (t < 3.0), 0.05, 0.0)
    dr = np.where((t > 4.0) & (t < 5.0), 0.05, 0.0)
    sim = model.simulate(t, {"delta_a": da, "delta_r": dr}).to_flight_data()
    rng = np.random.default_rng(3)
    chans = {k: sim[k] + 1e-4 * rng.standard_normal(t.size) for k in ("beta", "p", "r")}
    return model, FlightData(t, {**chans, "delta_a": da, "delta_r": dr})


def test_a_record_in_degrees_for_a_model_in_radians_is_refused():
    model, record = _lateral_record()
    assert model.channel_units["beta"] == "rad"
    names = ["L_p", "L_delta_a", "N_r"]
    deg = FlightData(record.time, dict(record.channels), {"beta": "deg"}, {"source": "f.csv"})
    with pytest.raises(
        IdentificationError,
        match=r"f\.csv: channel 'beta' is stated in 'deg' .* 'rad' \(1 deg = 0\.0174533 rad\)",
    ):
        identify(model, deg, names)
    # a control in degrees is caught as well, a matching or unstated label passes
    deg_da = FlightData(record.time, dict(record.channels), {"delta_a": "deg"})
    with pytest.raises(IdentificationError, match=r"record 0: channel 'delta_a'"):
        identify(model, deg_da, names)
    rad = FlightData(record.time, dict(record.channels), {"beta": "rad", "p": "rad/s"})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # three parameters of a short record: not the point
        assert identify(model, rad, names).parameter_names == tuple(names)


def test_a_plain_model_declares_no_units_so_labels_are_not_judged(sp_model, sp_noisy):
    labelled = FlightData(sp_noisy.time, dict(sp_noisy.channels), {"alpha": "deg"})
    assert catalog.short_period() is not None and getattr(sp_model, "channel_units", None) is None
    assert identify(sp_model, labelled, ["M_alpha", "M_q", "M_delta"]).success


def _store_with_entry(root):
    from aeroid.pipeline import ResultStore
    from aeroid.pipeline.keys import canonical_json, sha256_hex
    from aeroid.pipeline.stages import CampaignReport

    store = ResultStore(root)
    key = sha256_hex(canonical_json({"n": 1}))
    assert store.commit(
        "campaign_report", key, CampaignReport("t", "x", ("a",), ("f",), (("a",),)), task={"n": 1}
    )
    return key


def _forget(root) -> None:
    from aeroid.pipeline.storage._backend import _CHECKED

    _CHECKED.clear()  # as a fresh process would


def test_a_local_store_that_lost_its_marker_is_repaired_by_verify_remove(tmp_path):
    from click.testing import CliRunner

    from aeroid.cli import main
    from aeroid.errors import StoreError
    from aeroid.pipeline import ResultStore

    root = tmp_path / "store"
    key = _store_with_entry(root)
    (root / "aeroid-store.json").unlink()  # emptied mid-run: the run's entries came back
    (root / ".tmp").mkdir(exist_ok=True)
    _forget(root)
    with pytest.raises(StoreError, match=r"lost its aeroid-store\.json .*verify --remove"):
        ResultStore(root, create=False)
    out = CliRunner().invoke(main, ["verify", "--store", str(root)])
    assert out.exit_code != 0 and "lost its" in out.output
    out = CliRunner().invoke(main, ["verify", "--remove", "--store", str(root)])
    assert out.exit_code == 0, out.output
    assert (root / "aeroid-store.json").is_file()
    _forget(root)
    assert [e.key for e in ResultStore(root, create=False).entries()] == [key]


def test_the_next_run_repairs_a_local_store_but_not_a_folder_of_other_files(tmp_path):
    from aeroid.errors import StoreError
    from aeroid.pipeline import ResultStore

    root = tmp_path / "store"
    key = _store_with_entry(root)
    (root / "aeroid-store.json").unlink()
    _forget(root)
    assert [e.key for e in ResultStore(root).entries()] == [key]  # create=True: the next run
    # a user's folder is not taken over, nor is a store with a stray file or a link
    for extra in ("notes.txt", "identify/readme.md", "link"):
        other = tmp_path / f"other-{extra.replace('/', '-')}"
        _store_with_entry(other)
        (other / "aeroid-store.json").unlink()
        target = other / extra
        target.parent.mkdir(exist_ok=True)
        if extra == "link":
            target.symlink_to(tmp_path, target_is_directory=True)
        else:
            target.write_text("mine")
        _forget(other)
        with pytest.raises(StoreError, match="is not empty and is not an aeroid store"):
            ResultStore(other)
        with pytest.raises(StoreError, match=r"not an aeroid store \(no aeroid-store.json\)"):
            ResultStore(other, create=False, repair=True)
    stages_only = tmp_path / "empty-stages"
    (stages_only / "identify").mkdir(parents=True)
    with pytest.raises(StoreError, match="not an aeroid store"):
        ResultStore(stages_only, create=False, repair=True)  # no entry: nothing to repair


def test_verify_remove_repairs_a_url_store_that_lost_its_marker():
    import uuid

    import fsspec

    from aeroid.errors import StoreError
    from aeroid.pipeline import ResultStore

    url = f"memory://aeroid-test-{uuid.uuid4().hex[:12]}/store"
    key = _store_with_entry(url)
    fs, base = fsspec.core.url_to_fs(url)
    fs.rm(f"{base}/aeroid-store.json")
    _forget(url)
    with pytest.raises(StoreError, match="not an aeroid store"):
        ResultStore(url, create=False)
    assert [e.key for e in ResultStore(url, create=False, repair=True).entries()] == [key]
    assert fs.exists(f"{base}/aeroid-store.json")


@pytest.mark.parametrize(
    "start",
    [
        {"Z_alpha": 1.5, "M_alpha": 21.1, "M_q": 2.9, "M_delta": 9.2},
        {"Z_alpha": -1.1, "M_alpha": 20.0, "M_q": 7.1, "M_delta": -5.7},
    ],
)
def test_a_fit_stalled_on_a_diverging_simulation_is_an_error(sp_model, sp_noisy, start):
    # from these unstable starts the iteration used to "converge" with M_delta in the
    # thousands, success=True, and numpy's and scipy's warnings leaking
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        with pytest.raises(
            IdentificationError, match=r"diverges from the record: 'alpha' off"
        ) as err:
            identify(sp_model, sp_noisy, start)
    text = str(err.value)
    assert "'q' off by" in text and "at the parameters {'Z_alpha': " in text
    # the same record from the catalogue's start is fitted
    assert identify(sp_model, sp_noisy, list(start)).success


def test_a_lateral_fit_from_an_unstable_start_is_refused_not_returned():
    model, record = _lateral_record()
    truth = dict(model.parameters)
    names = [n for n in truth if n.startswith(("L_", "N_"))]
    # roll and yaw damping of the wrong sign: the simulation runs away
    start = {n: (-v if n in ("L_p", "N_r") else v) for n, v in truth.items() if n in names}
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        with pytest.raises(IdentificationError, match=r"'lateral_linear' diverges from") as err:
            identify(model, record, start)
    assert "'p' off by" in str(err.value) and "'L_p': " in str(err.value)
    # from the truth's signs the same record is fitted to the truth
    fit = identify(
        model, record, {n: 0.5 * v for n, v in start.items()} | {"L_p": -4.0, "N_r": -0.75}
    )
    assert fit.success
    for n in names:
        assert fit.parameters[n] == pytest.approx(truth[n], rel=0.02, abs=0.02)


@pytest.mark.parametrize(("channel", "value"), [("V", 30.0), ("alpha", 0.05), ("theta", 0.02)])
def test_a_stuck_air_data_channel_is_refused_by_the_compatibility_check(channel, value):
    from _compat_flight import simulated_flight

    from aeroid import ChannelError, check_compatibility

    flight = simulated_flight(duration=10.0, rate=25.0)
    stuck = FlightData(flight.time, {**flight.channels, channel: np.full(flight.n_samples, value)})
    with pytest.raises(ChannelError, match=rf"channel '{channel}' \({channel}\): holds {value:g}"):
        check_compatibility(stuck, max_passes=1, n_draws=2)
    if channel != "alpha":
        return  # one full check is enough (seconds each)
    # left out of the fitted outputs, the rest of the record is checked
    outputs = [o for o in ("V", "alpha", "beta", "phi", "theta", "psi") if o != channel]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert check_compatibility(stuck, outputs=outputs, max_passes=1, n_draws=2) is not None


@pytest.mark.parametrize(
    ("text", "kwargs", "shown"),
    [
        (
            "time,q\n0,1\n0.1,AWS_SECRET=abc123xyz\n0.2,3\n",
            {},
            "non-numeric (20 characters of text)",
        ),
        ("AWS_SECRET=abc123xyz,q\n0,1\n0.1,2\n", {}, "2 columns (not listed"),
        ("AWS_SECRET=abc123xyz,q\n0,1\n0.1,2\n", {"time_column": "t"}, "2 columns (not listed"),
        ("time,AWS_SECRET=abc123xyz\n0,1\n0.1,2\n", {"channels": ["q"]}, "2 columns (not listed"),
        ("time,AWS_SECRET=abc123xyz,AWS_SECRET=abc123xyz\n0,1,1\n0.1,2,2\n", {}, "appear twice"),
    ],
)
def test_library_errors_quote_no_file_contents(tmp_path, text, kwargs, shown):
    # the pipeline's load stage reports these messages in `aeroid run` and the report
    path = tmp_path / "creds.csv"
    path.write_text(text)
    with pytest.raises((DataFormatError, KeyError)) as err:
        load_flight_test(path, **kwargs)
    message = str(err.value)
    assert "creds.csv" in message and shown in message
    assert "abc123" not in message and "AWS_SECRET" not in message


def test_a_malformed_number_is_still_quoted_and_names_still_listed(tmp_path):
    path = tmp_path / "f.csv"
    path.write_text("time,q\n0,1\n0.1,1.2.3\n")
    with pytest.raises(DataFormatError, match=r"row 3, column 'q': non-numeric \('1\.2\.3'\)"):
        load_flight_test(path)
    path.write_text("time,q\n0,1\n0.1,2\n")
    with pytest.raises(KeyError, match=r"columns: \['time', 'q'\]"):
        load_flight_test(path, channels=["r"])


def test_every_remote_protocol_gets_the_timeout(monkeypatch):
    import fsspec.core

    from aeroid.pipeline.storage import _objectstore

    seen: dict[str, dict] = {}

    def fake(url, **kwargs):
        seen[url.split("://")[0]] = kwargs
        return object(), url.split("://", 1)[1]

    monkeypatch.setattr(fsspec.core, "url_to_fs", fake)
    monkeypatch.setenv("AEROID_REMOTE_TIMEOUT", "2.5")
    for url in ("s3://b/c", "gs://b/c", "az://b/c", "abfs://b/c", "https://h/c"):
        _objectstore.url_to_fs(url)
    assert seen["s3"]["config_kwargs"]["read_timeout"] == 2.5
    assert seen["gs"]["timeout"] == 2.5
    assert seen["az"]["read_timeout"] == seen["abfs"]["connection_timeout"] == 3
    try:
        import aiohttp  # noqa: F401  (fsspec's HTTP needs it; without it there is no client)
    except ImportError:
        assert "client_kwargs" not in seen["https"]
    else:
        assert seen["https"]["client_kwargs"]["timeout"].total == 2.5


def test_an_http_server_that_stops_answering_fails_the_read(monkeypatch):
    import contextlib
    import socket
    import threading
    import time

    pytest.importorskip("aiohttp")
    from aeroid.pipeline.storage._objectstore import url_to_fs

    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(4)
    held: list[socket.socket] = []
    stop = threading.Event()

    def accept_and_stay_silent() -> None:
        server.settimeout(0.05)
        while not stop.is_set():
            with contextlib.suppress(OSError):
                held.append(server.accept()[0])

    thread = threading.Thread(target=accept_and_stay_silent, daemon=True)
    thread.start()
    monkeypatch.setenv("AEROID_REMOTE_TIMEOUT", "0.3")
    start = time.monotonic()
    try:
        fs, path = url_to_fs(f"http://127.0.0.1:{server.getsockname()[1]}/store/x")
        with pytest.raises(Exception) as err:  # fsspec wraps the timeout
            fs.cat_file(path)
    finally:
        stop.set()
        thread.join()
        for conn in held:
            conn.close()
        server.close()
    assert "timeout" in type(err.value).__name__.lower() + str(err.value).lower()
    assert time.monotonic() - start < 20


def test_workers_given_to_run_or_rerun_are_bounded_like_the_configs(tmp_path):
    import os

    from click.testing import CliRunner

    from aeroid.cli import main
    from aeroid.errors import ConfigError
    from aeroid.pipeline import run

    limit = 4 * (os.cpu_count() or 1)
    cfg = tmp_path / "c.yaml"
    cfg.write_text("model: short_period\nflights: [{simulated: {n_flights: 1}}]\n")
    with pytest.raises(ConfigError, match=rf"workers: {limit + 1} workers .* at most {limit}"):
        run(cfg, store=str(tmp_path / "s"), workers=limit + 1)
    assert not (tmp_path / "s").exists()  # refused before anything is made
    out = CliRunner().invoke(main, ["run", str(cfg), "--workers", str(10 * limit)])
    assert out.exit_code != 0 and f"at most {limit}" in out.output
    out = CliRunner().invoke(
        main, ["rerun", "--all", "--store", str(tmp_path), "--workers", str(10 * limit)]
    )
    assert out.exit_code != 0 and f"--workers: {10 * limit} workers" in out.output


def test_datasets_beyond_a_files_total_budget_are_not_read_and_say_so(tmp_path, monkeypatch):
    h5py = pytest.importorskip("h5py")
    import aeroid.io.logs as logs

    path = tmp_path / "many.h5"
    n = 1000
    with h5py.File(path, "w") as f:
        f["time"] = np.arange(n) * 0.01
        for i in range(5):
            f[f"c{i}"] = np.full(n, float(i))
    # time (8 kB) and two channels fit a 26 kB budget; the third does not
    monkeypatch.setattr(logs, "_MAX_FILE_BYTES", 3 * 8 * n + 2000)
    log = read_log(path)
    assert sorted(log.channels) == ["c0", "c1"]
    assert "one file may declare in all" in log.metadata["skipped"]["c2"]
    with pytest.raises(KeyError, match=r"many\.h5: channel 'c3' not read: the datasets"):
        load_flight_test(path, channels=["c0", "c1", "c3"])
    # the channels asked for are all that count: two of them fit
    assert list(load_flight_test(path, channels=["c0", "c3"]).channels) == ["c0", "c3"]
    monkeypatch.setattr(logs, "_MAX_FILE_BYTES", 4 << 30)
    assert len(read_log(path).channels) == 5


def test_a_channel_skipped_for_its_storage_names_why_when_asked_for(tmp_path):
    h5py = pytest.importorskip("h5py")
    path = tmp_path / "ext.h5"
    secret = tmp_path / "secret.bin"
    secret.write_bytes(bytes(80))
    with h5py.File(path, "w") as f:
        f["time"] = np.arange(10) * 0.1
        f["q"] = np.ones(10)
        f.create_dataset("leak", (10,), dtype="<f8", external=[(str(secret), 0, 80)])
    with (
        pytest.warns(UserWarning, match="allow_external_data"),
        pytest.raises(KeyError, match=r"ext\.h5: channel 'leak' is stored in an external"),
    ):
        load_flight_test(path, channels=["q", "leak"])


@pytest.mark.parametrize("sample_rate", [None, 10.0])
def test_a_log_clock_stepping_back_half_a_second_is_refused(tmp_path, sample_rate):
    h5py = pytest.importorskip("h5py")
    t = np.arange(0.0, 4.0, 0.1)
    t[20:] -= 0.7  # the clock steps back 0.7 s at 2 s
    path = tmp_path / "back.h5"
    with h5py.File(path, "w") as f:
        f["time"] = t
        f["q"] = np.sin(t)
    with pytest.raises(DataFormatError, match=r"back\.h5: .*(back|increasing)"):
        load_flight_test(path, channels=["q"], sample_rate=sample_rate)
    csv = tmp_path / "back.csv"
    csv.write_text(
        "time,q\n" + "\n".join(f"{a:.2f},{b}" for a, b in zip(t, np.sin(t), strict=True))
    )
    with pytest.raises(
        DataFormatError, match=r"back\.csv: time: not strictly increasing at index 20"
    ):
        load_flight_test(csv)
