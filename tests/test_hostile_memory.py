"""Issue 49, "Memory and hangs": sizes bounded before reading, what nobody asked for not
read, wide files in one pass. The limits are lowered so that each bomb stays small."""

from __future__ import annotations

import io
import struct
import zlib

import numpy as np
import pytest

import aeroid.io._table_files as table_files
from aeroid import load_flight_test
from aeroid.errors import ChannelError, DataFormatError

_LIMIT = 1 << 20  # the bound each test lowers the real one (1 GiB) to


@pytest.fixture
def small_limit(monkeypatch):
    monkeypatch.setattr(table_files, "_MAX_DECLARED_BYTES", _LIMIT)


def _mat_header() -> bytes:
    import scipy.io

    out = io.BytesIO()
    scipy.io.savemat(out, {"x": np.zeros(2)})
    return out.getvalue()[:128]


def _mat_variable(name: str, dims: tuple[int, int], payload: bytes) -> bytes:
    """One compressed double variable declaring `dims`, whatever `payload` holds."""
    flags = struct.pack("<IIII", 6, 8, 6, 0)  # miUINT32 array flags: class double
    shape = struct.pack("<II", 5, 8) + struct.pack("<ii", *dims)
    label = name.encode()
    assert len(label) <= 4
    tag_name = struct.pack("<HH", 1, len(label)) + label.ljust(4, b"\0")  # small element
    real = struct.pack("<II", 9, len(payload)) + payload + b"\0" * (-len(payload) % 8)
    body = flags + shape + tag_name + real
    inner = struct.pack("<II", 14, len(body)) + body
    packed = zlib.compress(inner, 9)
    return struct.pack("<II", 15, len(packed)) + packed


def _mat_file(path, variables: dict[str, tuple[tuple[int, int], bytes]]) -> None:
    path.write_bytes(
        _mat_header() + b"".join(_mat_variable(n, d, p) for n, (d, p) in variables.items())
    )


def _vector(values) -> tuple[tuple[int, int], bytes]:
    v = np.asarray(values, dtype="<f8")
    return (1, v.size), v.tobytes()


def test_the_hand_made_mat_file_reads_as_scipy_writes_it(tmp_path):
    path = tmp_path / "plain.mat"
    _mat_file(path, {"time": _vector(np.arange(5) * 0.1), "q": _vector(np.arange(5.0))})
    data = load_flight_test(path)
    np.testing.assert_array_equal(data["q"], np.arange(5.0))


def test_a_mat_variable_whose_size_tag_lies_is_refused_before_scipy_reads_it(tmp_path, small_limit):
    # declares 1x10 (80 bytes: the shape check passes) but carries 4 MiB of zeros,
    # a few kB compressed
    path = tmp_path / "lying.mat"
    _mat_file(
        path,
        {
            "time": _vector(np.arange(10) * 0.1),
            "q": ((1, 10), bytes(4 * _LIMIT)),
        },
    )
    assert path.stat().st_size < 20_000
    with pytest.raises(DataFormatError, match=r"lying\.mat: variable 'q' expands beyond the 1 MiB"):
        load_flight_test(path)


def test_mat_variables_each_under_the_bound_are_bounded_together(tmp_path, small_limit):
    n = _LIMIT // 8 // 3  # a third of the bound each
    path = tmp_path / "many.mat"
    _mat_file(
        path,
        {"time": _vector(np.arange(n) * 0.01), **{f"c{i}": _vector(np.zeros(n)) for i in range(4)}},
    )
    with pytest.raises(DataFormatError, match=r"many\.mat: variable 'c2' declares .* taking the"):
        load_flight_test(path)
    # two channels and the time fit: what is not asked for does not count
    assert sorted(load_flight_test(path, channels=["c0", "c3"]).channels) == ["c0", "c3"]


def test_an_unused_huge_mat_variable_beside_the_channel_is_not_read(tmp_path, small_limit):
    path = tmp_path / "beside.mat"
    _mat_file(
        path,
        {
            "time": _vector(np.arange(10) * 0.1),
            "q": _vector(np.sin(np.arange(10.0))),
            "huge": ((1, 10), bytes(4 * _LIMIT)),  # lies as well: not even inflated
        },
    )
    data = load_flight_test(path, channels={"q": "pitch_rate"})
    np.testing.assert_array_equal(data["pitch_rate"], np.sin(np.arange(10.0)))
    with pytest.raises(ChannelError, match=r"column 'r' not found; columns: \['time', 'q', 'huge'"):
        load_flight_test(path, channels=["r"])
    with pytest.raises(DataFormatError, match="variable 'huge' expands beyond"):
        load_flight_test(path)  # every column: the bomb is read, and refused


