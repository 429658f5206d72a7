"""Prediction of a manoeuvre not used in the fit: the identified model flown on held-out inputs.

Klein & Morelli (ch. 12) and Tischler (ch. 15) check an identified model by
simulating it, parameters fixed, with the inputs of data it was not fitted
to, and comparing with what was measured there. `validate` does this for a
held-out window of its record or for a second record, starting from that
data's measured state, or (Tischler's time-domain verification) from an
initial state and one reference shift per output fitted to the held-out data
with everything the model holds fixed: another manoeuvre flies from another
trim, and its first sample is as noisy as the rest.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import partial
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._checks import time_label
from .._records import FrozenState, fmt, fmt_fixed, frozen_array, markdown_table
from .._stats import spread_over_noise
from .._threads import CALLER_STACKLEVEL
from ..errors import IdentifiabilityWarning, IdentificationError
from ..io.data import FlightData, measured_start, plain
from ..models.model import simulator_outputs

FloatArray = NDArray[np.float64]

# How a prediction starts (see `validate`'s ``holdout_start``).
STARTS = ("measured", "estimated")
# Fewer held-out samples than this say nothing about a model's dynamics.
MIN_HOLDOUT_SAMPLES = 10
# total RMS over noise RMS at which the response's variance equals the noise's
_EXCITED = math.sqrt(2.0)


@dataclass(frozen=True, eq=False)
class PredictionMetrics(FrozenState):
    """Fit of one output predicted on held-out data.

    Attributes
    ----------
    rmse : float
        Root-mean-square prediction error (measured minus predicted).
    theil_u : float
        Theil's inequality coefficient,
        ``rms(e) / (rms(y) + rms(y_hat))``: 0 for a perfect prediction, 1 for
        none; below about 0.3 the textbooks call a prediction good.
    r_squared : float
        ``1 - sum e^2 / sum (y - mean(y))^2``.
    fit : float
        Normalised fit in percent, ``100 (1 - |e| / |y - mean(y)|)``.
    """

    rmse: float
    theil_u: float
    r_squared: float
    fit: float


@dataclass(frozen=True, eq=False)
class PredictionResult(FrozenState):
    """The identified model's prediction of held-out data.

    Attributes
    ----------
    metrics : mapping of str to PredictionMetrics
    time : ndarray, shape (n_t,)
    measured, predicted : ndarray, shape (n_t, n_y)
    output_names : tuple of str
    source : str
        What was held out: ``"window [t0, t1] s"`` of the validated record, or
        ``"second record"``.
    units : mapping of str to str
    in_fit : bool
        True when the held-out window lies in a record the parameters were
        fitted to: then the prediction is no independent check.
    response_to_noise : mapping of str to float
        Per output, the measured output's RMS about its mean over its noise RMS,
        estimated model-free from first differences (``std(diff y) / sqrt 2``,
        exact for white noise on a response slow against the sample rate).
        Below sqrt 2 on every output (the response's variance below the
        noise's) the held-out data holds no manoeuvre and its metrics measure
        noise: a warning says so.
    """

    metrics: Mapping[str, PredictionMetrics]
    time: FloatArray
    measured: FloatArray
    predicted: FloatArray
    output_names: tuple[str, ...]
    source: str
    units: Mapping[str, str] = field(default_factory=dict)
    in_fit: bool = False
    response_to_noise: Mapping[str, float] = field(default_factory=dict)
    start: str = "measured"
    initial_state: Mapping[str, float] = field(default_factory=dict)
    shifts: Mapping[str, float] = field(default_factory=dict)

    @property
    def excited(self) -> bool:
        """False when no output's measured response stands out of its noise."""
        ratios = self.response_to_noise.values()
        return not ratios or any(v >= _EXCITED for v in ratios)

    def __post_init__(self) -> None:
        object.__setattr__(self, "metrics", MappingProxyType(dict(self.metrics)))
        object.__setattr__(
            self, "response_to_noise", MappingProxyType(dict(self.response_to_noise))
        )
        for name in ("time", "measured", "predicted"):
            object.__setattr__(self, name, frozen_array(getattr(self, name)))
        object.__setattr__(self, "output_names", tuple(self.output_names))
        object.__setattr__(self, "units", MappingProxyType(dict(self.units)))
        for name in ("initial_state", "shifts"):
            object.__setattr__(self, name, MappingProxyType(dict(getattr(self, name))))

    def plot(self, **kwargs: Any) -> Any:
        """Measured vs predicted outputs on the held-out data. Returns a matplotlib Figure."""
        from ..reports.plotting import plot_prediction

        return plot_prediction(self, **kwargs)

    def summary(self) -> str:
        """Markdown table of the per-output prediction metrics."""
        rows = [
            (
                n,
                fmt(m.rmse),
                fmt_fixed(m.theil_u, 3),
                fmt_fixed(m.r_squared, 3),
                fmt_fixed(m.fit, 1),
            )
            for n, m in self.metrics.items()
        ]
        caveat = (
            " **This window was also used in the fit: the prediction is no independent check.**"
            if self.in_fit
            else ""
        )
        if not self.excited:
            caveat += (
                " **Not excited: no output's measured response stands out of its noise; "
                "the metrics measure noise.**"
            )
        start = (
            "initial state and output shifts fitted to it"
            if self.start == "estimated"
            else "start from its measured state"
        )
        return (
            f"Prediction of held-out data ({self.source}, {self.time.size} samples), "
            f"parameters fixed, {start}.{caveat}\n\n"
            + markdown_table(("output", "prediction RMSE", "Theil U", "R^2", "fit %"), rows)
        )


def prediction_metrics(y: FloatArray, y_hat: FloatArray) -> PredictionMetrics:
    """RMSE, Theil U, R^2 and fit % of a prediction `y_hat` of `y` (one output)."""
    e = y - y_hat
    rmse = float(np.sqrt(np.mean(e**2)))
    scale = float(np.sqrt(np.mean(y**2))) + float(np.sqrt(np.mean(y_hat**2)))
    theil = rmse / scale if scale > 0 else float("nan")
    spread2 = float(np.sum((y - y.mean()) ** 2))
    sse = float(e @ e)
    r2 = 1.0 - sse / spread2 if spread2 > 0 else float("nan")
    fit = 100.0 * (1.0 - math.sqrt(sse / spread2)) if spread2 > 0 else float("nan")
    return PredictionMetrics(rmse=rmse, theil_u=theil, r_squared=r2, fit=fit)


def _number(spec: Mapping[str, Any], key: str) -> float:
    v = spec[key]
    if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
        raise IdentificationError(f"holdout.{key}: expected a number, got {plain(v)}")
    x = float(v)
    if not math.isfinite(x):
        raise IdentificationError(f"holdout.{key}: expected a finite number, got {plain(v)}")
    return x


def holdout_record(data: FlightData, holdout: Any) -> tuple[FlightData, str, bool]:
    """The held-out data `holdout` names: (record, description, is a window of `data`).

    `holdout` is a second `FlightData`, or a mapping with ``t0`` and ``t1`` (a
    window of `data`, seconds), or with ``fraction`` (the last fraction of
    `data`'s time span).
    """
    if isinstance(holdout, FlightData):
        record, source, window = holdout, "second record", False
    elif isinstance(holdout, Mapping):
        keys = set(holdout)
        unknown = keys - {"t0", "t1", "fraction"}
        if unknown:
            raise IdentificationError(
                f"holdout: unknown key(s) {sorted(map(str, unknown))}; give t0 and t1, or fraction"
            )
        start, end = float(data.time[0]), float(data.time[-1])
        if "fraction" in keys:
            if keys & {"t0", "t1"}:
                raise IdentificationError("holdout: give either t0/t1 or fraction, not both")
            frac = _number(holdout, "fraction")
            if not 0.0 < frac < 1.0:
                raise IdentificationError(f"holdout.fraction must lie in (0, 1), got {frac:g}")
            t0, t1 = end - frac * (end - start), end
        else:
            if "t0" not in keys or "t1" not in keys:
                missing = "t0" if "t0" not in keys else "t1"
                raise IdentificationError(f"holdout.{missing}: a held-out window needs t0 and t1")
            t0, t1 = _number(holdout, "t0"), _number(holdout, "t1")
            if not t1 > t0:
                raise IdentificationError(f"holdout: need t1 > t0, got t0={t0:g}, t1={t1:g}")
            if t0 < start or t1 > end:
                raise IdentificationError(
                    f"holdout: window [{time_label(t0)}, {time_label(t1)}] s lies outside the record "
                    f"[{time_label(start)}, {time_label(end)}] s"
                )
        mask = (data.time >= t0) & (data.time <= t1)
        if int(mask.sum()) < MIN_HOLDOUT_SAMPLES:
            raise IdentificationError(
                f"holdout: window [{time_label(t0)}, {time_label(t1)}] s holds {int(mask.sum())} samples; "
                f"a prediction needs at least {MIN_HOLDOUT_SAMPLES}"
            )
        record, source, window = (
            data.window(t0, t1),
            f"window [{time_label(t0)}, {time_label(t1)}] s",
            True,
        )
    else:
        raise IdentificationError(
            "holdout: expected a mapping with t0 and t1 (or fraction), or FlightData, "
            f"got {type(holdout).__name__}"
        )
    if record.n_samples < MIN_HOLDOUT_SAMPLES:
        raise IdentificationError(
            f"holdout: the held-out record has {record.n_samples} samples; "
            f"a prediction needs at least {MIN_HOLDOUT_SAMPLES}"
        )
    return record, source, window


def predict(
    model: Any,
    record: FlightData,
    p: Any,
    outputs: Sequence[str],
    flown: FlightData,
    biases: Mapping[str, float],
    opts: Mapping[str, Any],
    source: str,
    units: Mapping[str, str],
    *,
    in_fit: bool = False,
    start: str = "measured",
) -> PredictionResult:
    """Simulate `model` with parameters `p` on the (delayed) controls `flown` of
    `record` from its measured initial state (or, `start` ``"estimated"``, from
    the initial state and output shifts fitted to it), and score it against `record`."""
    record.require(list(outputs), role="output")
    names = list(model.outputs)
    # the measured state at the first held-out sample, less the sensor biases the
    # fit estimated where they apply (a measured state carries its sensor's bias)
    # (a SimulatorModel has no states: it starts where its own simulate_data does)
    states = getattr(model, "states", ())
    x0 = {k: v - biases.get(k, 0.0) for k, v in measured_start(record, states).items()}
    y = record.array(list(outputs))
    if start == "estimated":
        x0, shifts = _fitted_start(model, flown, p, outputs, x0, opts)
    else:
        shifts = {o: float(biases.get(o, 0.0)) for o in outputs}
    run = partial(model.simulate_data, flown, x0=x0 or None, parameters=p, **opts)
    y_sim = simulator_outputs(model, run, flown.n_samples)
    idx = [names.index(o) for o in outputs]
    y_hat = y_sim[:, idx] + np.array([shifts[o] for o in outputs])
    metrics = {o: prediction_metrics(y[:, j], y_hat[:, j]) for j, o in enumerate(outputs)}
    ratios = {o: spread_over_noise(y[:, j]) for j, o in enumerate(outputs)}
    if ratios and all(v < _EXCITED for v in ratios.values()):
        listing = ", ".join(f"{n!r} {v:.2g}" for n, v in ratios.items())
        warnings.warn(
            f"validate: the held-out data ({source}) is not excited: on no output does the "
            "measured response's variance exceed its sample-to-sample noise's (RMS over "
            f"noise RMS, below {_EXCITED:.3g}: {listing}); the prediction metrics measure "
            "noise. Hold out a window that holds a manoeuvre",
            IdentifiabilityWarning,
            stacklevel=CALLER_STACKLEVEL + 1,
        )
    return PredictionResult(
        metrics=metrics,
        time=record.time,
        measured=y,
        predicted=y_hat,
        output_names=tuple(outputs),
        source=source,
        units={k: v for k, v in units.items() if k in outputs},
        in_fit=in_fit,
        response_to_noise=ratios,
        start=start,
        initial_state=x0,
        shifts={o: v for o, v in shifts.items() if v != 0.0},
    )


def _fitted_start(
    model: Any,
    flown: FlightData,
    p: Mapping[str, float],
    outputs: Sequence[str],
    guess: Mapping[str, float],
    opts: Mapping[str, Any],
) -> tuple[dict[str, float], dict[str, float]]:
    """The initial state and per-output reference shifts that fit `flown` best with
    every parameter of `model` held at `p`: output error over those alone."""
    from ..estimation.identification import identify

    held_fields = (
        {f.name for f in dataclasses.fields(model)} if dataclasses.is_dataclass(model) else ()
    )
    if "parameters" not in held_fields or not hasattr(model, "dynamics"):
        raise IdentificationError(
            'holdout_start="estimated" needs a Model (its initial state is fitted); '
            f"got {type(model).__name__}"
        )
    held = dataclasses.replace(model, parameters={**dict(model.parameters), **dict(p)})
    with warnings.catch_warnings():
        # a state that integrates (a bank angle) starts where its sensor's shift
        # would put it: the prediction is the same for any split of the two
        warnings.simplefilter("ignore", IdentifiabilityWarning)
        fit = identify(
            held,
            flown,
            [],
            outputs=list(outputs),
            x0=dict(guess) or None,
            # a model without states has only the shifts to fit
            estimate_x0=bool(model.states),
            estimate_bias=list(outputs),
            error_bars="white",
            simulate_options=dict(opts),
        )
    return dict(fit.initial_states[0]), {o: float(fit.biases[0][o]) for o in outputs}
