"""The pre-flight check refuses the loader options a flight's file cannot honour."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from aeroid.errors import ConfigError, DataFormatError
from aeroid.io.channel_map import load_mapped
from aeroid.io.data import FlightData
from aeroid.io.quality import check_data_quality
from aeroid.pipeline.plans.checks import preflight

T = np.arange(0.0, 2.0, 0.02)


def _flight(tmp: Path, units: dict[str, str] | None = None) -> Path:
    data = FlightData(
        T, {"alpha": np.sin(T), "q": np.cos(T), "elevator": np.sin(3 * T)}, units or {}
    )
    return data.to_csv(tmp / "f.csv")


def _config(tmp: Path, flights: str, stages: str = "identify: {parameters: [M_q]}") -> Path:
    p = tmp / "camp.yaml"
    p.write_text(f"model: short_period\nflights: {flights}\nstore: st\nstages:\n  {stages}\n")
    return p


def _refused(cfg: Path) -> str:
    with pytest.raises(ConfigError) as err:
        preflight(cfg)
    return str(err.value)


def test_a_mistyped_channel_in_a_plain_map_is_refused_by_name(tmp_path: Path) -> None:
    _flight(tmp_path)
    # aoa_deg is no column: read {column: name}, the map would rename alpha away
    cfg = _config(tmp_path, "[{path: f.csv, channels: {alpha: aoa_deg, q: q, elevator: elevator}}]")
    text = _refused(cfg)
    assert "flights[0].path: f.csv: channels: 'aoa_deg' is neither a column" in text
    assert "renames the column 'alpha'" in text
    # a column renamed to the model's name is what {column: name} is for
    FlightData(T, {"alpha": T, "q": T, "de": T}).to_csv(tmp_path / "g.csv")
    preflight(_config(tmp_path, "[{path: g.csv, channels: {alpha: alpha, q: q, de: elevator}}]"))


def test_a_map_unit_contradicting_the_files_is_refused_with_its_key(tmp_path: Path) -> None:
    _flight(tmp_path, {"alpha": "rad", "q": "rad/s"})
    entry = "{alpha: {channel: alpha, unit: deg}, q: q, elevator: elevator}"
    text = _refused(_config(tmp_path, f"[{{path: f.csv, channels: {entry}}}]"))
    assert "flights[0].channels.alpha.unit: f.csv: unit 'deg' contradicts the unit 'rad'" in text
    # the same unit as the file's converts nothing and passes
    preflight(_config(tmp_path, f"[{{path: f.csv, channels: {entry.replace('deg', 'rad')}}}]"))


@pytest.mark.parametrize("key", ["sample_rate: 10", "max_gap: 1"])
def test_log_options_on_a_table_are_refused_with_their_key(tmp_path: Path, key: str) -> None:
    _flight(tmp_path)
    text = _refused(_config(tmp_path, f"[{{path: f.csv, {key}}}]"))
    name = key.split(":")[0]
    assert f"flights[0].{name}: f.csv: {name} applies to flight logs" in text


def test_load_mapped_refuses_sample_rate_on_a_table(tmp_path: Path) -> None:
    p = _flight(tmp_path)
    with pytest.raises(DataFormatError, match="sample_rate, max_gap, t0 and t1 apply to flight"):
        load_mapped(p, {"a": "alpha"}, sample_rate=10, window=[0.5, 1.5])
    assert load_mapped(p, {"a": "alpha"}, window=[0.5, 1.5]).n_samples == 51


def test_dropout_factor_one_is_refused_by_the_config_check(tmp_path: Path) -> None:
    _flight(tmp_path)
    cfg = _config(
        tmp_path,
        "[f.csv]",
        "load: {quality: {dropout_factor: 1}}\n  identify: {parameters: [M_q]}",
    )
    text = _refused(cfg)
    assert "stages.load.quality.dropout_factor: Input should be greater than 1" in text
    assert "quality.bool" not in text


def test_a_bad_quality_key_is_the_one_error(tmp_path: Path) -> None:
    _flight(tmp_path)
    cfg = _config(
        tmp_path, "[f.csv]", "load: {quality: {jitter_limt: 0.05}}\n  identify: {parameters: [M_q]}"
    )
    text = _refused(cfg)
    assert "stages.load.quality.jitter_limt: unknown key" in text
    assert len(text.strip().splitlines()) == 1, text


@pytest.mark.parametrize(
    ("limit", "value", "interval"),
    [
        ("dropout_factor", 1.0, r"\(1, inf\)"),
        ("alias_band", 0.0, r"\(0, 1\)"),
        ("alias_band", 1.5, r"\(0, 1\)"),
        ("alias_limit", 2.0, r"\[0, 1\]"),
        ("jitter_limit", -1.0, r"\[0, inf\)"),
    ],
)
def test_the_quality_limits_state_their_interval(limit: str, value: float, interval: str) -> None:
    data = FlightData(T, {"x": np.sin(T)})
    with pytest.raises(DataFormatError, match=rf"{limit}: expected a number in {interval}, got"):
        check_data_quality(data, **{limit: value})
