"""Optimal input design: which manoeuvre constrains the parameters best?

`design_experiment` searches a manoeuvre family's design variables for the
D-optimal (smallest volume of the Cramér–Rao ellipsoid) or A-optimal
(smallest sum of relative variances) Fisher information, with a seeded
differential-evolution search (Storn & Price 1997) followed by a bounded
quasi-Newton polish.

Every generation is one batched simulation: each candidate's control
history is paired with its ``2 n_p`` central-difference parameter columns,
and all candidates x columns are integrated in a single `Model.simulate_batch`
call with per-member controls. Every batch (the initial design, the population,
the polish's gradient stencil, the final comparison) is padded to one number of
candidates, so a compiled simulation compiles one program for the whole design.
"""

from __future__ import annotations

import contextlib
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.optimize
from numpy.typing import NDArray

from .._records import FrozenState, fmt, frozen_array, frozen_mapping, markdown_table
from .._threads import CALLER_STACKLEVEL, small_blas
from .._value_checks import check_seed
from ..errors import (
    AeroidError,
    ChannelError,
    IdentifiabilityWarning,
    IdentificationError,
    ModelDefinitionError,
    SimulationError,
)
from ..estimation.identifiability import NO_EFFECT, RCOND
from ..io.data import FlightData, as_float, check_flag
from ..models.integration import shifted_controls
from ..models.model import (
    Model,
    SimulatorModel,
    control_delays,
    require_model,
    resolve_parameters,
)
from ._design_family import family_bounds, family_controls, family_vector, trim_vector
from .design_options import optimizer_settings
from .maneuvers import ManeuverFamily
from .sensitivity import (
    _analyse_fisher,
    _check_noise_names,
    _check_simulate_options,
    _combo_text,
    _control_names,
    _crb,
    _fd_sensitivities,
    _fd_steps,
    _fisher,
    _noise_vector,
    _output_names,
    _parameter_list,
    _relative_step,
)

__all__ = ["ExperimentDesign", "design_experiment"]

FloatArray = NDArray[np.float64]

_CRITERIA = ("D", "A")
# Most samples of a design's time grid, and most values one batched simulation of the
# optimiser's population may hold (2 GiB of float64).
_MAX_SAMPLES = 10**7
_MAX_BATCH_VALUES = 2**28
# A criterion value for candidates whose information matrix is singular or whose
# simulation failed: finite, so the optimiser's population statistics stay finite.
_PENALTY = 1e30


