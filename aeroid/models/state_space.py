"""The matrices ``[A B c]`` and ``[C D d]`` of a state-space model as functions of
its parameters, for frequency-domain identification (`aeroid.frequency.frequency_domain`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import IdentificationError
from ..io.data import plain
from . import integration as _integrate

FloatArray = NDArray[np.float64]


class StateSpace:
    """``[A B c]`` and ``[C D d]`` (selected outputs) for a batch of parameter vectors.

    A model shown linear time-invariant on the record's time grid (or declared
    so) gives them by `lti_form`; any other model is linearised by central
    differences about a reference state and control.
    """

    def __init__(
        self,
        model: Any,
        names: list[str],
        base: Mapping[str, float],
        time: FloatArray,
        rows: list[int] | None,
        reference: tuple[FloatArray, FloatArray],
    ) -> None:
        self.model = model
        self.names = names
        self.base = dict(base)
        self.n_x, self.n_u = model.n_states, model.n_controls
        self.rows = rows
        self.t0 = float(time[0])
        self.x_ref, self.u_ref = reference
        self._basis: Any = None  # None: unchecked; False: not affine; else the basis
        p1 = {k: np.array([v]) for k, v in self.base.items()}
        self.linear = True
        funs = [model._dynamics_batch]
        if rows is not None and model._measurement_batch is not None:
            funs.append(model._measurement_batch)
        for fun in funs:
            mats, not_lti = _integrate.lti_form(
                fun, time, self.n_x, self.n_u, p1, trusted=bool(model.linear)
            )
            if mats is None:
                if not not_lti:
                    raise IdentificationError(
                        f"the {fun.role} of model {model.name!r} could not be evaluated (an "
                        "exception or a non-finite value) at the initial parameters"
                    )
                self.linear = False

    def _linearised(self, fun: Any, P: Mapping[str, FloatArray]) -> FloatArray:
        batch = next(iter(P.values())).shape[0]
        n_in = self.n_x + self.n_u
        z = np.concatenate([self.x_ref, self.u_ref])
        h = 1e-6 * np.maximum(1.0, np.abs(z))
        pts = np.repeat(z[:, None], 1 + 2 * n_in, axis=1)
        pts[:, 1 : 1 + n_in] += np.diag(h)
        pts[:, 1 + n_in :] -= np.diag(h)
        Z = np.repeat(pts, batch, axis=1)  # point-major, member-minor
        PP = {k: np.tile(v, 1 + 2 * n_in) for k, v in P.items()}
        with np.errstate(all="ignore"):
            out = fun(self.t0, Z[: self.n_x], Z[self.n_x :], PP)
        vals = out.reshape(fun.n_out, 1 + 2 * n_in, batch)
        if not np.all(np.isfinite(vals)):
            raise IdentificationError(
                f"the {fun.role} of model {self.model.name!r} is not finite near the reference "
                "point of its linearisation"
            )
        jac = (vals[:, 1 : 1 + n_in] - vals[:, 1 + n_in :]) / (2 * h[None, :, None])
        M = np.empty((batch, fun.n_out, n_in + 1))
        M[:, :, :n_in] = np.transpose(jac, (2, 0, 1))
        M[:, :, n_in] = vals[:, 0, :].T - np.einsum("bij,j->bi", M[:, :, :n_in], z)
        return M

    def _form(self, fun: Any, P: Mapping[str, FloatArray]) -> FloatArray:
        if not self.linear:
            return self._linearised(fun, P)
        mats, _ = _integrate.lti_form(fun, np.array([self.t0]), self.n_x, self.n_u, P, trusted=True)
        if mats is None:
            raise IdentificationError(
                f"the {fun.role} of model {self.model.name!r} could not be evaluated (an "
                "exception or a non-finite value) at the parameters "
                f"{plain({k: v.tolist() for k, v in P.items() if k in self.names})}"
            )
        a, b, c = mats
        return np.concatenate([a, b, c[:, :, None]], axis=2)

    def matrices(self, values: FloatArray) -> tuple[FloatArray, FloatArray | None]:
        """``[A B c]`` (batch, n_x, n_x + n_u + 1) and ``[C D d]`` of the selected outputs."""
        values = np.atleast_2d(values)
        batch = values.shape[0]
        P = {k: np.full(batch, v) for k, v in self.base.items()}
        for j, n in enumerate(self.names):
            P[n] = values[:, j].copy()
        F = self._form(self.model._dynamics_batch, P)
        if self.rows is None:
            return F, None
        if self.model._measurement_batch is None:
            H = np.zeros((batch, len(self.rows), F.shape[2]))
            for i, r in enumerate(self.rows):
                H[:, i, r] = 1.0
            return F, H
        H = self._form(self.model._measurement_batch, P)[:, self.rows, :]
        return F, H

    def _central(
        self, p: FloatArray
    ) -> tuple[FloatArray, FloatArray | None, FloatArray, FloatArray | None]:
        n_p = p.size
        h = 1e-4 * np.maximum(1.0, np.abs(p))
        batch = np.repeat(p[None, :], 1 + 2 * n_p, axis=0)
        batch[1 : 1 + n_p] += np.diag(h)
        batch[1 + n_p :] -= np.diag(h)
        F, H = self.matrices(batch)
        dF = (F[1 : 1 + n_p] - F[1 + n_p :]) / (2 * h[:, None, None])
        dH = None if H is None else (H[1 : 1 + n_p] - H[1 + n_p :]) / (2 * h[:, None, None])
        return F[0], None if H is None else H[0], dF, dH

    def affine(self, p0: FloatArray) -> bool:
        """Whether the matrices are affine in the parameters, checked once about `p0`.

        Then they are ``M(p) = M(p0) + Σ (p − p0)_l ∂M/∂p_l`` everywhere, and no
        model function is evaluated again.
        """
        if self._basis is None:
            F0, H0, dF, dH = self._central(p0)
            rng = np.random.default_rng(0)
            probe = p0 + np.maximum(1.0, np.abs(p0)) * rng.uniform(-0.5, 0.5, p0.size)
            ok = self._on_the_plane(probe, p0, (F0, H0, dF, dH))
            self._basis = (p0.copy(), F0, H0, dF, dH) if ok else False
        return self._basis is not False

    def not_affine_in(self, p0: FloatArray) -> list[str]:
        """The parameters the matrices are not affine in, each moved alone about `p0`
        (for a message: `affine` answers for all of them at once)."""
        at = self._central(p0)
        out = []
        for j, name in enumerate(self.names):
            probe = p0.copy()
            probe[j] += 0.37 * max(1.0, abs(float(p0[j])))
            if not self._on_the_plane(probe, p0, at):
                out.append(name)
        return out

    def _on_the_plane(self, probe: FloatArray, p0: FloatArray, at: tuple[Any, ...]) -> bool:
        """Whether the matrices at `probe` are those at `p0` moved along their slopes
        (`at`: the matrices at `p0` and their slopes, as `_central` gives them)."""
        F0, H0, dF, dH = at
        Fp, Hp = self.matrices(probe)
        for got, base, slope in ((Fp, F0, dF), (Hp, H0, dH)):
            if got is None or base is None or slope is None:
                continue
            want = base + np.einsum("l,lij->ij", probe - p0, slope)
            tol = 1e-7 * (
                np.abs(base) + np.abs(got[0]) + np.max(np.abs(base), initial=0.0) + 1e-300
            )
            if not np.all(np.abs(got[0] - want) <= tol):
                return False
        return True

    def with_slopes(
        self, p: FloatArray
    ) -> tuple[FloatArray, FloatArray | None, FloatArray, FloatArray | None]:
        """Matrices at `p` and their slopes in each parameter (central differences)."""
        if not self._basis:
            return self._central(p)
        p0, F0, H0, dF, dH = self._basis
        F = F0 + np.einsum("l,lij->ij", p - p0, dF)
        H = None if H0 is None else H0 + np.einsum("l,lij->ij", p - p0, dH)
        return F, H, dF, dH

    def at(self, p: FloatArray) -> tuple[FloatArray, FloatArray | None]:
        """Matrices at one parameter vector."""
        if self._basis:
            F, H, _, _ = self.with_slopes(p)
            return F, H
        Fb, Hb = self.matrices(p)
        return Fb[0], None if Hb is None else Hb[0]
