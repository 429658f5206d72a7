"""Output sensitivities, Fisher information and Cramér–Rao bounds of a trajectory.

Before fitting (or flying), the sensitivities ``dy/dθ`` of the model outputs
along a manoeuvre tell which parameters the data can constrain: weighted by
the measurement noise they give the Fisher information matrix, whose inverse
is the Cramér–Rao lower bound on the covariance any unbiased output-error
fit can reach.

All finite-difference columns are integrated in one batched simulation
(central differences, ``2 n_p + 1`` members), never as ``n_p + 1`` serial
runs; black-box simulators are looped member by member.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import partial
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._records import FrozenState, fmt, frozen_array, frozen_mapping, markdown_table
from .._threads import small_blas
from .._units import require_model_units
from .._value_checks import check_distinct
from ..errors import (
    ChannelError,
    IdentifiabilityWarning,
    IdentificationError,
    SimulationError,
)
from ..estimation.identifiability import NO_EFFECT, RCOND, unidentifiable
from ..io.data import FlightData, measured_start
from ..models.model import (
    Model,
    SimulatorModel,
    check_simulate_options,
    delayed_controls,
    fitted_manoeuvre,
    require_model,
    resolve_parameters,
    simulator_outputs,
)
from ..models.replay import FittedReplay, fitted_replay

__all__ = ["SensitivityResult", "sensitivities"]

FloatArray = NDArray[np.float64]


# -- shared numerics (also used by experiment design) ---------------------------------


def _output_names(model: Any) -> tuple[str, ...]:
    if isinstance(model, Model):
        return model.output_names
    return tuple(model.outputs)


def _control_names(model: Any) -> tuple[str, ...]:
    return tuple(model.controls)


def _check_simulate_options(options: Mapping[str, Any] | None, model: Any) -> dict[str, Any]:
    # keys and values (a negative rtol, a bool substeps) for a Model; others pass unchecked
    return check_simulate_options(options, model, IdentificationError)


def _relative_step(value: Any) -> float:
    """The finite-difference step, a number in (0, 0.1) (text and bools refused)."""
    try:
        if isinstance(value, (bool, np.bool_, str, bytes)):  # float() would read "1e-6"
            raise TypeError
        rel = float(value)
    except (TypeError, ValueError):
        rel = float("nan")
    if not (np.isfinite(rel) and 0 < rel < 0.1):
        raise IdentificationError(f"relative_step: expected a number in (0, 0.1), got {value!r}")
    return rel


def _parameter_list(model: Any, parameters: Any, what: str = "parameters") -> list[str]:
    names = list(model.parameters)
    if parameters is None:
        return names
    if isinstance(parameters, str):
        parameters = [parameters]
    if isinstance(parameters, Mapping):
        parameters = list(parameters)
    try:
        chosen = [str(p) for p in parameters]
    except TypeError:
        raise IdentificationError(
            f"{what}: expected a sequence of parameter names, got {parameters!r}"
        ) from None
    if not chosen:
        raise IdentificationError(f"{what}: give at least one parameter name")
    unknown = [p for p in chosen if p not in model.parameters]
    if unknown:
        raise IdentificationError(
            f"{what}: {unknown} are not parameters of model {model.name!r}; "
            f"its parameters are {names}"
        )
    dupes = sorted({p for p in chosen if chosen.count(p) > 1})
    if dupes:
        raise IdentificationError(f"{what}: duplicate names {dupes}")
    return chosen


def _fd_steps(values: FloatArray, relative_step: float) -> FloatArray:
    # Relative steps, with unit scale near zero so a parameter at θ = 0 still moves.
    return relative_step * np.maximum(np.abs(values), 1.0)


def _simulate_members(
    model: Any,
    time: FloatArray,
    controls: FloatArray,
    x0: Any,
    params: Mapping[str, FloatArray],
    options: Mapping[str, Any],
    errors: list[str] | None = None,
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Outputs (B, n_t, n_y) and success flags of a batch; controls (B or 1, n_t, n_u).

    What failed (the first failing member's state or output and time, or what a
    stepped simulator raised) is appended to `errors`.
    """
    batch = max(int(np.size(v)) for v in params.values()) if params else controls.shape[0]
    if isinstance(model, Model):
        opts = {"method": "auto", **options}
        sim = model.simulate_batch(time, controls, x0, params, **opts)
        if errors is not None and not np.all(sim.ok):
            errors.append(sim.failure[int(np.argmin(sim.ok))])
        return sim.outputs, sim.ok
    # Black-box simulator: one member at a time.
    names = _control_names(model)
    n_y = len(_output_names(model))
    out = np.full((batch, time.size, n_y), np.nan)
    ok = np.zeros(batch, dtype=bool)
    for b in range(batch):
        u = controls[b if controls.shape[0] > 1 else 0]
        cdict = {n: u[:, j] for j, n in enumerate(names)}
        pb = {k: float(np.broadcast_to(v, (batch,))[b]) for k, v in params.items()}
        try:
            run = partial(model.simulate, time, cdict, x0, pb, **options)
            out[b] = simulator_outputs(model, run, time.size)
        except SimulationError as exc:
            if errors is not None:
                errors.append(str(exc))
            continue
        ok[b] = True
    return out, ok