@dataclass(frozen=True, eq=False)
class ExperimentDesign(FrozenState):
    """An optimised manoeuvre with its predicted parameter precision.

    Attributes
    ----------
    design : mapping of str to float
        The chosen design variables (as flown: after any peak limiting).
    initial_design : mapping of str to float
        The family's reference design the optimum is compared with.
    variable_names : tuple of str
    bounds : ndarray, shape (n_variables, 2)
    time : ndarray, shape (n_t,)
    controls : ndarray, shape (n_t, n_controls)
        The designed history of every model control (undriven ones are zero).
    control_names : tuple of str
    parameter_names : tuple of str
    values : mapping of str to float
        Parameter values the design was computed at.
    noise : mapping of str to float
        Measurement-noise standard deviation per output.
    criterion : str
        ``"D"`` or ``"A"``.
    criterion_value, initial_criterion_value : float
        The minimised criterion at the optimum and at the initial design
        (lower is better; infinite when the design cannot identify the
        parameters). D: ``log det`` of the relative Cramér–Rao covariance
        (each parameter scaled by ``|θ|``, or by 1 at zero); A: the sum of
        the relative Cramér–Rao variances.
    predicted_stderr, initial_stderr : mapping of str to float
        Cramér–Rao standard errors with the designed and the initial manoeuvre.
    fisher_information : ndarray, shape (n_p, n_p)
        At the optimum.
    recommendation : str
        One-paragraph advice for the flight-test plan.
    maneuver : str
        Description of the designed manoeuvre.
    n_generations, n_candidates, n_simulations : int
        Work done: optimiser generations, candidate designs evaluated,
        trajectories integrated for them (the copies that pad a batch to the
        population's size are not counted).
    n_failed : int
        Candidates whose simulation failed (non-finite, or the model raised):
        they cannot be flown and were dropped from the search, with a warning.
    success : bool
    message : str
    seed : int or None
        The optimiser's seed (`design_experiment` draws and records one when
        none is given).
    model_name : str
    """

    design: Mapping[str, float]
    initial_design: Mapping[str, float]
    variable_names: tuple[str, ...]
    bounds: FloatArray
    time: FloatArray
    controls: FloatArray
    control_names: tuple[str, ...]
    parameter_names: tuple[str, ...]
    values: Mapping[str, float]
    noise: Mapping[str, float]
    criterion: str
    criterion_value: float
    initial_criterion_value: float
    predicted_stderr: Mapping[str, float]
    initial_stderr: Mapping[str, float]
    fisher_information: FloatArray
    recommendation: str
    maneuver: str
    n_generations: int
    n_candidates: int
    n_simulations: int
    success: bool
    message: str
    seed: int | None = None
    model_name: str = ""
    n_failed: int = 0

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        for name in ("bounds", "time", "controls", "fisher_information"):
            set_(self, name, frozen_array(getattr(self, name)))
        for name in ("design", "initial_design", "values", "noise", "predicted_stderr",
                     "initial_stderr"):  # fmt: skip
            set_(self, name, frozen_mapping(getattr(self, name)))
        for name in ("variable_names", "control_names", "parameter_names"):
            set_(self, name, tuple(getattr(self, name)))

    def control(self, name: str) -> FloatArray:
        """Designed history of one control."""
        if name not in self.control_names:
            raise ChannelError(
                f"control {name!r} not designed; controls: {list(self.control_names)}"
            )
        return self.controls[:, self.control_names.index(name)]

    def to_flight_data(self) -> FlightData:
        """The fly-ready control history as `FlightData` (one channel per control)."""
        return FlightData(
            self.time,
            {n: self.controls[:, j] for j, n in enumerate(self.control_names)},
            metadata={"maneuver": self.maneuver, "criterion": self.criterion},
        )

    def plot(self, **kwargs: Any) -> Any:
        """The designed manoeuvre and predicted precision. Returns a matplotlib Figure."""
        from ..reports.plotting import plot_design

        return plot_design(self, **kwargs)

    def summary(self) -> str:
        """Markdown section: design variables, predicted precision and the recommendation."""
        var_rows = [
            (n, fmt(self.initial_design[n]), fmt(self.design[n]), f"{fmt(lo)} – {fmt(hi)}")
            for n, (lo, hi) in zip(self.variable_names, self.bounds, strict=True)
        ]
        vars_table = markdown_table(("variable", "initial", "designed", "bounds"), var_rows)
        rows = []
        for n in self.parameter_names:
            se0, se = self.initial_stderr[n], self.predicted_stderr[n]
            ratio = f"{se0 / se:.3g}x" if np.isfinite(se0) and se > 0 and np.isfinite(se) else "—"
            v = self.values[n]
            rel = f"{100 * se / abs(v):.2g}%" if v != 0 and np.isfinite(se) else "—"
            rows.append((n, fmt(v), fmt(se0), fmt(se), rel, ratio))
        par_table = markdown_table(
            ("parameter", "value", "initial stderr", "predicted stderr", "rel.", "improvement"),
            rows,
        )
        duration = float(self.time[-1] - self.time[0])
        failed = (
            f" {self.n_failed} of the {self.n_candidates} candidates failed to simulate "
            "and were dropped."
            if self.n_failed
            else ""
        )
        criterion = (
            f"Criterion {fmt(self.initial_criterion_value)} → {fmt(self.criterion_value)}"
            if np.isfinite(self.criterion_value)
            else "Criterion infinite (the design cannot identify every parameter)"
        )
        return "\n".join(
            [
                "## Experiment design",
                "",
                f"{self.criterion}-optimal design over {fmt(duration)} s at "
                f"{fmt((self.time.size - 1) / duration)} Hz: {self.maneuver}.",
                "",
                vars_table,
                "",
                par_table,
                "",
                f"{criterion} after {self.n_generations} generations ({self.n_candidates} candidates, "
                f"{self.n_simulations} simulated trajectories).{failed} {self.message}",
                "",
                f"**Recommendation:** {self.recommendation}",
            ]
        )


