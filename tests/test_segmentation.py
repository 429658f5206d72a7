"""Manoeuvre windows: seeded recovery of known excitations, modes, markers and given times."""

from __future__ import annotations

import json

import numpy as np
import pytest
from _manoeuvre_record import NOISE, manoeuvre_record
from matplotlib.figure import Figure

import aeroid
from aeroid import (
    ChannelError,
    DataFormatError,
    FlightData,
    ManeuverWindow,
    SegmentationResult,
    resample,
    segment,
)
from aeroid.io._logtypes import FlightLog, LogChannel, LogEvent

INPUTS = ["elevator", "aileron", "rudder"]


def _edges(result: SegmentationResult) -> np.ndarray:
    return np.array([(w.t0, w.t1) for w in result.windows]).reshape(-1, 2)


def _edge_errors(result: SegmentationResult, truth, margin=(1.0, 1.0)) -> np.ndarray:
    return np.array(
        [
            (w.t0 - (a - margin[0]), w.t1 - (b + margin[1]))
            for w, (a, b) in zip(result.windows, truth, strict=True)
        ]
    )


def test_automatic_segmentation_finds_all_five_manoeuvres_within_half_a_second():
    # doublets, a 3-2-1-1, sweeps on one input and a doublet pair on two, with
    # noise and drifting trim; truth = excitation start - margin, end + margin
    worst = 0.0
    for seed in range(20):
        data, truth = manoeuvre_record(seed)
        result = segment(data, inputs=INPUTS)
        assert len(result.windows) == 5, (seed, result.summary())
        worst = max(worst, float(np.abs(_edge_errors(result, truth)).max()))
        assert result.windows[3].reason == "excitation in aileron, rudder"
        assert result.windows[0].reason == "excitation in elevator"
    assert worst <= 0.5


def test_the_noise_floor_is_the_inputs_noise():
    # 1.4826 x MAD of about 8000 quiet samples: relative standard error about 1.2 %
    data, _ = manoeuvre_record(7)
    result = segment(data, inputs=INPUTS)
    for trace in result.traces:
        assert trace.floor == pytest.approx(NOISE[trace.name], rel=0.05)
        assert trace.level == pytest.approx(5.0 * trace.floor)
        assert trace.trim is not None and trace.energy is not None
    # giving the floor instead of estimating it finds the same windows
    given = segment(data, inputs=INPUTS, noise_floor=dict(NOISE))
    np.testing.assert_allclose(_edges(given), _edges(result))


def test_noise_and_drifting_trim_alone_give_no_window():
    for seed in range(10):
        rng = np.random.default_rng(100 + seed)
        t = np.arange(0, 300, 0.02)
        drift = 0.02 * np.sin(2 * np.pi * t / 250 + rng.uniform(0, 6)) + 1e-4 * t
        data = FlightData(t, {"elevator": drift + 0.002 * rng.standard_normal(t.size)})
        assert segment(data, inputs=["elevator"]).windows == ()


def test_a_noise_free_input_on_a_drifting_trim():
    # simulated data: no noise to set a floor, a trim that ramps or bends
    t = np.arange(0, 60, 0.02)
    doublet = 0.1 * ((t >= 20) & (t < 21)) - 0.1 * ((t >= 21) & (t < 22))
    for trim in (0.03 + 0 * t, 0.03 + 0.001 * t, 0.01 * np.sin(2 * np.pi * t / 100)):
        result = segment(FlightData(t, {"u": doublet + trim}), inputs=["u"])
        np.testing.assert_allclose(_edges(result), [(19.0, 22.98)], atol=1e-9)


def test_a_noise_free_input_busy_with_manoeuvres_and_a_flickering_one():
    # three doublets fill a fifth of a noise-free record: the floor was the whole
    # record's RMS (the doublets' own), so none cleared five floors; a quantised input
    # that flickers by a step on 40 % of its samples met the same fallback
    t = np.arange(0, 30, 0.02)
    u = np.zeros_like(t)
    for start in (1.0, 11.0, 21.0):
        u += 0.05 * ((t >= start) & (t < start + 1)) - 0.05 * ((t >= start + 1) & (t < start + 2))
    result = segment(FlightData(t, {"u": u}), inputs=["u"], margin=0.0)
    np.testing.assert_allclose(
        _edges(result), [(1.0, 2.98), (11.0, 12.98), (21.0, 22.98)], atol=1e-9
    )
    t = np.arange(0, 60, 0.02)
    u = np.zeros_like(t)
    for start in (10.0, 35.0):
        u += 0.05 * ((t >= start) & (t < start + 1)) - 0.05 * ((t >= start + 1) & (t < start + 2))
    flicker = 0.001 * np.random.default_rng(1).choice([-1, 0, 0, 0, 1], size=t.size)
    result = segment(FlightData(t, {"u": u + flicker}), inputs=["u"], margin=0.0)
    np.testing.assert_allclose(_edges(result), [(10.0, 11.98), (35.0, 36.98)], atol=1e-9)