def _fd_sensitivities(
    model: Any,
    time: FloatArray,
    controls: FloatArray,
    x0: Any,
    values: Mapping[str, float],
    names: Sequence[str],
    steps: FloatArray,
    options: Mapping[str, Any],
    *,
    nominal: bool,
    errors: list[str] | None = None,
) -> tuple[FloatArray | None, FloatArray, NDArray[np.bool_]]:
    """Central-difference sensitivities of one or many control histories in ONE batch.

    controls: (S, n_t, n_u), one history per candidate.  Returns the nominal
    outputs (S, n_t, n_y) if requested, the sensitivities (S, n_p, n_t, n_y)
    and a per-candidate success flag.
    """
    n_s = controls.shape[0]
    n_p = len(names)
    per = 2 * n_p + (1 if nominal else 0)
    batch = n_s * per
    params = {k: np.full(batch, float(v)) for k, v in values.items()}
    # member layout: candidate-major; within a candidate [+θ_1, -θ_1, +θ_2, ..., nominal]
    for j, name in enumerate(names):
        col = params[name].reshape(n_s, per)
        col[:, 2 * j] += steps[j]
        col[:, 2 * j + 1] -= steps[j]
    # a single history is shared by all members; several are repeated per member
    u = np.repeat(controls, per, axis=0) if n_s > 1 else controls
    y, ok = _simulate_members(model, time, u, x0, params, options, errors)
    y = y.reshape(n_s, per, time.size, -1)
    ok_c = np.asarray(ok.reshape(n_s, per).all(axis=1), dtype=bool)
    pm = y[:, : 2 * n_p].reshape(n_s, n_p, 2, time.size, -1)
    with np.errstate(all="ignore"):
        sens = (pm[:, :, 0] - pm[:, :, 1]) / (2.0 * steps[None, :, None, None])
    return (y[:, -1] if nominal else None), sens, ok_c


def _fisher(sens: FloatArray, sigma: FloatArray) -> FloatArray:
    """Fisher information sum_t S^T R^-1 S; sens (..., n_p, n_t, n_y), sigma (n_y,)."""
    w = sens / sigma
    return np.einsum("...itk,...jtk->...ij", w, w)