class _Evaluator:
    """Criterion of many candidate designs from one batched simulation each call."""

    def __init__(
        self,
        model: Any,
        maneuver: ManeuverFamily,
        time: FloatArray,
        x0: Any,
        values: Mapping[str, float],
        names: Sequence[str],
        sigma: FloatArray,
        out_idx: list[int],
        criterion: str,
        options: Mapping[str, Any],
        relative_step: float,
        trim: FloatArray | None = None,
        width: int = 0,
        delays: Mapping[str, float] | None = None,
    ) -> None:
        self.model = model
        self.maneuver = maneuver
        self.time = time
        self.x0 = x0
        self.values = values
        self.names = list(names)
        self.sigma = sigma
        self.out_idx = out_idx
        self.criterion = criterion
        self.options = options
        theta = np.array([values[n] for n in names])
        self.steps = _fd_steps(theta, relative_step)
        self.scale = np.where(theta != 0, np.abs(theta), 1.0)
        all_controls = _control_names(model)
        self.cols = [all_controls.index(c) for c in maneuver.controls]
        self.n_u = len(all_controls)
        self.trim = np.zeros(self.n_u) if trim is None else trim
        # a fit's estimated time delays: the vehicle it describes acts on u(t - tau)
        self.delays = [(all_controls.index(c), tau) for c, tau in (delays or {}).items()]
        # Every batch is padded to this many candidates (0: none): each batch shape
        # compiles a program of its own, and the population, the polish's gradient
        # stencil and the final comparison would otherwise give three or four.
        self.width = int(width)
        self.n_candidates = 0
        self.n_simulations = 0
        self.errors: list[str] = []  # what failed in a simulation, for the messages
        self.n_failed = 0  # candidates whose simulation failed (dropped)
        self.n_y = len(_output_names(model))

    def controls(self, variables: FloatArray) -> FloatArray:
        """(S, n_t, n_u) control histories of candidate designs (S, n_v)."""
        n_t = self.time.size
        out = np.broadcast_to(self.trim, (variables.shape[0], n_t, self.n_u)).copy()
        for s, v in enumerate(variables):
            try:
                sig = np.asarray(self.maneuver.signal(v, self.time), dtype=np.float64)
            except AeroidError:
                raise
            except Exception as exc:  # the family is the user's code: name it
                raise ModelDefinitionError(
                    f"maneuver {type(self.maneuver).__name__}: signal() raised "
                    f"{type(exc).__name__}: {exc} (for the design {v.tolist()})"
                ) from exc
            if sig.ndim == 1 and len(self.cols) == 1:
                sig = sig[:, None]
            if sig.shape != (n_t, len(self.cols)):
                raise IdentificationError(
                    f"maneuver.signal returned shape {sig.shape}; expected "
                    f"({n_t}, {len(self.cols)}) for controls {list(self.maneuver.controls)}"
                )
            if not np.all(np.isfinite(sig)):
                raise IdentificationError(
                    f"maneuver.signal returned non-finite values for design {v.tolist()}"
                )
            out[s][:, self.cols] += sig
        return out

    def fisher(
        self, variables: FloatArray, *, filler: FloatArray | None = None
    ) -> tuple[FloatArray, NDArray[np.bool_]]:
        """Fisher information (S, n_p, n_p) and success flags of candidates (S, n_v).

        The batch simulated is padded to `width` candidates with copies of the last
        one, or of `filler` where given, and the padding's results are dropped: every
        member is integrated on its own, so a candidate's information does not depend
        on what else is in its batch.
        """
        n = variables.shape[0]
        u = self.controls(variables)
        if self.delays:
            cols, taus = [c for c, _ in self.delays], [tau for _, tau in self.delays]
            u = np.stack([shifted_controls(self.time, us, cols, taus) for us in u])
        if n < self.width:
            extra = u[-1:]
            if filler is not None:
                with contextlib.suppress(IdentificationError):  # a family's bad corner
                    extra = self.controls(filler[None, :])
            u = np.concatenate([u, np.repeat(extra, self.width - n, axis=0)])
        try:
            sens, ok = self._sensitivities(u)
        except SimulationError:
            # dynamics that raise stop the whole batch: fly each candidate on its own,
            # so that only those that fail are dropped, as a non-finite one is
            parts = [self._one(u[s : s + 1]) for s in range(n)]
            sens = np.concatenate([p[0] for p in parts])
            ok = np.concatenate([p[1] for p in parts])
        self.n_candidates += n
        self.n_simulations += n * 2 * len(self.names)
        self.n_failed += int(np.count_nonzero(~ok[:n]))
        return _fisher(sens[:n, ..., self.out_idx], self.sigma), ok[:n]

    def _sensitivities(self, u: FloatArray) -> tuple[FloatArray, NDArray[np.bool_]]:
        _, sens, ok = _fd_sensitivities(
            self.model, self.time, u, self.x0, self.values, self.names, self.steps,
            self.options, nominal=False, errors=self.errors,
        )  # fmt: skip
        return sens, ok

    def _one(self, u: FloatArray) -> tuple[FloatArray, NDArray[np.bool_]]:
        """One candidate's sensitivities and flag; a raised `SimulationError` fails it."""
        try:
            return self._sensitivities(u)
        except SimulationError as exc:
            self.errors.append(str(exc))
            shape = (1, len(self.names), self.time.size, self.n_y)
            return np.full(shape, np.nan), np.zeros(1, dtype=bool)

    def criterion_of(self, fisher: FloatArray, ok: NDArray[np.bool_]) -> FloatArray:
        """Criterion per candidate (lower is better); `_PENALTY` when failed or when the
        information cannot identify the parameters, by the test `_analyse_fisher` applies
        (a null direction of the unit-diagonal matrix): a rank-deficient matrix inverted
        through rounding noise would rank candidates on that noise."""
        fs = fisher * np.outer(self.scale, self.scale)  # information about θ / scale
        out = np.full(fs.shape[0], _PENALTY)
        with np.errstate(all="ignore"):
            d = np.sqrt(np.clip(np.diagonal(fs, axis1=1, axis2=2), 0.0, None))
            live = np.all(d > 1e-300 + NO_EFFECT * d.max(axis=1, keepdims=True), axis=1)
            good = ok & live & np.all(np.isfinite(fs), axis=(1, 2))
            if not np.any(good):
                return out
            dg = d[good]
            fn = fs[good] / (dg[:, :, None] * dg[:, None, :])
            w, v = np.linalg.eigh(0.5 * (fn + np.swapaxes(fn, 1, 2)))
            full = w[:, 0] >= RCOND * np.maximum(w[:, -1], 1e-300)
            if self.criterion == "D":  # -log det fs = -(log det fn + 2 Σ log d)
                val = -(np.sum(np.log(np.abs(w)), axis=1) + 2.0 * np.sum(np.log(dg), axis=1))
            else:  # trace of fs^-1 = Σ_i (fn^-1)_ii / d_i²
                inv_diag = np.einsum("sik,sk->si", v**2, 1.0 / w)
                val = np.sum(inv_diag / dg**2, axis=1)
            keep = full & np.isfinite(val)
            idx = np.flatnonzero(good)[keep]
            out[idx] = val[keep]
        return out

    def __call__(self, variables: FloatArray) -> FloatArray:
        f, ok = self.fisher(variables)
        return self.criterion_of(f, ok)