def test_a_parquet_bomb_is_refused_before_reading_and_an_unused_one_not_read(
    tmp_path, small_limit, monkeypatch
):
    pa = pytest.importorskip("pyarrow")
    pq = pytest.importorskip("pyarrow.parquet")
    n = 64
    table = pa.table(
        {
            "time": np.arange(n) * 0.1,
            "q": np.cos(np.arange(n)),
            # 64 strings of 64 kB: 4 MiB decoded, stored as one dictionary entry (its
            # stated uncompressed size is 64 kB) and a few kB on disk
            "blob": pa.array([b"A" * 65536] * n, type=pa.binary()),
        }
    )
    path = tmp_path / "bomb.parquet"
    pq.write_table(table, path, compression="zstd")
    assert path.stat().st_size < 50_000
    read_table = pq.read_table

    def guarded(source, columns=None, **kwargs):
        assert columns is not None and "blob" not in columns, "the bomb was read"
        return read_table(source, columns=columns, **kwargs)

    monkeypatch.setattr(pq, "read_table", guarded)
    with pytest.raises(DataFormatError, match=r"bomb\.parquet: column 'blob' is not numeric"):
        load_flight_test(path)
    data = load_flight_test(path, channels=["q"])
    np.testing.assert_array_equal(data["q"], np.cos(np.arange(n)))
    # numbers beyond the bound are refused from the declared sizes
    m = _LIMIT // 8
    pq.write_table(pa.table({"time": np.arange(m) * 0.1, "q": np.zeros(m)}), path)
    with pytest.raises(DataFormatError, match=r"declares .* \(131072 rows x 2 columns read\)"):
        load_flight_test(path)


def test_an_unused_huge_hdf5_dataset_and_its_groups_clock_are_not_read(tmp_path):
    h5py = pytest.importorskip("h5py")
    path = tmp_path / "beside.h5"
    with h5py.File(path, "w") as f:
        f["time"] = np.arange(50) * 0.1
        f["q"] = np.sin(np.arange(50))
        # 512 MiB declared each (under the per-dataset bound), nothing stored
        big = {"shape": (1 << 26,), "dtype": "<f8", "chunks": (1 << 16,), "compression": "gzip"}
        f.create_dataset("unused", **big)
        f.create_dataset("camera/time", **big)
        f.create_dataset("camera/frames", **big)
    assert path.stat().st_size < 100_000
    data = load_flight_test(path, channels=["q"])
    assert list(data.channels) == ["q"]
    # a near miss is still suggested from the datasets that were not read
    with pytest.raises(ChannelError, match=r"'camera\.frame' not found .*'camera\.frames'"):
        load_flight_test(path, channels=["camera.frame"])


def test_one_channel_of_a_200k_column_csv_is_read_alone(tmp_path):
    names = ["time", *(f"c{i}" for i in range(200_000))]
    path = tmp_path / "wide.csv"
    rows = [",".join([str(k), *(["0"] * (len(names) - 1))]) for k in range(3)]
    path.write_text(",".join(names) + "\n" + "\n".join(rows))
    data = load_flight_test(path, channels=["c199999"])
    assert list(data.channels) == ["c199999"] and data.n_samples == 3


def test_a_bad_cell_at_the_end_of_a_wide_csv_is_found_in_one_pass(tmp_path):
    # a column at a time took 69 s at 20,000 columns (quadratic); one pass takes ~1 s
    n = 50_000
    names = ["time", *(f"c{i}" for i in range(n))]
    rows = [",".join([str(k), *(["1.5"] * n)]) for k in range(4)]
    rows[3] = rows[3][: -len("1.5")] + "AWS_SECRET=abc123xyz"
    rows[2] = rows[2][: -len("1.5")] + "n/a"
    path = tmp_path / "wide.csv"
    path.write_text(",".join(names) + "\n" + "\n".join(rows))
    with pytest.raises(DataFormatError, match=rf"row 4, column 'c{n - 1}': non-numeric \('n/a'\)"):
        load_flight_test(path)
    rows[2] = rows[2][: -len("n/a")] + "1.5"
    path.write_text(",".join(names) + "\n" + "\n".join(rows))
    with pytest.raises(DataFormatError) as err:
        load_flight_test(path)
    assert f"row 5, column 'c{n - 1}': non-numeric (20 characters of text)" in str(err.value)
    assert "abc123" not in str(err.value)