def _analyse_fisher(
    fisher: FloatArray, names: Sequence[str]
) -> tuple[FloatArray, tuple[tuple[str, ...], ...], FloatArray]:
    """Covariance bound, unidentifiable combinations, normalised eigenvalues.

    Near-null directions of the Fisher matrix scaled to unit diagonal name the
    parameter combinations the data cannot separate; their bound is infinite
    instead of a silently huge (or truncated) number.
    """
    n = len(names)
    combos, bad = unidentifiable(fisher, names)
    d = np.sqrt(np.clip(np.diag(fisher), 0.0, None))
    dead = d <= 1e-300 + NO_EFFECT * (d.max() if n else 0.0)
    live = np.flatnonzero(~dead)
    cov = np.full((n, n), np.nan)
    eig = np.zeros(n)
    if live.size:
        dl = d[live]
        fn = fisher[np.ix_(live, live)] / np.outer(dl, dl)
        w, v = np.linalg.eigh(0.5 * (fn + fn.T))
        eig[: live.size] = w
        keep = ~(w < RCOND * max(float(w[-1]), 1e-300))
        inv_n = (v[:, keep] / w[keep]) @ v[:, keep].T
        cov[np.ix_(live, live)] = inv_n / np.outer(dl, dl)
    for i in np.flatnonzero(bad).tolist():
        cov[i, :] = np.nan
        cov[:, i] = np.nan
        cov[i, i] = np.inf
    return cov, tuple(combos), eig


def _crb(cov: FloatArray) -> FloatArray:
    diag = np.diag(cov).copy()
    with np.errstate(invalid="ignore"):
        return np.where(np.isfinite(diag), np.sqrt(np.clip(diag, 0.0, None)), np.inf)


def _noise_vector(
    noise: Mapping[str, float], outputs: Sequence[str], what: str = "noise"
) -> FloatArray:
    sig = np.empty(len(outputs))
    for i, o in enumerate(outputs):
        if o not in noise:
            raise IdentificationError(
                f"{what}: no standard deviation for output {o!r}; given for {sorted(noise)}"
            )
        try:
            # float() would read True as 1.0 and "0.01" as 0.01
            if isinstance(noise[o], (bool, np.bool_, str, bytes)):
                raise TypeError
            s = float(noise[o])
        except (TypeError, ValueError):
            raise IdentificationError(
                f"{what}[{o!r}]: expected a positive number, got {noise[o]!r}"
            ) from None
        if not (np.isfinite(s) and s > 0):
            raise IdentificationError(
                f"{what}[{o!r}]: expected a positive standard deviation, got {noise[o]!r}"
            )
        sig[i] = s
    return sig


def _combo_text(combos: Sequence[Sequence[str]]) -> str:
    return "; ".join(" + ".join(c) if len(c) > 1 else f"{c[0]} (no sensitivity)" for c in combos)