def test_a_one_second_doublet_is_not_shorter_than_one_second():
    # 50 samples at 50 Hz last 1 s; first to last sample is 0.98 s, which the default
    # min_duration of 1 s dropped without a word
    t = np.arange(0, 40, 0.02)
    u = 0.05 * ((t >= 20) & (t < 20.5)) - 0.05 * ((t >= 20.5) & (t < 21.0))
    u = u + 1e-3 * np.random.default_rng(0).standard_normal(t.size)
    result = segment(FlightData(t, {"u": u}), inputs=["u"], margin=0.0)
    np.testing.assert_allclose(_edges(result), [(20.0, 20.98)], atol=1e-9)
    # a run one sample shorter than the minimum still is
    short = segment(FlightData(t, {"u": u}), inputs=["u"], margin=0.0, min_duration=1.02)
    assert short.windows == ()


def _pulses(t: np.ndarray, spans, amplitude: float = 1.0) -> np.ndarray:
    x = np.zeros_like(t)
    for a, b in spans:
        x[(t >= a) & (t < b)] = amplitude
    return x


def test_merge_drop_margin_and_clip():
    rng = np.random.default_rng(5)
    t = np.arange(0, 60, 0.02)
    # near the start (margin clipped), two pulses 1.2 s apart (merged), a blip (dropped)
    spans = [(0.3, 2.0), (20.0, 22.0), (23.2, 25.0), (40.0, 40.4), (57.0, 59.5)]
    x = _pulses(t, spans) + 0.01 * rng.standard_normal(t.size)
    result = segment(FlightData(t, {"u": x}), inputs=["u"], margin=(1.0, 0.5))
    want = [(0.0, 2.5), (19.0, 25.5), (56.0, 59.98)]
    np.testing.assert_allclose(_edges(result), want, atol=0.03)
    # a larger min_duration drops the first pulse; merge_gap=0 keeps the pair apart
    result = segment(
        FlightData(t, {"u": x}), inputs=["u"], min_duration=1.75, merge_gap=0.0, margin=0
    )
    want = [(20.0, 21.98), (23.2, 24.98), (57.0, 59.48)]
    np.testing.assert_allclose(_edges(result), want, atol=0.03)
    assert result.settings["merge_gap"] == 0.0
    json.dumps(dict(result.settings))


def test_a_log_at_several_rates_segments_channel_by_channel():
    data, truth = manoeuvre_record(11)
    keep = slice(None, None, 4)  # aileron at 12.5 Hz, the others at 50 Hz
    log = FlightLog(
        {
            "elevator": LogChannel("elevator", data.time, data["elevator"], "rad"),
            "aileron": LogChannel("aileron", data.time[keep], data["aileron"][keep], "rad"),
            "rudder": LogChannel("rudder", data.time, data["rudder"], "rad"),
        }
    )
    result = segment(log, inputs=INPUTS)
    assert len(result) == 5
    assert np.abs(_edge_errors(result, truth)).max() <= 0.5
    assert result.extent == (0.0, 200.0)


def test_given_windows_are_used_as_they_are_and_cut_flights():
    data, _ = manoeuvre_record(0)
    result = segment(data, windows=[(30, 40, "cruise"), (10.0, 20.0)], inputs=["elevator"])
    assert result.way == "time"
    assert result.windows == (ManeuverWindow(10.0, 20.0, "given"), ManeuverWindow(30, 40, "cruise"))
    flights = result.flights(data)
    assert [f.time[0] for f in flights] == [10.0, 30.0]
    assert flights[1].metadata["window"] == [30.0, 40.0]
    assert flights[1].metadata["reason"] == "cruise"
    assert flights[1].metadata["source"] == "seed 0"
    assert flights[1].units["elevator"] == "rad"
    with pytest.raises(DataFormatError, match="outside the record"):
        segment(data, windows=[(300, 400)])
    with pytest.raises(DataFormatError, match="need finite t1 > t0"):
        segment(data, windows=[(5, 5)])
    with pytest.raises(DataFormatError, match="expected FlightData"):
        result.flights({"time": [0, 1]})


