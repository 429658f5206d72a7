"""The log-posterior that `aeroid.infer` samples: priors, batched likelihood, start.

Split out of `aeroid.uncertainty.inference` (which re-exports every name): the problem
(parameters, noise levels, priors, simulation options and backend) and the
starting ball of the walkers.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from functools import partial
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._threads import quiet_warnings
from ..errors import InferenceError, SimulationError
from ..io.data import FlightData, as_float, measured_start
from ..models.model import (
    SIMULATE_OPTION_KEYS,
    BatchSimulator,
    Model,
    check_integrator,
    check_simulate_options,
    require_model,
    simulator_outputs,
)
from .priors import LogUniform, Prior

FloatArray = NDArray[np.float64]

#: Default noise prior: LogUniform(NOISE_LO * s, NOISE_HI * s), s = RMS of the output about its mean.
NOISE_LO = 1e-6
NOISE_HI = 10.0
# Starting balls: fraction of the identification stderr, of the prior scale, of a noise level.
_BALL_STDERR = 0.5
_BALL_PRIOR = 0.01
_BALL_NOISE = 0.05
_SIM_OPTIONS = SIMULATE_OPTION_KEYS
_JAX_OPTIONS = ("substeps", "control_interpolation")
_BACKENDS = ("numpy", "jax")


class _StartFailure(SimulationError, InferenceError):
    """The model gives non-finite values at the starting point of the walkers.

    A `SimulationError` like every such failure, and an `InferenceError` as
    `infer` raised before for a start where every simulation failed.
    """


class _Posterior:
    """Log-posterior of a batch of parameter vectors for one model and record."""

    def __init__(
        self,
        model: Any,
        data: FlightData,
        parameters: Mapping[str, Prior],
        *,
        outputs: Sequence[str] | None,
        noise: Mapping[str, float] | None,
        x0: Any,
        backend: str,
        simulate_options: Mapping[str, Any] | None,
    ) -> None:
        if not isinstance(data, FlightData):
            raise InferenceError(f"data: expected aeroid.FlightData, got {type(data).__name__}")
        require_model(model, InferenceError)
        self.batched = isinstance(model, Model)
        if backend not in _BACKENDS:
            raise InferenceError(f"backend: expected one of {list(_BACKENDS)}, got {backend!r}")
        if backend == "jax" and not self.batched:
            raise InferenceError(
                f"backend='jax' needs an aeroid.Model with a continuous dynamics callable; "
                f"model {getattr(model, 'name', '?')!r} is a stepped simulator "
                f"({type(model).__name__}); use backend='numpy'"
            )
        self.model = model
        self.backend = backend
        self.model_name = str(getattr(model, "name", ""))
        model_outputs = tuple(model.output_names if self.batched else model.outputs)

        # outputs entering the likelihood
        if outputs is None:
            outs = model_outputs
        else:
            outs = (outputs,) if isinstance(outputs, str) else tuple(outputs)
            bad = [o for o in outs if o not in model_outputs]
            if bad or not outs or len(set(outs)) != len(outs):
                raise InferenceError(
                    f"outputs: expected distinct names among the model's outputs "
                    f"{list(model_outputs)}, got {list(outs)}"
                )
        data.require(outs, role="output")
        self.output_names = outs
        self.out_index = np.array([model_outputs.index(o) for o in outs], dtype=np.int64)
        self.time = np.array(data.time)
        self.y = data.array(list(outs)).astype(np.float64)  # (n_t, n_y)
        self.data = data

        # parameters and priors
        if not isinstance(parameters, Mapping) or not parameters:
            raise InferenceError(
                "parameters: expected a non-empty dict of parameter name -> prior, e.g. "
                "{'M_alpha': aeroid.Normal(-4, 2)}"
            )
        model_params = dict(model.parameters)
        given_noise = self._check_noise(noise, outs)
        noise_name = {o: f"sigma_{o}" for o in outs if o not in given_noise}
        clash = sorted(n for n in noise_name.values() if n in model_params)
        if clash:
            raise InferenceError(
                f"noise parameter names {clash} clash with model parameters; give the noise "
                "of those outputs with noise={...}"
            )
        valid = [*model_params, *noise_name.values()]
        names: list[str] = []
        priors: list[Prior] = []
        for name, prior in parameters.items():
            if name not in valid:
                hint = ""
                if name.startswith("sigma_") and name[6:] in given_noise:
                    hint = f" (the noise of {name[6:]!r} is given with noise=)"
                raise InferenceError(
                    f"parameters: {name!r} is neither a parameter of model {self.model_name!r} "
                    f"nor an estimated noise level{hint}; valid names: {valid}"
                )
            if not isinstance(prior, Prior):
                raise InferenceError(
                    f"parameters[{name!r}]: expected a prior (aeroid.Normal, Uniform, "
                    f"LogUniform, HalfNormal or a Prior subclass), got {prior!r}"
                )
            names.append(name)
            priors.append(prior)
        for o, n in noise_name.items():
            if n not in names:
                names.append(n)
                priors.append(_default_noise_prior(self.y[:, outs.index(o)]))
        self.names = tuple(names)
        self.priors = tuple(priors)
        self.n_dim = len(names)
        self.model_cols = [(n, i) for i, n in enumerate(names) if n in model_params]
        self.noise_parameters = tuple(n for n in names if n not in model_params)
        # per output: column of theta holding its sigma, or -1 with a fixed value
        self.sigma_col = np.array(
            [names.index(noise_name[o]) if o in noise_name else -1 for o in outs], dtype=np.int64
        )
        self.sigma_fixed = np.array([given_noise.get(o, np.nan) for o in outs])
        self.noise = given_noise
        self.fixed = {k: v for k, v in model_params.items() if k not in names}
        self.n_t = self.time.size
        self.const = 0.5 * self.n_t * len(outs) * math.log(2.0 * math.pi)

        # simulation set-up
        if simulate_options is not None and not isinstance(simulate_options, Mapping):
            raise InferenceError(
                f"simulate_options: expected a dict, got {type(simulate_options).__name__}"
            )
        opts = dict(simulate_options or {})
        if self.batched:
            allowed = _JAX_OPTIONS if backend == "jax" else _SIM_OPTIONS
            unknown = sorted(set(opts) - set(allowed))
            if unknown:
                raise InferenceError(
                    f"simulate_options: unknown options {unknown} for backend {backend!r}; "
                    f"valid: {list(allowed)}"
                )
            data.require(model.controls, role="control")
            self.controls = model.control_array(self.time, data)[0]
            if x0 is None:
                x0 = measured_start(data, model.states)
            self.x0 = model.initial_state(x0, 1)[0]
            if backend == "numpy":
                opts.setdefault("method", "auto")
                # here, naming the option: in the likelihood a bad one is a rejected member
                check_simulate_options(opts, model, InferenceError)
            else:
                from ..models.integration import check_control_interpolation

                check_control_interpolation(
                    opts.get("control_interpolation", "linear"),
                    InferenceError,
                    "simulate_options['control_interpolation']",
                    model.controls,
                )
            if backend == "jax" and opts.get("substeps") is not None:
                check_integrator(
                    "rk4",
                    opts["substeps"],
                    1e-9,
                    1e-12,
                    error=InferenceError,
                    prefix="simulate_options",
                )
            if opts.get("substeps") is None and opts.get("method", "auto") in ("auto", "rk4"):
                found = _path_substeps(model, self.time, self.controls, self.x0)
                if found is not None:  # the sampler's programs read the modes at the start
                    opts["substeps"] = found
        else:
            self.x0 = x0
        self.options = opts
        self.last_error: Exception | None = None
        self._jax_batch: int | None = None
        # the record's simulation, checked once (the sampler's thousands of calls pay none)
        self._simulator: BatchSimulator | None = None
        if self.batched and backend == "numpy":
            self._simulator = BatchSimulator(model, self.time, self.controls, self.x0, **opts)

    def expect(self, calls: int) -> None:
        """Tell the simulation how many batches the sampler will score: enough of them
        compile the model's RK4 from the first (`BatchSimulator`)."""
        if self._simulator is not None:
            self._simulator.repeated = int(calls)

    @staticmethod
    def _check_noise(noise: Mapping[str, float] | None, outs: tuple[str, ...]) -> dict[str, float]:
        if noise is None:
            return {}
        if not isinstance(noise, Mapping):
            raise InferenceError(
                f"noise: expected a dict of output -> standard deviation, got {noise!r}"
            )
        out: dict[str, float] = {}
        for k, v in noise.items():
            if k not in outs:
                raise InferenceError(
                    f"noise: {k!r} is not an output in the likelihood; outputs: {list(outs)}"
                )
            s = as_float(v)
            if s is None or not (s > 0.0 and math.isfinite(s)):
                raise InferenceError(f"noise[{k!r}]: expected a standard deviation > 0, got {v!r}")
            out[str(k)] = s
        return out

    # -- simulation of a batch ------------------------------------------------------------
    def simulate(self, params: Mapping[str, FloatArray], batch: int) -> FloatArray:
        """Outputs (batch, n_t, n_y) of the likelihood's outputs; failed members are NaN."""
        with quiet_warnings(), np.errstate(all="ignore"):
            if not self.batched:
                return self._loop(params, batch)
            if self.backend == "jax":
                return self._jax(params, batch)
            try:
                return self._numpy(params)
            except Exception as exc:  # one bad member must not sink the batch
                self.last_error = exc
                if batch == 1:
                    return np.full((1, self.n_t, len(self.output_names)), np.nan)
            rows = []
            for b in range(batch):
                one = {k: v[b : b + 1] for k, v in params.items()}
                try:
                    rows.append(self._numpy(one)[0])
                except Exception as exc:
                    self.last_error = exc
                    rows.append(np.full((self.n_t, len(self.output_names)), np.nan))
            return np.stack(rows)

    def _numpy(self, params: Mapping[str, FloatArray]) -> FloatArray:
        assert self._simulator is not None
        return self._simulator.outputs(params, self.out_index)

    def _jax(self, params: Mapping[str, FloatArray], batch: int) -> FloatArray:
        from ..models import jax_compiled as _jax

        # pad to one batch size so the vmapped rollout compiles once
        size = self._jax_batch = max(self._jax_batch or 0, batch)
        padded = {k: np.concatenate([v, np.repeat(v[:1], size - batch)]) for k, v in params.items()}
        y = _jax.batch_outputs(
            self.model,
            self.time,
            self.controls,
            self.x0,
            padded,
            substeps=self.options.get("substeps"),
            control_interpolation=self.options.get("control_interpolation", "linear"),
        )
        return np.asarray(y)[:batch][:, :, self.out_index]

    def _run(self, values: Mapping[str, float]) -> Any:
        return self.model.simulate_data(self.data, x0=self.x0, parameters=values, **self.options)

    def _loop(self, params: Mapping[str, FloatArray], batch: int) -> FloatArray:
        out = np.full((batch, self.n_t, len(self.output_names)), np.nan)
        for b in range(batch):
            p = {k: float(v[b]) for k, v in params.items()}
            try:
                y = simulator_outputs(self.model, partial(self._run, p), self.n_t)
                out[b] = y[:, [list(self.model.outputs).index(o) for o in self.output_names]]
            except Exception as exc:  # a failing member is a rejected proposal
                self.last_error = exc
        return out

    # -- densities ------------------------------------------------------------------------
    def log_prior(self, theta: FloatArray) -> FloatArray:
        lp = np.zeros(theta.shape[0])
        with np.errstate(all="ignore"):
            for i, prior in enumerate(self.priors):
                lp = lp + np.asarray(prior.log_pdf(theta[:, i]), dtype=np.float64)
        return np.where(np.isfinite(lp), lp, -np.inf)

    def sigmas(self, theta: FloatArray) -> FloatArray:
        sig = np.broadcast_to(self.sigma_fixed, (theta.shape[0], self.sigma_fixed.size)).copy()
        est = self.sigma_col >= 0
        sig[:, est] = theta[:, self.sigma_col[est]]
        return sig

    def log_likelihood(self, theta: FloatArray) -> FloatArray:
        batch = theta.shape[0]
        params = {n: np.ascontiguousarray(theta[:, i]) for n, i in self.model_cols}
        y = self.simulate(params, batch)
        with np.errstate(all="ignore"):
            r = y - self.y[None]
            ss = np.einsum("btj,btj->bj", r, r)
            sig = self.sigmas(theta)
            ll = -self.n_t * np.log(sig).sum(axis=1) - 0.5 * (ss / sig**2).sum(axis=1)
            ll = ll - self.const
        return np.where(np.isfinite(ll) & np.all(sig > 0, axis=1), ll, -np.inf)

    def __call__(self, theta: FloatArray) -> FloatArray:
        theta = np.asarray(theta, dtype=np.float64)
        lp = self.log_prior(theta)
        good = np.flatnonzero(np.isfinite(lp))
        if good.size:
            lp[good] = lp[good] + self.log_likelihood(theta[good])
        return np.where(np.isfinite(lp), lp, -np.inf)

    # -- starting points --------------------------------------------------------------------
    def require_simulates(self, center: FloatArray) -> None:
        """Raise `SimulationError` (naming the state or output and the time) when the
        model gives non-finite values at the starting point; a walker elsewhere that
        fails is only a rejected point."""
        if not self.batched:
            return
        values = {n: np.array([center[i]]) for n, i in self.model_cols}
        size = self._jax_batch or 1
        if self._simulator is not None and size > 1:
            # a batch of the sampler's size: the program it runs, compiled once for both
            many = {n: np.repeat(v, size) for n, v in values.items()}
            with quiet_warnings(), np.errstate(all="ignore"):
                if np.all(np.isfinite(self._simulator.outputs(many, self.out_index)[0])):
                    return
        res = self.model.simulate_batch(
            self.time, self.controls, self.x0, values, **{"method": "auto", **self.options}
        )
        if not res.ok[0]:
            start = {n: float(center[i]) for n, i in self.model_cols}
            raise _StartFailure(
                f"infer: model {self.model.name!r} cannot be simulated at the starting point "
                f"{start}: {res.failure[0]}"
            )

    def residuals(self, values: Mapping[str, float]) -> FloatArray:
        """Residuals (n_t, n_y) at one parameter set (NaN where the simulation fails)."""
        params = {n: np.array([values[n]]) for n, _ in self.model_cols}
        return np.asarray(self.simulate(params, 1)[0] - self.y)

    def residual_rms(self, values: Mapping[str, float]) -> FloatArray:
        """RMS residual per output at one parameter set (NaN where the simulation fails)."""
        params = {n: np.array([values[n]]) for n, _ in self.model_cols}
        y = self.simulate(params, 1)[0]
        with np.errstate(all="ignore"):
            return np.asarray(np.sqrt(np.mean((y - self.y) ** 2, axis=0)))

    def start_ball(self, initial: Any) -> tuple[FloatArray, FloatArray]:
        """Centre (n_dim,) and a square-root covariance (n_dim, n_dim) of the starting ball."""
        center = np.full(self.n_dim, np.nan)
        root = np.zeros((self.n_dim, self.n_dim))
        names = self.names
        model_names = [n for n, _ in self.model_cols]
        if initial is None:
            given: dict[str, float] = {}
            for n in model_names:
                nominal = float(self.model.parameters[n])
                prior = self.priors[names.index(n)]
                given[n] = nominal if np.isfinite(prior.log_pdf(nominal)) else prior.center
        elif isinstance(initial, Mapping):
            given = {}
            for k, v in initial.items():
                if k not in names:
                    raise InferenceError(
                        f"initial: {k!r} is not an inferred parameter; inferred: {list(names)}"
                    )
                value = as_float(v)
                if value is None:
                    raise InferenceError(f"initial[{k!r}]: expected a number, got {v!r}")
                given[k] = value
                if not math.isfinite(value):
                    raise InferenceError(f"initial[{k!r}]: value {v!r} is not finite")
        elif hasattr(initial, "parameters"):
            given = self._from_fit(initial, center, root)
        else:
            raise InferenceError(
                "initial: expected None, a dict of starting values, an identification result "
                f"or an InferenceResult to continue, got {type(initial).__name__}"
            )
        for n, v in given.items():
            i = names.index(n)
            center[i] = v
            if root[i, i] == 0.0:
                prior = self.priors[i]
                if n in self.noise_parameters:
                    root[i, i] = _BALL_NOISE * abs(v)
                else:
                    root[i, i] = _BALL_PRIOR * prior.scale
        # model parameters nobody gave: the prior's centre
        for i, n in enumerate(names):
            if n not in self.noise_parameters and not np.isfinite(center[i]):
                center[i] = self.priors[i].center
                root[i, i] = _BALL_PRIOR * self.priors[i].scale
        # noise levels nobody gave: the residual RMS at the centre
        missing = [
            i for i, n in enumerate(names) if n in self.noise_parameters and np.isnan(center[i])
        ]
        if missing:
            values = {n: center[i] for n, i in self.model_cols}
            rms = self.residual_rms(values)
            for i in missing:
                j = int(np.flatnonzero(self.sigma_col == i)[0])
                s = float(rms[j])
                if not (s > 0.0 and math.isfinite(s)):
                    s = float(np.std(self.y[:, j])) or 1.0
                lo, hi = self.priors[i].support
                s = min(max(s, lo), hi)
                center[i] = s
                root[i, i] = _BALL_NOISE * s
        # a degenerate ball cannot be stretched open: give every direction some width
        for i in range(self.n_dim):
            if not root[i, i] > 0.0:
                root[i, i] = _BALL_PRIOR * (abs(center[i]) or 1.0)
        return center, root

    def _from_fit(self, fit: Any, center: FloatArray, root: FloatArray) -> dict[str, float]:
        """Centre on a fit's estimates, ball from its covariance (or standard errors)."""
        values = fit.parameters if isinstance(fit.parameters, Mapping) else {}
        stderr = getattr(fit, "stderr", {}) or {}
        given: dict[str, float] = {}
        idx: list[int] = []
        for i, n in enumerate(self.names):
            if n in values and math.isfinite(float(values[n])):
                given[n] = float(values[n])
                center[i] = given[n]
                idx.append(i)
        # covariance block of the parameters the fit estimated
        cov = getattr(fit, "covariance", None)
        fit_names = tuple(getattr(fit, "parameter_names", ()))
        sub = [n for n in (self.names[i] for i in idx) if n in fit_names]
        done = False
        if cov is not None and sub and len(sub) == len(idx):
            c = np.asarray(cov, dtype=np.float64)
            if c.shape == (len(fit_names), len(fit_names)):
                cols = [fit_names.index(n) for n in sub]
                block = c[np.ix_(cols, cols)]
                try:
                    chol = np.linalg.cholesky(block)
                    if np.all(np.isfinite(chol)):
                        root[np.ix_(idx, idx)] = _BALL_STDERR * chol
                        done = True
                except np.linalg.LinAlgError:
                    pass
        if not done:
            for i in idx:
                s = stderr.get(self.names[i], np.nan) if isinstance(stderr, Mapping) else np.nan
                s = float(s)
                if s > 0 and math.isfinite(s):
                    root[i, i] = _BALL_STDERR * s
        # noise levels from the fit's noise covariance (variances)
        noise_cov = getattr(fit, "noise_covariance", None)
        fit_outs = tuple(getattr(fit, "output_names", ()))
        if noise_cov is not None and fit_outs:
            nc = np.asarray(noise_cov, dtype=np.float64)
            for j, o in enumerate(self.output_names):
                col = int(self.sigma_col[j])
                if col < 0 or self.names[col] in given or o not in fit_outs:
                    continue
                k = fit_outs.index(o)
                if nc.ndim == 2 and nc.shape[0] > k and nc[k, k] > 0 and math.isfinite(nc[k, k]):
                    s = math.sqrt(float(nc[k, k]))
                    given[self.names[col]] = s
                    center[col] = s
                    # a standard deviation estimated from n_t residuals is good to 1/sqrt(2 n_t)
                    root[col, col] = max(s / math.sqrt(2.0 * self.n_t), 1e-3 * s)
        return given

    def draw_start(
        self, rng: np.random.Generator, n_walkers: int, center: FloatArray, root: FloatArray
    ) -> tuple[FloatArray, FloatArray]:
        """Walkers in the ball; walkers at impossible points are redrawn a few times."""
        x = center + rng.standard_normal((n_walkers, self.n_dim)) @ root.T
        lp = self._score(x)  # in the batches the sampler will score
        shrink = 1.0
        for _ in range(10):
            bad = np.flatnonzero(~np.isfinite(lp))
            if bad.size == 0:
                break
            shrink *= 0.5
            x[bad] = center + shrink * rng.standard_normal((bad.size, self.n_dim)) @ root.T
            lp[bad] = self._score(x[bad])
        return x, lp

    def _score(self, theta: FloatArray) -> FloatArray:
        half = max(1, self._jax_batch or theta.shape[0])
        return np.concatenate([self(theta[i : i + half]) for i in range(0, theta.shape[0], half)])


def _default_noise_prior(y: FloatArray) -> Prior:
    s = float(np.sqrt(np.mean((y - y.mean()) ** 2)))
    if not (s > 0.0 and math.isfinite(s)):
        s = 1.0
    return LogUniform(NOISE_LO * s, NOISE_HI * s)


def _path_substeps(model: Any, time: FloatArray, controls: FloatArray, x0: Any) -> int | None:
    """The RK4 substeps the model's path at its nominal parameters asks for, where that is
    more than the rule at its start gives (`integration.path_substeps`), else None."""
    from ..models import integration as _integrate

    if getattr(model, "linear", None) is True or not hasattr(model, "_dynamics_batch"):
        return None
    member = {k: np.array([float(v)]) for k, v in model.parameters.items()}
    x = np.asarray(x0, dtype=np.float64).reshape(-1, 1)
    u = np.asarray(controls, dtype=np.float64)[None]
    with np.errstate(all="ignore"):
        return _integrate.path_substeps(model._dynamics_batch, time, x, u, member)