# -- the public record ----------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class SensitivityResult(FrozenState):
    """Output sensitivities along a trajectory and the information they carry.

    Attributes
    ----------
    time : ndarray, shape (n_t,)
    parameter_names : tuple of str
        The analysed parameters, in the order of every matrix axis.
    output_names : tuple of str
    values : mapping of str to float
        Parameter values (all model parameters) at which the sensitivities were taken.
    noise : mapping of str to float
        Measurement-noise standard deviation per output used for the Fisher matrix.
    noise_source : str
        ``"given"``, ``"fit"`` (the noise an identification result weighed
        its outputs by), ``"residuals"`` (estimated from measured minus
        simulated outputs) or ``"unit"`` (no noise known: bounds are per unit
        noise); for a mix, the outputs per source, as ``"fit (x); unit (v)"``.
    sensitivities : ndarray, shape (n_t, n_y, n_p)
        ``dy/dθ`` histories.
    outputs : ndarray, shape (n_t, n_y)
        Simulated outputs at `values`.
    fisher_information : ndarray, shape (n_p, n_p)
        ``sum_t S_t^T R^-1 S_t`` with ``R = diag(noise^2)``.
    covariance : ndarray, shape (n_p, n_p)
        Cramér–Rao covariance bound (inverse Fisher matrix); infinite diagonal
        and NaN rows for parameters in unidentifiable combinations.
    cramer_rao_bound : mapping of str to float
        Lower bound on the standard error of each parameter.
    norms : mapping of str to float
        Noise-weighted 2-norm of each parameter's sensitivity, ``sqrt(F_jj)``
        (the inverse of the bound the parameter would have if it were alone).
    identifiable : bool
    unidentifiable : tuple of tuple of str
        Parameter combinations the trajectory cannot separate.
    eigenvalues : ndarray, shape (n_p,)
        Eigenvalues of the Fisher matrix scaled to unit diagonal (ascending).
    relative_step : float
    method : str
        How the sensitivities were computed.
    model_name : str
    nuisance : tuple of str
        The estimates besides the parameters that a fit of this record made
        and whose information the bounds leave out, as the fit's own error
        bars do: its initial states (``"x0.<state>"``), state-equation biases
        (``"bias.state.<state>"``) and output biases (``"bias.<output>"``).
        `fisher_information` is then what the parameters keep of it (the
        Schur complement), `norms` the sensitivities' own.
    """

    time: FloatArray
    parameter_names: tuple[str, ...]
    output_names: tuple[str, ...]
    values: Mapping[str, float]
    noise: Mapping[str, float]
    noise_source: str
    sensitivities: FloatArray
    outputs: FloatArray
    fisher_information: FloatArray
    covariance: FloatArray
    cramer_rao_bound: Mapping[str, float]
    norms: Mapping[str, float]
    identifiable: bool
    unidentifiable: tuple[tuple[str, ...], ...]
    eigenvalues: FloatArray
    relative_step: float
    method: str
    model_name: str = ""
    nuisance: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        for name in (
            "time",
            "sensitivities",
            "outputs",
            "fisher_information",
            "covariance",
            "eigenvalues",
        ):
            set_(self, name, frozen_array(getattr(self, name)))
        for name in ("values", "noise", "cramer_rao_bound", "norms"):
            set_(self, name, frozen_mapping(getattr(self, name)))
        set_(self, "parameter_names", tuple(self.parameter_names))
        set_(self, "output_names", tuple(self.output_names))
        set_(self, "unidentifiable", tuple(tuple(c) for c in self.unidentifiable))
        set_(self, "nuisance", tuple(str(n) for n in self.nuisance))

    def sensitivity(self, output: str, parameter: str) -> FloatArray:
        """History of ``d output / d parameter`` on `time`."""
        if output not in self.output_names:
            raise ChannelError(
                f"output {output!r} not analysed; outputs: {list(self.output_names)}"
            )
        if parameter not in self.parameter_names:
            raise IdentificationError(
                f"parameter {parameter!r} not analysed; parameters: {list(self.parameter_names)}"
            )
        return self.sensitivities[
            :, self.output_names.index(output), self.parameter_names.index(parameter)
        ]

    @property
    def correlation(self) -> FloatArray:
        """Correlation matrix of the Cramér–Rao covariance (NaN where undefined)."""
        d = np.sqrt(np.abs(np.diag(self.covariance)))
        with np.errstate(divide="ignore", invalid="ignore"):
            c = self.covariance / np.outer(d, d)
        c[~np.isfinite(c)] = np.nan
        for i in range(c.shape[0]):
            c[i, i] = 1.0
        c.setflags(write=False)
        return c

    def plot(self, **kwargs: Any) -> Any:
        """Scaled sensitivity histories. Returns a matplotlib Figure."""
        from ..reports.plotting import plot_sensitivities

        return plot_sensitivities(self, **kwargs)

    def summary(self) -> str:
        """Markdown section: sensitivity norms, Cramér–Rao bounds and identifiability."""
        rows = []
        for n in self.parameter_names:
            v = self.values[n]
            b = self.cramer_rao_bound[n]
            rel = f"{100 * b / abs(v):.2g}%" if v != 0 and np.isfinite(b) else "—"
            rows.append((n, fmt(v), fmt(self.norms[n]), fmt(b), rel))
        table = markdown_table(
            ("parameter", "value", "sensitivity norm", "Cramér–Rao std. error", "rel. bound"),
            rows,
        )
        src = {
            "given": "given",
            "fit": "the fit's",
            "residuals": "estimated from the residuals",
            "unit": "unknown — bounds are per unit noise",
        }.get(self.noise_source, self.noise_source)
        noise = ", ".join(f"{k} {fmt(v)}" for k, v in self.noise.items())
        lines = [
            "## Sensitivity analysis",
            "",
            table,
            "",
            f"{self.time.size} samples over {fmt(float(self.time[-1] - self.time[0]))} s; "
            f"noise σ ({src}): {noise}. Sensitivities by {self.method}.",
        ]
        if self.identifiable:
            lines.append("All analysed parameters are identifiable from this trajectory.")
        else:
            lines.append(
                f"**Not identifiable:** this trajectory cannot separate "
                f"{_combo_text(self.unidentifiable)}."
            )
        return "\n".join(lines)