def _sysid_log() -> FlightLog:
    t = np.arange(0, 100, 0.01)
    nav = np.select([t < 20, t < 35, t < 60, t < 72], [2.0, 14.0, 2.0, 14.0], 4.0)
    events = [
        LogEvent(0.0, "mode", "POSCTL"),
        LogEvent(20.0, "mode", "SYSID"),
        LogEvent(35.0, "mode", "POSCTL"),
        LogEvent(60.0, "mode", "SYSID"),
        LogEvent(72.0, "mode", "AUTO.RTL"),
        LogEvent(40.0, "message", "sweep start"),
        LogEvent(52.0, "message", "sweep end"),
        LogEvent(80.0, "message", "sweep start"),
    ]
    channels = {
        "status.nav_state": LogChannel("status.nav_state", t, nav),
        "rc.pitch": LogChannel("rc.pitch", t, np.sin(t), "-"),
    }
    return FlightLog(channels, tuple(events), {"source": "sysid.ulg"})


def test_windows_from_the_mode_by_event_or_by_channel():
    log = _sysid_log()
    by_event = segment(log, mode="SYSID", margin=0.5)
    assert by_event.way == "mode"
    assert [(w.t0, w.t1) for w in by_event] == [(19.5, 35.5), (59.5, 72.5)]
    assert by_event.windows[0].reason == "mode == 'SYSID'"
    by_channel = segment(log, mode=("status.nav_state", 14), margin=0)
    np.testing.assert_allclose(_edges(by_channel), [(20.0, 34.99), (60.0, 71.99)])
    assert by_channel.traces[0].name == "status.nav_state"
    # after resampling (the mode held, the events kept), the record segments alike
    data = resample(
        log,
        {"nav": "status.nav_state", "pitch": "rc.pitch"},
        rate=50,
        method={"nav": "hold"},
    )
    again = segment(data, mode="SYSID", margin=0.5)
    assert [(w.t0, w.t1) for w in again] == [(19.5, 35.5), (59.5, 72.5)]
    by_value = segment(data, mode=("nav", "14"), margin=0)
    np.testing.assert_allclose(_edges(by_value), [(20.0, 34.98), (60.0, 71.98)])
    flights = again.flights(data)
    assert len(flights) == 2 and flights[0].metadata["reason"] == "mode == 'SYSID'"


def test_a_loaders_mode_event_matches_by_name_or_number():
    """The log readers write "SYSTEMID (mode 25)" (ArduPilot) and "MANUAL (nav_state 0)"
    (PX4): `mode=25`, `"25"` or `"SYSTEMID"` found nothing."""
    t = np.arange(0, 10, 0.01)
    events = (
        LogEvent(0.0, "mode", "STABILIZE (mode 0)"),
        LogEvent(2.0, "mode", "SYSTEMID (mode 25)"),
        LogEvent(5.0, "mode", "STABILIZE (mode 0)"),
        LogEvent(7.0, "mode", "MANUAL (nav_state 0)"),
    )
    log = FlightLog({"rc.pitch": LogChannel("rc.pitch", t, np.sin(t), "-")}, events, {})
    for wanted in (25, "25", "SYSTEMID", "SYSTEMID (mode 25)"):
        assert [(w.t0, w.t1) for w in segment(log, mode=wanted, margin=0)] == [(2.0, 5.0)]
    manual = segment(log, mode="MANUAL", margin=0)
    assert [(w.t0, w.t1) for w in manual] == [(7.0, 9.99)]
    # a number matches the number in brackets only, not another mode's text
    assert [(w.t0, w.t1) for w in segment(log, mode=0, margin=0)] == [
        (0.0, 2.0),
        (5.0, 9.99),
    ]


def test_windows_between_event_markers():
    log = _sysid_log()
    result = segment(log, events=("sweep start", "sweep end"), margin=(1.0, 2.0))
    np.testing.assert_allclose(_edges(result), [(39.0, 54.0), (79.0, 99.99)])
    assert "open at the end" in result.windows[1].reason
    pair = segment(log, events=(("message", "sweep start"), ("message", "sweep end")), margin=0)
    assert (pair.windows[0].t0, pair.windows[0].t1) == (40.0, 52.0)
    with pytest.raises(DataFormatError, match=r"no event matches.*did you mean \['sweep start'"):
        segment(log, events=("sweep strat", "sweep end"))


