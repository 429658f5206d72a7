"""Issue 49, "Security": a flight file reads nothing outside itself unless allowed, the
network is opt-in and located at its key, and no error quotes what a file holds."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from aeroid import load_flight_test, read_log
from aeroid.errors import ChannelError, ConfigError, DataFormatError
from aeroid.pipeline.plans.config import load_config

h5py = pytest.importorskip("h5py")

_SECRET = np.arange(16, dtype="<f8") * 1.25  # what a hostile file points at


def _matlab_73(tmp_path, *, virtual: bool):
    """A MATLAB v7.3 file (HDF5 behind MATLAB's 512-byte text header) whose 'leak'
    dataset lives in another file."""
    secret = tmp_path / "secret.bin"
    secret.write_bytes(_SECRET.tobytes())
    path = tmp_path / "flight.mat"
    with h5py.File(path, "w", userblock_size=512) as f:
        f["time"] = np.arange(16) * 0.1
        f["q"] = np.ones(16)
        if virtual:
            other = tmp_path / "other.h5"
            with h5py.File(other, "w") as g:
                g["data"] = _SECRET
            layout = h5py.VirtualLayout(shape=(16,), dtype="<f8")
            layout[:] = h5py.VirtualSource(str(other), "data", shape=(16,))
            f.create_virtual_dataset("leak", layout)
        else:
            f.create_dataset("leak", (16,), dtype="<f8", external=[(str(secret), 0, 128)])
        for name in ("time", "q", "leak"):
            f[name].attrs["MATLAB_class"] = np.bytes_(b"double")
    header = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Sat Dec  5 00:00:00 2026"
    with open(path, "r+b") as fh:
        fh.write(header.ljust(116) + bytes(8) + b"\x00\x02IM")
    return path


@pytest.mark.parametrize("virtual", [False, True])
def test_a_matlab_73_file_reads_no_other_file_unless_allowed(tmp_path, virtual):
    path = _matlab_73(tmp_path, virtual=virtual)
    with pytest.warns(UserWarning, match="allow_external_data"):
        log = read_log(path)
    assert log.metadata["format"] == "matlab"
    assert "leak" not in log and "q" in log
    with (
        pytest.warns(UserWarning),
        pytest.raises(ChannelError, match=r"flight\.mat: channel 'leak'"),
    ):
        load_flight_test(path, channels=["q", "leak"])
    # asked for the other channel only, the outside dataset is not even looked at
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert list(load_flight_test(path, channels=["q"]).channels) == ["q"]
    allowed = read_log(path, allow_external_data=True)
    np.testing.assert_array_equal(allowed.channels["leak"].values, _SECRET)


def _config(tmp_path, extra: str):
    (tmp_path / "a.csv").write_text("time,q\n0,1\n0.1,2\n")
    cfg = tmp_path / "c.yaml"
    cfg.write_text("model: short_period\nflights: [a.csv]\nname: secret-campaign\n" + extra)
    return cfg


@pytest.mark.parametrize(
    ("extra", "located"),
    [
        ("scheduler: tcp://10.1.2.3:8786\n", "c.yaml: scheduler: tcp://10.1.2.3:8786 is another"),
        ("store: s3://bucket/x\n", "c.yaml: store: s3://bucket/x sends flight data"),
        ("store: memory://x\n", "c.yaml: store: memory:// lives in this process"),
    ],
)
def test_network_refusals_name_their_key_and_quote_no_other(tmp_path, extra, located):
    with pytest.raises(ConfigError) as err:
        load_config(_config(tmp_path, extra))
    text = str(err.value)
    assert located in text
    assert "(top level)" not in text and "secret-campaign" not in text


def test_a_tcp_scheduler_on_this_machine_or_opted_in_is_taken(tmp_path):
    assert load_config(_config(tmp_path, "scheduler: tcp://127.0.0.1:8786\n")).scheduler
    cfg = load_config(_config(tmp_path, "scheduler: tcp://10.1.2.3:1\nallow_network: true\n"))
    assert cfg.allow_network


@pytest.mark.parametrize("columns", [3, 2_000])  # pyarrow's locator and the wide one
def test_a_secret_in_a_cell_is_not_quoted_by_either_locator(tmp_path, columns):
    names = ["time", *(f"c{i}" for i in range(columns))]
    rows = [",".join([f"{k * 0.1:.1f}", *(["0"] * columns)]) for k in range(4)]
    rows[2] = rows[2][: -len("0")] + "password=hunter2-AKIA"
    path = tmp_path / "creds.csv"
    path.write_text(",".join(names) + "\n" + "\n".join(rows))
    with pytest.raises(DataFormatError) as err:
        load_flight_test(path)
    text = str(err.value)
    assert f"row 4, column 'c{columns - 1}': non-numeric (21 characters of text)" in text
    assert "hunter2" not in text and "password" not in text


def test_a_text_file_named_as_a_flight_is_not_quoted_by_the_config_check(tmp_path):
    from aeroid.pipeline.plans.checks import preflight

    (tmp_path / "passwd.txt").write_text("root:x:0:0:root:/root:/bin/bash\nAWS_KEY=wJalrXUtnFEMI\n")
    cfg = tmp_path / "c.yaml"
    cfg.write_text(
        "model: short_period\nflights: [passwd.txt]\nstages:\n  identify: {parameters: [M_q]}\n"
    )
    with pytest.raises(ConfigError) as err:
        preflight(cfg)
    text = str(err.value)
    assert "passwd.txt" in text
    assert "root:" not in text and "wJalr" not in text and "AWS_KEY" not in text