# -- the public function --------------------------------------------------------------------


def _check_noise_names(noise: Any, all_outputs: Sequence[str], model_name: str) -> None:
    """Refuse a `noise` option that is not a mapping of the model's output names."""
    if not isinstance(noise, Mapping):
        raise IdentificationError(
            f"noise: expected a dict of output -> standard deviation, got {type(noise).__name__}"
        )
    unknown = sorted(set(noise) - set(all_outputs))
    if unknown:
        raise IdentificationError(
            f"noise: {unknown} are not outputs of model {model_name!r}; "
            f"outputs: {list(all_outputs)}"
        )


@small_blas
def sensitivities(
    model: Model | SimulatorModel,
    data: FlightData,
    parameters: Sequence[str] | str | Mapping[str, float] | Any | None = None,
    *,
    values: Any = None,
    noise: Mapping[str, float] | None = None,
    outputs: Sequence[str] | None = None,
    x0: Any = None,
    relative_step: float = 1e-6,
    simulate_options: Mapping[str, Any] | None = None,
) -> SensitivityResult:
    """Output sensitivities, Fisher information and Cramér–Rao bounds along a record.

    Parameters
    ----------
    model : Model or SimulatorModel
    data : FlightData
        Supplies the time grid and the control histories; measured outputs
        (when present) are used only to estimate the noise when `noise` is None.
    parameters : sequence of str, mapping or result, optional
        Parameters to analyse (default: all model parameters). A mapping of
        values or a result (as `validate` takes them) analyses its parameters
        at its values.
    values : mapping or result, optional
        Parameter values to linearise at, merged onto the nominal ones; a
        result with ``.parameters`` (identification or inference) works too,
        and an identification result's estimated time delays delay its
        controls, as in `validate`.
    noise : mapping of str to float, optional
        Measurement-noise standard deviation per output. Default, per output:
        the noise an identification result given as `values` weighed it by,
        else estimated from measured minus simulated outputs, else (not
        measured) unit noise, with a warning that names those outputs.
    outputs : sequence of str, optional
        Outputs to use. Default: those named in `noise`, else those an
        identification result fitted, else those the record measures (all
        model outputs for a record that measures none).
    x0 : array_like or mapping, optional
        Initial state; default: the state an identification result given as
        `values` used for this record, else the measured states at the first
        sample. On a record the result was fitted to, the model is replayed
        as fitted: with the output and state-equation biases it estimated
        for it, and (unless `x0` is given) with the information its estimated
        initial states and biases take taken out (``nuisance``), so that the
        bounds are the fit's white error bars.
    relative_step : float
        Central-difference step relative to ``max(|θ|, 1)``.
    simulate_options : mapping, optional
        Passed to the simulator (for a `Model`: ``method``, ``substeps``,
        ``rtol``, ``atol``; the default method is ``"auto"``).

    Returns
    -------
    SensitivityResult

    Raises
    ------
    IdentificationError
        Unknown parameters, bad noise specification or step (text or a bool
        where a number is expected), an empty `outputs`, unknown or invalid
        `simulate_options`.
    ChannelError
        A control (or requested output) is missing.
    SimulationError
        The model fails to simulate at or next to `values`.

    Warns
    -----
    IdentifiabilityWarning
        When the trajectory cannot separate some parameters (named).
    """
    require_model(model, IdentificationError)
    if not isinstance(data, FlightData):
        raise IdentificationError(f"data: expected FlightData, got {type(data).__name__}")
    require_model_units(
        model, [data], [*model.controls, *getattr(model, "output_names", ())], IdentificationError
    )
    if isinstance(parameters, Mapping) or hasattr(parameters, "parameters"):
        # parameter values given where names go (as validate takes them): analyse those
        # parameters at those values
        if values is not None:
            raise IdentificationError(
                "parameters: give parameter values either as `parameters` or as `values`, not both"
            )
        values = parameters
        given: Any = getattr(parameters, "parameter_names", None) or getattr(
            parameters, "parameters", parameters
        )
        parameters = [str(n) for n in given]
        if not isinstance(values, Mapping):
            # a result's other estimates (a posterior's sigma_<output>, a fit's delays)
            # are not the model's parameters
            parameters = [n for n in parameters if n in model.parameters] or parameters
    names = _parameter_list(model, parameters)
    vals = resolve_parameters(model, values, error=IdentificationError)
    # the nuisance estimates of a fit of this record, replayed from its own start
    nuisance = _fit_nuisance(values, data, model) if x0 is None else ([], [], [])
    # on a record the fit was fitted to: its start, output biases and state biases
    replay = fitted_replay(model, values, data, x0)
    x0 = replay.x0
    fit_sigma = _fit_noise(values, all_outputs := _output_names(model))
    data = delayed_controls(values, data)  # a fit's estimated time delays
    rel = _relative_step(relative_step)
    options = _check_simulate_options(simulate_options, model)
    if outputs is not None:
        outs = [outputs] if isinstance(outputs, str) else list(outputs)
        if not outs:  # an empty analysis would pass for one
            raise IdentificationError(
                f"outputs: name at least one output; outputs: {list(all_outputs)}"
            )
        unknown = [o for o in outs if o not in all_outputs]
        if unknown:
            raise ChannelError(
                f"outputs: {unknown} are not outputs of model {model.name!r}; "
                f"outputs: {list(all_outputs)}"
            )
        check_distinct(outs, "outputs", IdentificationError)
    elif noise is not None:
        outs = [o for o in all_outputs if o in noise]
        if not outs:
            raise IdentificationError(
                f"noise: names no model output; outputs are {list(all_outputs)}, "
                f"noise given for {sorted(noise)}"
            )
    elif fit_sigma:  # the outputs the fit weighed
        outs = [o for o in all_outputs if o in fit_sigma]
    else:  # those the record measures (all, for a record that measures none: unit noise)
        outs = [o for o in all_outputs if o in data] or list(all_outputs)
    if noise is not None:
        _check_noise_names(noise, all_outputs, model.name)
    controls = _control_names(model)
    data.require(controls, role="control")
    u = data.array(list(controls))[None] if controls else np.zeros((1, data.n_samples, 0))
    if x0 is None and isinstance(model, Model):
        x0 = measured_start(data, model.states)
    theta = np.array([vals[n] for n in names])
    steps = _fd_steps(theta, rel)
    errors: list[str] = []
    y0, sens, ok = _fd_sensitivities(
        replay.model, data.time, u, x0, vals, names, steps, options, nominal=True, errors=errors
    )
    if not ok[0]:
        why = f": {errors[0]}" if errors else ""
        raise SimulationError(
            f"sensitivities: model {model.name!r} failed to simulate at (or within a "
            f"relative {rel:g} step of) the parameter values {vals}{why}"
        )
    assert y0 is not None  # requested above
    idx = [all_outputs.index(o) for o in outs]
    y_nom = y0[0][:, idx] + np.array([replay.output_biases.get(o, 0.0) for o in outs])
    s = sens[0][:, :, idx]  # (n_p, n_t, n_y)
    if noise is not None:
        sigma = _noise_vector(noise, outs)
        source = "given"
    else:
        sigma, source = _estimate_noise(data, outs, y_nom, fit_sigma)
    s_n, nuisance_names = _nuisance_sensitivities(
        replay, nuisance, data.time, u, vals, rel, options, idx, model.name
    )
    fisher = _fisher(s, sigma)
    norms = np.sqrt(np.clip(np.diag(fisher), 0, None))
    if nuisance_names:
        fisher = _schur(np.concatenate([s, s_n]), sigma, len(names))
    cov, combos, eig = _analyse_fisher(fisher, names)
    crb = _crb(cov)
    if combos:
        warnings.warn(
            f"sensitivities: the trajectory cannot separate {_combo_text(combos)}; "
            "their Cramér–Rao bounds are reported as infinite",
            IdentifiabilityWarning,
            stacklevel=3,  # sensitivities, its BLAS wrapper (aeroid._threads), the caller
        )
    is_model = isinstance(model, Model)
    method = (
        "central differences, one batched simulation"
        if is_model
        else "central differences, simulated member by member"
    )
    return SensitivityResult(
        time=data.time,
        parameter_names=tuple(names),
        output_names=tuple(outs),
        values=vals,
        noise=dict(zip(outs, sigma.tolist(), strict=True)),
        noise_source=source,
        sensitivities=np.transpose(s, (1, 2, 0)),
        outputs=y_nom,
        fisher_information=fisher,
        covariance=cov,
        cramer_rao_bound=dict(zip(names, crb.tolist(), strict=True)),
        norms=dict(zip(names, norms.tolist(), strict=True)),
        identifiable=not combos,
        unidentifiable=combos,
        eigenvalues=eig,
        relative_step=rel,
        method=method,
        model_name=str(model.name),
        nuisance=tuple(nuisance_names),
    )