@pytest.mark.parametrize("where", [(0, "q"), (5, "r")])
def test_a_narrow_csv_reports_the_earliest_bad_cell(tmp_path, where):
    row, column = where
    t = np.arange(20) * 0.1
    cells = {"time": [f"{x:.1f}" for x in t], "q": ["1"] * 20, "r": ["2"] * 20}
    cells[column][row] = "x"
    cells["r" if column == "q" else "q"][row + 3] = "y"
    path = tmp_path / "f.csv"
    path.write_text(
        "time,q,r\n"
        + "\n".join(",".join(cells[c][i] for c in ("time", "q", "r")) for i in range(20))
    )
    with pytest.raises(DataFormatError, match=rf"row {row + 2}, column '{column}': non-numeric"):
        load_flight_test(path)


def test_aeroid_status_ends_on_a_glob_through_a_symlink_loop(tmp_path):
    from click.testing import CliRunner

    from aeroid.cli import main

    loop = tmp_path / "loop"
    (loop / "a").mkdir(parents=True)
    t = np.arange(0, 2, 0.1)
    (loop / "a" / "f.csv").write_text(
        "time,alpha,q,elevator\n" + "\n".join(f"{x:.1f},0,0,0" for x in t)
    )
    (loop / "a" / "up").symlink_to("..", target_is_directory=True)
    (loop / "a" / "self").symlink_to(".", target_is_directory=True)
    cfg = tmp_path / "c.yaml"
    cfg.write_text("model: short_period\nflights: ['loop/**/*.csv']\n")
    out = CliRunner().invoke(main, ["status", str(cfg)])
    assert out.exit_code == 0, out.output
    assert "| f " in out.output and "0 stored, 5 missing" in out.output  # one flight, once


def test_the_config_check_names_hdf5_channels_without_reading_them(tmp_path, monkeypatch):
    h5py = pytest.importorskip("h5py")
    import aeroid.io.logs as logs
    from aeroid.pipeline.plans.checks import preflight

    n = 50
    with h5py.File(tmp_path / "f.h5", "w") as f:
        f["time"] = np.arange(n) * 0.1
        f["alpha"] = np.zeros(n)
        f["imu"] = np.zeros((n, 3))
        f["de"] = np.zeros(n)
        f["camera/time"] = np.arange(4 * n) * 0.025
        f["camera/frames"] = np.zeros((4 * n, 64))
    read: list[str] = []
    real = logs._hdf5_array

    def spy(ds, matlab):
        read.append(ds.name)
        return real(ds, matlab)

    monkeypatch.setattr(logs, "_hdf5_array", spy)
    cfg = tmp_path / "c.yaml"
    stage = "stages:\n  identify: {parameters: [M_q]}\n"
    cfg.write_text(
        "model: short_period\nflights: [{path: f.h5, channels: "
        "{alpha: alpha, q: 'imu[1]', elevator: de}}]\n" + stage
    )
    preflight(cfg)
    assert read == []  # named from the shapes alone
    cfg.write_text(
        "model: short_period\nflights: [{path: f.h5, channels: "
        "{alpha: alpha, q: 'imu[5]', elevator: de}}]\n" + stage
    )
    from aeroid.errors import ConfigError

    with pytest.raises(ConfigError, match=r"log channel 'imu\[5\]' not found"):
        preflight(cfg)
    # the loader reads what the flight maps, and nothing of the camera group
    data = load_flight_test(tmp_path / "f.h5", channels={"q": "imu[1]", "alpha": "alpha"})
    assert sorted(data.channels) == ["alpha", "q"]
    assert sorted(read) == ["/alpha", "/imu", "/time"]


def test_a_csv_whose_first_line_never_ends_is_refused_unread(tmp_path, monkeypatch):
    import aeroid.io._flight_csv as flight_csv

    monkeypatch.setattr(flight_csv, "_MAX_HEADER", 4096)
    path = tmp_path / "blob.csv"
    path.write_bytes(b"# exported\n" + b"A" * 10_000)  # one line, no newline: read whole before
    with pytest.raises(DataFormatError, match=r"blob\.csv: line 2 is longer than \d+ MiB"):
        load_flight_test(path)
    path.write_text("time,q\n0,1\n0.1,2\n")
    assert load_flight_test(path).n_samples == 2