def _batch_width(opts: Mapping[str, Any], n_variables: int) -> int:
    """Candidates in every batch the design simulates: the largest batch it asks for,
    differential evolution's population (scipy's size: ``popsize`` per variable, at
    least five, or the rows of an array ``init``), or the polish's gradient stencil."""
    init = opts["init"]
    if isinstance(init, str):
        population = max(5, int(opts["popsize"]) * max(1, n_variables))
    else:
        population = int(np.shape(init)[0]) if np.ndim(init) == 2 else 0
    stencil = 2 * n_variables + 1 if opts["polish"] else 0
    return max(population, stencil, 2)


def _polish(
    evaluate: _Evaluator, x: FloatArray, f: float, bounds: FloatArray, maxiter: int = 40
) -> tuple[FloatArray, float]:
    """Bounded L-BFGS-B from the best candidate; each gradient is ONE batched evaluation."""
    lo, hi = bounds[:, 0], bounds[:, 1]
    h = 1e-4 * (hi - lo)
    n = x.size

    def fun(z: FloatArray) -> tuple[float, FloatArray]:
        z = np.clip(z, lo, hi)
        up = np.minimum(z + h, hi)
        dn = np.maximum(z - h, lo)
        cand = np.vstack([z[None, :], np.tile(z, (2 * n, 1))])
        idx = np.arange(n)
        cand[1 + idx, idx] = up
        cand[1 + n + idx, idx] = dn
        vals = evaluate(cand)
        if vals[0] >= _PENALTY:
            return float(vals[0]), np.zeros(n)
        grad = (vals[1 : 1 + n] - vals[1 + n :]) / (up - dn)
        grad[~np.isfinite(grad) | (np.abs(vals[1:1 + n]) >= _PENALTY) | (np.abs(vals[1 + n:]) >= _PENALTY)] = 0.0  # fmt: skip
        return float(vals[0]), grad

    res = scipy.optimize.minimize(
        fun, x, jac=True, method="L-BFGS-B", bounds=list(map(tuple, bounds)),
        options={"maxiter": maxiter},
    )  # fmt: skip
    xr = np.clip(np.asarray(res.x, dtype=np.float64), lo, hi)
    if float(res.fun) < f:
        return xr, float(res.fun)
    return x, f