def _estimate_noise(
    data: FlightData,
    outputs: Sequence[str],
    simulated: FloatArray,
    fitted: Mapping[str, float],
) -> tuple[FloatArray, str]:
    """Per output: the fit's noise, else the residual RMS, else unit noise (warned).

    Returns the standard deviations and their source: ``"fit"``,
    ``"residuals"`` or ``"unit"``, or for a mix the outputs per source
    (``"fit (x); unit (v)"``).
    """
    sigma = np.ones(len(outputs))
    kinds: dict[str, list[str]] = {}
    for i, o in enumerate(outputs):
        kind = "unit"
        if o in fitted:
            sigma[i], kind = fitted[o], "fit"
        elif o in data:
            r = data.channels[o] - simulated[:, i]
            s = float(np.sqrt(np.mean(r**2)))
            if s > 1e-12 * max(float(np.max(np.abs(data.channels[o]))), 1e-300):
                sigma[i], kind = s, "residuals"
        kinds.setdefault(kind, []).append(o)
    if "unit" in kinds:
        missing = kinds["unit"]
        warnings.warn(
            f"sensitivities: cannot estimate the noise of outputs {missing} from the data "
            "(not measured, or residuals are zero); using unit noise for "
            + (f"{missing} only" if len(kinds) > 1 else "all outputs")
            + " — pass noise={output: sigma} for meaningful Cramér–Rao bounds",
            UserWarning,
            stacklevel=4,  # here, sensitivities, its BLAS wrapper, the caller
        )
    if len(kinds) == 1:
        return sigma, next(iter(kinds))
    return sigma, "; ".join(f"{k} ({', '.join(v)})" for k, v in kinds.items())