def test_errors_name_what_is_wrong():
    log = _sysid_log()
    with pytest.raises(ChannelError, match=r"input 'rc.pich' not found.*'rc.pitch'"):
        segment(log, inputs=["rc.pich"])
    with pytest.raises(ChannelError, match=r"'nav_stat'.*'status.nav_state'"):
        segment(log, mode=("nav_stat", 14))
    with pytest.raises(DataFormatError, match=r"choose one of.*\['windows', 'mode'\]"):
        segment(log, windows=[(1, 2)], mode="SYSID")
    with pytest.raises(DataFormatError, match="give inputs="):
        segment(log)
    with pytest.raises(DataFormatError, match="no 'mode' events"):
        segment(FlightLog(log.channels), mode="SYSID")
    with pytest.raises(DataFormatError, match="margin before"):
        segment(log, mode="SYSID", margin=(-1, 0))
    with pytest.raises(DataFormatError, match="threshold"):
        segment(log, inputs=["rc.pitch"], threshold=0)
    with pytest.raises(DataFormatError, match=r"noise_floor: \['x'\]"):
        segment(log, inputs=["rc.pitch"], noise_floor={"x": 1.0})
    with pytest.raises(DataFormatError, match="too few"):
        segment({"u": ([0, 1, 2], [0, 1, 0])}, inputs=["u"])
    odd = FlightData([0.0, 1.0, 2.0], {"u": [0.0, 0.0, 0.0]}, metadata={"events": [[1.0]]})
    with pytest.raises(DataFormatError, match=r"metadata\['events'\]: expected \[time, kind"):
        segment(odd, mode="SYSID")
    with pytest.raises(TypeError, match="frozen record"):
        segment(log, mode="SYSID").settings["threshold"] = 1.0


def test_window_lengths_and_inputs_are_checked_before_any_work():
    t = np.arange(0, 120, 0.02)
    de = 1e-3 * np.random.default_rng(0).standard_normal(t.size)
    de[(t > 30) & (t < 35)] += 0.1
    data = FlightData(t, {"de": de})
    for width in (70.0, 200.0, 1e9):
        with pytest.raises(DataFormatError, match=r"energy_window: .* too long for input 'de'"):
            segment(data, inputs=["de"], energy_window=width)
    # a trim median longer than the record is the whole record's median: same windows
    base = segment(data, inputs=["de"])
    for width in (1000.0, 1e9):
        long = segment(data, inputs=["de"], trim_window=width)
        np.testing.assert_array_equal(_edges(long), _edges(base))
    with pytest.raises(DataFormatError, match="inputs: expected channel names, got 5"):
        segment(data, inputs=5)
    with pytest.raises(DataFormatError, match="channel 'x': expected a LogChannel"):
        segment({"de": (t, de), "x": 5}, inputs=["de"])
    with pytest.raises(DataFormatError, match=r"threshold: .*multiple of the noise floor.*'a'"):
        segment(data, inputs=["de"], threshold="a")
    with pytest.raises(DataFormatError, match=r"noise_floor for 'de': .*input's units.*'a'"):
        segment(data, inputs=["de"], noise_floor="a")


def test_summary_and_plot():
    data, _ = manoeuvre_record(3)
    result = segment(data, inputs=INPUTS)
    text = result.summary()
    assert text.startswith("5 window(s) by excitation in [0, 200] s")
    assert "| # | t0 [s]" in text and "| elevator [rad] |" in text
    fig = result.plot()
    assert isinstance(fig, Figure) and len(fig.axes) == 3
    assert fig.axes[0].get_ylabel() == "elevator [rad]"
    assert fig.axes[-1].get_xlabel() == "time [s]"
    assert len(fig.axes[0].patches) == 5  # one shaded span per window
    bare = segment(data, windows=[(1, 2)]).plot()
    assert len(bare.axes) == 1
    assert aeroid.segment is segment and aeroid.SegmentationResult is SegmentationResult


def test_a_given_window_reaching_past_the_record_is_clipped_to_it():
    t = np.arange(500) * 0.02
    data = aeroid.FlightData(t, {"u": np.zeros_like(t)})
    (window,) = aeroid.segment(data, windows=[(-5.0, 2.0)]).windows
    assert (window.t0, window.t1, window.reason) == (0.0, 2.0, "given")