@small_blas
def design_experiment(
    model: Model | SimulatorModel,
    maneuver: ManeuverFamily,
    parameters: Sequence[str] | str,
    *,
    criterion: str = "D",
    values: Any = None,
    noise: Mapping[str, float] | None = None,
    duration: float,
    sample_rate: float,
    x0: Any = None,
    trim: Mapping[str, float] | None = None,
    seed: int | None = None,
    optimizer_options: Mapping[str, Any] | None = None,
    progress: bool = False,
    relative_step: float = 1e-6,
    simulate_options: Mapping[str, Any] | None = None,
) -> ExperimentDesign:
    """D- or A-optimal manoeuvre design over a manoeuvre family.

    Parameters
    ----------
    model : Model or SimulatorModel
    maneuver : ManeuverFamily
        `Doublet`, `Multisine`, `Chirp` or any object with that interface.
    parameters : sequence of str
        Parameters whose precision the design should maximise.
    criterion : {"D", "A"}
        D: minimise the volume of the Cramér–Rao ellipsoid (``log det`` of
        the relative covariance); A: minimise the sum of relative variances.
        Parameters are scaled by ``|θ|`` (1 at zero) so units do not matter.
    values : mapping or result, optional
        Parameter values to design at (default: nominal), or a result with
        ``.parameters``; an identification result's estimated time delays
        delay its controls, as in `sensitivities` (the designed, recorded
        controls are the commands, undelayed).
    noise : mapping of str to float, optional
        Measurement-noise standard deviation per output used in the design
        (its outputs are the measured ones); default: every output with unit
        noise, so the predicted standard errors are per unit noise.
    duration : float
        Length of the manoeuvre in seconds.
    sample_rate : float
        Sample rate of the design grid in Hz.
    x0 : array_like or mapping, optional
        Initial (trim) state; default zero.
    trim : mapping of str to float, optional
        Constant control values the manoeuvre is flown about (a nonlinear
        model's trim: the thrust, the elevator that holds the trim); the
        manoeuvre adds to its control's value. Default zero for every control
        (a perturbation model).
    seed : int, optional
        Seed of the optimiser; the same seed gives a bit-identical design.
        None draws one from the operating system's entropy and records it on
        the result (``design.seed``), so that the design can be repeated.
        None draws fresh entropy.
    optimizer_options : mapping, optional
        Differential-evolution settings: ``maxiter`` (default 30),
        ``popsize`` (10, times the number of variables), ``tol``, ``atol``,
        ``mutation``, ``recombination``, ``strategy``, ``init``, and
        ``polish`` (bounded L-BFGS-B refinement, default True).
    progress : bool
        Show a progress bar of the generations.
    relative_step : float
        Central-difference step of the sensitivities, relative to ``max(|θ|, 1)``.
    simulate_options : mapping, optional
        Passed to the simulator (for a `Model`: ``method``, ``substeps``,
        ``rtol``, ``atol``; default method ``"auto"``).

    Returns
    -------
    ExperimentDesign

    Raises
    ------
    IdentificationError
        Bad parameters, criterion, noise, grid or optimiser options, or a
        family with no design variables or one that breaks the `ManeuverFamily`
        protocol (a control listed twice, bounds that are not finite
        ``(low, high)`` pairs, an `initial` or `canonical` design of the wrong
        length, an `initial` outside the bounds), naming the method at fault.
    ChannelError
        The family drives a control the model does not have.
    SimulationError
        The model fails to simulate the initial design.

    Warns
    -----
    UserWarning
        When some candidate designs fail to simulate (a non-finite state or
        output, dynamics or a simulator that raise): they cannot be flown and
        are dropped from the search, whatever the failure; the warning counts
        them and names the first failure, the result's ``n_failed`` counts them,
        and the optimum may sit on that edge of what simulates rather than on
        the physics.
    IdentifiabilityWarning
        When even the best design cannot identify every parameter: the
        message names the parameter combinations the manoeuvre cannot
        separate, their predicted standard errors are infinite and the
        result has ``success=False``.
    """
    require_model(model, IdentificationError)
    if not isinstance(maneuver, ManeuverFamily):
        raise IdentificationError(
            "maneuver: expected a ManeuverFamily (Doublet, Multisine, Chirp or an object with "
            f"controls, variable_names, bounds, initial, signal, describe), got "
            f"{type(maneuver).__name__}"
        )
    if parameters is None:
        raise IdentificationError("parameters: name the parameters the design should target")
    names = _parameter_list(model, parameters)
    if criterion not in _CRITERIA:
        raise IdentificationError(
            f"criterion: expected one of {list(_CRITERIA)}, got {criterion!r}"
        )
    vals = resolve_parameters(model, values, error=IdentificationError)
    options = _check_simulate_options(simulate_options, model)
    opts = optimizer_settings(optimizer_options)
    dur, fs = as_float(duration), as_float(sample_rate)
    if dur is None or fs is None:
        raise IdentificationError(
            f"duration and sample_rate: expected numbers, got {duration!r}, {sample_rate!r}"
        )
    if not (np.isfinite(dur) and dur > 0 and np.isfinite(fs) and fs > 0):
        raise IdentificationError(
            f"duration and sample_rate must be positive, got {duration!r}, {sample_rate!r}"
        )
    n_t = round(dur * fs) + 1
    if n_t < 3:
        raise IdentificationError(f"duration * sample_rate gives {n_t} samples; need at least 3")
    if n_t > _MAX_SAMPLES:  # every candidate is simulated on this grid, all at once
        raise IdentificationError(
            f"duration * sample_rate gives {n_t} samples; at most {_MAX_SAMPLES} are supported"
        )
    rel = _relative_step(relative_step)
    check_flag(progress, "progress", IdentificationError)
    if check_seed(seed, IdentificationError) is None:
        # fresh entropy, recorded on the result so that the design can be repeated
        seed = int(np.random.SeedSequence().generate_state(1)[0])
    time = np.arange(n_t) / fs
    all_outputs = _output_names(model)
    if noise is None:
        outs = list(all_outputs)
        sigma = np.ones(len(outs))
    else:
        _check_noise_names(noise, all_outputs, model.name)
        outs = [o for o in all_outputs if o in noise]
        if not outs:
            raise IdentificationError("noise: give a standard deviation for at least one output")
        sigma = _noise_vector(noise, outs)
    out_idx = [all_outputs.index(o) for o in outs]
    controls = _control_names(model)
    missing = [c for c in family_controls(maneuver) if c not in controls]
    if missing:
        raise ChannelError(
            f"maneuver drives {missing}, which are not controls of model {model.name!r}; "
            f"controls: {list(controls)}"
        )
    trims = trim_vector(trim, controls, model.name)
    top = getattr(maneuver, "highest_frequency", lambda: None)()
    if top is not None and top >= fs / 2:  # it would alias onto a lower line
        raise IdentificationError(
            f"maneuver {maneuver!r}: its frequencies reach {top:g} Hz, at or above the "
            f"Nyquist frequency {fs / 2:g} Hz of sample_rate {fs:g} Hz"
        )
    bounds, var_names = family_bounds(maneuver)
    batch_width = _batch_width(opts, len(var_names)) if isinstance(model, Model) else 0
    # differential evolution scores its whole population in one batched simulation
    members = max(int(opts["popsize"]) * len(var_names), batch_width) * (2 * len(names) + 1)
    width = len(all_outputs) + (model.n_states if isinstance(model, Model) else 0)
    if members * n_t * max(width, 1) > _MAX_BATCH_VALUES:
        raise IdentificationError(
            f"duration * sample_rate: {n_t} samples for {members} simulations at once "
            f"(popsize {opts['popsize']}) would not fit in memory; use fewer samples or a "
            "smaller optimizer_options['popsize']"
        )
    if isinstance(model, Model) and x0 is not None:
        x0 = model.initial_state(x0, 1)[0]
    x_init = family_vector(maneuver, "initial", maneuver.initial, bounds, inside=True)

    evaluate = _Evaluator(
        model, maneuver, time, x0, vals, names, sigma, out_idx, criterion, options, rel,
        trims, batch_width, control_delays(model, values, error=IdentificationError),
    )  # fmt: skip
    # padded with another design (a corner of the bounds): a batch of one control history
    # repeated is simulated as a shared history, by a compiled program of its own
    corner = np.where(x_init == bounds[:, 0], bounds[:, 1], bounds[:, 0])
    _, ok_init = evaluate.fisher(x_init[None, :], filler=corner)
    if not ok_init[0]:
        why = f": {evaluate.errors[-1]}" if evaluate.errors else ""
        raise SimulationError(
            f"design_experiment: model {model.name!r} fails to simulate the initial design "
            f"{dict(zip(var_names, x_init.tolist(), strict=True))}{why}"
        )

    from .._progress import progress_bar

    bar = progress_bar(int(opts["maxiter"]), desc="design_experiment", enabled=progress, unit="gen")

    generations = 0

    def callback(intermediate_result: Any) -> None:
        nonlocal generations
        generations += 1
        if bar is not None:
            bar.update(1)
            bar.set_postfix(criterion=f"{float(intermediate_result.fun):.4g}")

    def func(x: FloatArray) -> FloatArray:
        return evaluate(np.atleast_2d(x.T))  # scipy passes (n_v, S)

    try:
        res = scipy.optimize.differential_evolution(
            func,
            list(map(tuple, bounds)),
            strategy=opts["strategy"],
            maxiter=int(opts["maxiter"]),
            popsize=int(opts["popsize"]),
            tol=float(opts["tol"]),
            atol=float(opts["atol"]),
            mutation=opts["mutation"],
            recombination=float(opts["recombination"]),
            rng=np.random.default_rng(seed),
            callback=callback,
            polish=False,
            init=opts["init"],
            x0=x_init,
            updating="deferred",
            vectorized=True,
        )
    except (ValueError, TypeError) as exc:
        if isinstance(exc, AeroidError):  # ours (a bad design, a model that misbehaves)
            raise
        raise IdentificationError(f"optimizer_options: rejected by the optimiser: {exc}") from None
    finally:
        if bar is not None:
            bar.close()
    x_best = np.clip(np.asarray(res.x, dtype=np.float64), bounds[:, 0], bounds[:, 1])
    f_best = float(res.fun)
    if f_best >= _PENALTY:  # no candidate identifies: none beats the reference design
        x_best = x_init
    elif opts["polish"]:
        x_best, f_best = _polish(evaluate, x_best, f_best, bounds)
    canon = getattr(maneuver, "canonical", None)
    if callable(canon):
        x_best = family_vector(
            maneuver, "canonical", lambda: canon(x_best, time), bounds, inside=False
        )
        x_init_c = family_vector(
            maneuver, "canonical", lambda: canon(x_init, time), bounds, inside=False
        )
    else:
        x_init_c = x_init
    fis, ok = evaluate.fisher(np.vstack([x_best, x_init]))
    crit = evaluate.criterion_of(fis, ok)
    crit = np.where(crit >= _PENALTY, np.inf, crit)
    cov, combos, _ = _analyse_fisher(fis[0], names)
    cov0, _, _ = _analyse_fisher(fis[1], names)
    se = dict(zip(names, _crb(cov).tolist(), strict=True))
    se0 = dict(zip(names, _crb(cov0).tolist(), strict=True))
    description = maneuver.describe(x_best, time)
    u = evaluate.controls(x_best[None, :])[0]
    success = bool(np.isfinite(crit[0])) and not combos
    message = (
        "Optimiser finished: " + str(res.message)
        if success
        else "No design in the bounds identifies all parameters."
    )
    if combos or not success:
        # Degeneracy is loud: a design that cannot identify a parameter is flagged
        # (success=False) and named, not returned as if it were merely imprecise.
        what = _combo_text(combos) if combos else ", ".join(n for n in names if not se[n] < np.inf)
        message += f" The best design found cannot separate {what or 'the parameters'}."
        warnings.warn(
            f"design_experiment: no design of {description} within the "
            f"bounds can separate {what or 'the parameters'}; their predicted standard "
            "errors are infinite and the design is flagged success=False",
            IdentifiabilityWarning,
            stacklevel=CALLER_STACKLEVEL,
        )
    if evaluate.n_failed:
        warnings.warn(
            f"design_experiment: {evaluate.n_failed} of {evaluate.n_candidates} candidate "
            f"designs failed to simulate and were dropped (first: {evaluate.errors[0]}); "
            "the design found may sit on the edge of what the model can fly rather than on "
            "the physics",
            UserWarning,
            stacklevel=CALLER_STACKLEVEL,
        )
    return ExperimentDesign(
        design=dict(zip(var_names, x_best.tolist(), strict=True)),
        initial_design=dict(zip(var_names, np.asarray(x_init_c).tolist(), strict=True)),
        variable_names=var_names,
        bounds=bounds,
        time=time,
        controls=u,
        control_names=controls,
        parameter_names=tuple(names),
        values=vals,
        noise=dict(zip(outs, sigma.tolist(), strict=True)),
        criterion=criterion,
        criterion_value=float(crit[0]),
        initial_criterion_value=float(crit[1]),
        predicted_stderr=se,
        initial_stderr=se0,
        fisher_information=fis[0],
        recommendation=_recommendation(description, names, se, se0),
        maneuver=description,
        n_generations=generations,
        n_candidates=evaluate.n_candidates,
        n_simulations=evaluate.n_simulations,
        success=success,
        message=message,
        seed=seed,
        model_name=str(model.name),
        n_failed=evaluate.n_failed,
    )


def _recommendation(
    description: str, names: Sequence[str], se: Mapping[str, float], se0: Mapping[str, float]
) -> str:
    text = f"designed {description}"
    if not all(np.isfinite(se[n]) for n in names):
        bad = [n for n in names if not np.isfinite(se[n])]
        return f"{text}; even this design cannot identify {', '.join(bad)} — widen the bounds"
    unident = [n for n in names if not np.isfinite(se0[n])]
    if unident:
        return (
            f"{text}; the initial design could not identify {', '.join(unident)}, the designed "
            "one can"
        )
    ratios = {n: se0[n] / se[n] for n in names if se[n] > 0}
    best = max(ratios, key=lambda n: ratios[n])
    if ratios[best] <= 1.0 + 1e-9:
        return f"{text}; no improvement over the initial design was found"
    return (
        f"{text}; predicted stderr improves {ratios[best]:.2g}x over the initial design for {best}"
    )