def _fit_noise(result: Any, outputs: Sequence[str]) -> dict[str, float]:
    """The noise standard deviations an identification result weighed its outputs by."""
    names = tuple(getattr(result, "output_names", ()) or ())
    cov = np.asarray(getattr(result, "noise_covariance", np.zeros((0, 0))), dtype=np.float64)
    if isinstance(result, Mapping) or cov.shape != (len(names), len(names)):
        return {}
    var = np.diag(cov)
    return {
        o: float(np.sqrt(v))
        for o, v in zip(names, var.tolist(), strict=True)
        if o in outputs and np.isfinite(v) and v > 0
    }


def _fit_nuisance(
    result: Any, data: FlightData, model: Any
) -> tuple[list[str], list[str], list[str]]:
    """The initial states, state biases and output biases a fit estimated for `data`
    (empty unless `result` is an identification result fitted to it)."""
    i = fitted_manoeuvre(result, data)
    est = getattr(result, "extra_stderr", None)
    if i is None or not isinstance(est, Mapping) or not isinstance(model, Model):
        return [], [], []
    states = [s for s in model.states if f"x0[{i}].{s}" in est]
    on_states = [s for s in model.states if f"bias[{i}].state.{s}" in est]
    on_outputs = [o for o in model.output_names if f"bias[{i}].{o}" in est]
    return states, on_states, on_outputs


def _nuisance_sensitivities(
    replay: FittedReplay,
    nuisance: tuple[list[str], list[str], list[str]],
    time: FloatArray,
    controls: FloatArray,
    values: Mapping[str, float],
    rel: float,
    options: Mapping[str, Any],
    idx: Sequence[int],
    model_name: str,
) -> tuple[FloatArray, list[str]]:
    """Sensitivities (n_n, n_t, n_y) of the outputs `idx` to a fit's estimated initial
    states, state biases (central differences of the start) and output biases (ones)."""
    states, on_states, on_outputs = nuisance
    model = replay.model
    # a bias on an output not analysed takes nothing from the bounds
    on_outputs = [o for o in on_outputs if model.output_names.index(o) in idx]
    names = [f"x0.{s}" for s in states] + [f"bias.state.{s}" for s in on_states]
    rows = [model.states.index(s) for s in states]
    rows += [model.states.index(replay.bias_states[s]) for s in on_states]
    out = np.zeros((len(rows) + len(on_outputs), time.size, len(idx)))
    if rows:
        start = np.array([float(replay.x0[s]) for s in model.states])
        steps = _fd_steps(start[rows], rel)
        x0 = np.repeat(start[None], 2 * len(rows), axis=0)
        for j, (r, h) in enumerate(zip(rows, steps.tolist(), strict=True)):
            x0[2 * j, r] += h
            x0[2 * j + 1, r] -= h
        params = {k: np.full(2 * len(rows), float(v)) for k, v in values.items()}
        errors: list[str] = []
        y, ok = _simulate_members(model, time, controls, x0, params, options, errors)
        if not np.all(ok):
            why = f": {errors[0]}" if errors else ""
            raise SimulationError(
                f"sensitivities: model {model_name!r} failed to simulate within a relative "
                f"{rel:g} step of the fit's initial state{why}"
            )
        y = y[:, :, list(idx)]
        out[: len(rows)] = (y[0::2] - y[1::2]) / (2.0 * steps[:, None, None])
    for j, o in enumerate(on_outputs):
        out[len(rows) + j, :, list(idx).index(model.output_names.index(o))] = 1.0
    return out, names + [f"bias.{o}" for o in on_outputs]


def _schur(sens: FloatArray, sigma: FloatArray, n_p: int) -> FloatArray:
    """The Fisher information of the first `n_p` parameters left after the others
    (nuisance estimates) are estimated too: ``F_pp - F_pn F_nn^+ F_np``, whose inverse
    is the parameters' block of the whole Fisher matrix's inverse."""
    full = _fisher(sens, sigma)
    f_pp, f_pn, f_nn = full[:n_p, :n_p], full[:n_p, n_p:], full[n_p:, n_p:]
    d = np.sqrt(np.clip(np.diag(f_nn), 1e-300, None))
    # on a unit diagonal, so that estimates of very different sizes keep their digits
    inv = np.linalg.pinv(f_nn / np.outer(d, d), rcond=RCOND, hermitian=True) / np.outer(d, d)
    out = f_pp - f_pn @ inv @ f_pn.T
    return np.asarray(0.5 * (out + out.T))
