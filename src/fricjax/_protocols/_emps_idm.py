"""The EMPS benchmark: the inverse-dynamic-model (IDM) fits of static friction laws (IDIM-LS).

The Electro-Mechanical Positioning System (Janot, Gautier & Brunot 2019, *Data Set and Reference Models of
EMPS*, nonlinearbenchmark.org) is a ball-screw axis under a PD position controller, logged at 1 kHz. Its
inverse dynamic model (emps-ensemble paper, eq. 1) is

    tau = M q'' + F_f(q') + offset,    tau = gtau * vir,

linear in `M` and in the friction amplitudes. On the data of the reference IDIM preprocessing (`emps_idm_data`,
`_emps_idm_data`), `fit_emps_idm` fits the eight friction laws of the emps-ensemble paper (Coulomb + viscous,
Threlfall, Tustin, Bo-Pavelescu; symmetric and asymmetric): laws linear in their parameters by ordinary least
squares exactly as IDIM-LS (reproducing the published estimates, standard deviations, condition number and
relative errors to every printed digit), the others by separable least squares (linear coefficients solved
exactly for each value of the nonlinear ones, which are found by a bounded global-then-local search). The
model-free reading of the friction off the plateaus is `emps_plateau_forces` (`_emps_plateaus`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Any

import equinox as eqx
import numpy as np
import scipy.optimize

from .._data._emps import EMPSRecord
from .._estimation.linear._covariance import covariance
from .._estimation.linear._lstsq import LstsqResult, lstsq
from .._metrics import numpy_rmse
from .._models.physics._static import AbstractStaticFriction, LawRegression
from .._smoothing import AbstractSmoothing, Exact
from .._systems._emps import EMPSPlant
from .._validation import integer
from ._emps_idm_data import EMPSIDMData, emps_idm_data

# ---------------------------------------------------------------------------------------------------------------
# IDM fit


@dataclasses.dataclass(frozen=True)
class _LawSpec:
    """A static law with its regression form (`AbstractStaticFriction.regression_form`)."""

    law: type[AbstractStaticFriction]
    form: LawRegression

    @classmethod
    def of(cls, law: type[AbstractStaticFriction]) -> _LawSpec:
        form = law.regression_form()
        assert form is not None, f"{law.__name__} has no regression form"
        return cls(law, form)

    @property
    def viscous(self) -> bool:
        return self.form.viscous

    @property
    def fixed_sign(self) -> bool:
        return self.form.fixed_sign

    @property
    def nonlinear(self) -> tuple[str, ...]:
        return self.form.nonlinear

    @property
    def amplitude(self) -> bool:
        return self.form.amplitude

    def terms(self, v: np.ndarray, nl: dict[str, float]) -> list[tuple[str, np.ndarray]]:
        return self.form.terms(v, nl)


DEFAULT_BOUNDS: dict[str, tuple[float, float]] = {"v0": (1e-5, 0.1), "vs": (1e-5, 0.1), "delta": (0.25, 10.0)}
"""Search intervals of the nonlinear IDM parameters: `v0`, `vs` [m/s] and `delta` [-] (EMPS speeds reach
0.13 m/s)."""


class _Problem:
    """The separable least-squares problem of one law on one data set (columns cached, decimated)."""

    def __init__(self, spec: _LawSpec, asymmetric: bool, data: EMPSIDMData | tuple[np.ndarray, ...]):
        self.spec, self.asymmetric = spec, asymmetric
        self.qd, self.qdd, self.tau, self._decimate = _regression_signals(data)
        v = self.qd
        self.sides = (v > 0, v < 0) if asymmetric else None
        fixed: list[tuple[tuple[str, int | None], np.ndarray]] = [(("M", None), self.qdd)]
        if spec.viscous:
            fixed += self._split("Fv", v)
        if spec.fixed_sign:
            fixed += self._split("Fc", np.sign(v))
        if not asymmetric:  # the asymmetric laws have no offset (it is collinear with Fc+ and Fc-)
            fixed.append((("offset", None), np.ones_like(v)))
        self.fixed_names = [name for name, _ in fixed]
        self.fixed = np.column_stack([self._decimate(column) for _, column in fixed])
        self.y = self._decimate(self.tau)

    def _split(self, name: str, column: np.ndarray) -> list[tuple[tuple[str, int | None], np.ndarray]]:
        if self.sides is None:
            return [((name, None), column)]
        return [((name, side), column * mask) for side, mask in enumerate(self.sides)]

    def design(self, nl: dict[str, float]) -> tuple[list[tuple[str, int | None]], np.ndarray]:
        names, columns = list(self.fixed_names), [self.fixed]
        for name, column in self.spec.terms(self.qd, nl):
            for key, split in self._split(name, column):
                names.append(key)
                columns.append(self._decimate(split)[:, None])
        return names, np.hstack(columns)

    def solve(self, nl: dict[str, float]) -> tuple[list[tuple[str, int | None]], np.ndarray, LstsqResult]:
        names, X = self.design(nl)
        return names, X, lstsq(X, self.y)

    def relative_error(self, nl: dict[str, float]) -> float:
        """The search objective `100 ||e|| / ||tau||` [%], `inf` where it cannot be evaluated (a design column
        that overflows at a corner of the bounds)."""
        _, X = self.design(nl)
        if not np.all(np.isfinite(X)):
            return np.inf
        value = 100.0 * numpy_rmse(lstsq(X, self.y).residual) / numpy_rmse(self.y)
        return float(value) if np.isfinite(value) else np.inf


def _regression_signals(
    data: EMPSIDMData | tuple[np.ndarray, ...],
) -> tuple[np.ndarray, np.ndarray, np.ndarray, Callable[[np.ndarray], np.ndarray]]:
    if isinstance(data, EMPSIDMData):
        return data.qd, data.qdd, data.tau, data.decimate
    arrays = [np.asarray(a, dtype=np.float64) for a in data]
    qd, qdd, tau = arrays[-3:]
    if not (qd.ndim == qdd.ndim == tau.ndim == 1 and qd.shape == qdd.shape == tau.shape):
        raise ValueError(
            "the IDM arrays `qd`, `qdd`, `tau` must be 1-D of one length, got shapes "
            f"{qd.shape}, {qdd.shape}, {tau.shape}."
        )
    if not all(np.all(np.isfinite(a)) for a in (qd, qdd, tau)):
        raise ValueError("the IDM arrays contain NaN or inf; clean the record first.")
    return qd, qdd, tau, lambda column: np.asarray(column, dtype=np.float64)


def _as_idm_data(data: Any, preprocessing: dict[str, Any]) -> EMPSIDMData | tuple[np.ndarray, ...]:
    if isinstance(data, EMPSRecord):
        return emps_idm_data(data, **preprocessing)
    if isinstance(data, EMPSIDMData):
        return data
    if isinstance(data, (tuple, list)) and len(data) in (3, 4):
        return tuple(data)
    raise TypeError(
        "`data` must be an EMPSRecord (from load_emps), an EMPSIDMData (from emps_idm_data) or a tuple of "
        f"arrays (q, qd, qdd, tau) / (qd, qdd, tau) at the regression rate; got {type(data).__name__}."
    )


Param = float | tuple[float, float]


class EMPSIDMResult(eqx.Module):
    """An IDM fit `tau = M q'' + F_f(q') + offset` of one static friction law to EMPS data.

    **Fields:**

    - `law`: the fricjax law class (`CoulombViscous`, `Threlfall`, `Tustin`, `BoPavelescu`, `Coulomb`);
      `asymmetric`: whether the coefficients differ for q' > 0 and q' < 0.
    - `M`: mass [kg]; `offset`: constant force [N] (0 for the asymmetric laws, which have none).
    - `params`: the friction parameters named as the law's arguments (`Fc`, `Fv`, `Fs` [N, N·s/m]; `v0`,
      `vs` [m/s]; `delta`), a `(positive side, negative side)` pair for the asymmetric coefficients.
    - `std`: standard deviations of the coefficients linear in the IDM (`M`, `Fv`, `Fc`, `Fs`, `offset`),
      `sigma = sqrt(diag(sigma_e^2 (X^T X)^-1))`, `sigma_e^2 = ||e||^2 / (N - p)`, conditional on the nonlinear
      parameters (p counts all fitted parameters). The reference script uses `std(e)` (divisor N - 1) in place
      of `sigma_e`, a factor `sqrt((N - 1) / (N - p))` (1.0006 on EMPS) smaller.
    - `relative_error`: `100 ||tau - tau_hat|| / ||tau||` [%] on the fitted data; `error_norm`: `||e||` [N];
      `noise_std`: `sigma_e` [N]; `condition_number`: 2-norm condition number of the observation matrix;
      `n_samples`: N.
    - `preprocessing`: the `emps_idm_data` settings used for records (so `relative_error_on` a new record
      preprocesses it the same way).
    """

    law: type[AbstractStaticFriction] = eqx.field(static=True)
    asymmetric: bool = eqx.field(static=True)
    M: float
    offset: float
    params: dict[str, Param]
    std: dict[str, Param]
    relative_error: float
    error_norm: float
    noise_std: float
    condition_number: float
    n_samples: int
    preprocessing: dict[str, Any]

    def _nonlinear(self) -> dict[str, float]:
        return {name: float(self.params[name]) for name in _LawSpec.of(self.law).nonlinear}  # type: ignore[arg-type]

    def _coefficients(self, names: Sequence[tuple[str, int | None]]) -> np.ndarray:
        values: dict[str, Any] = {"M": self.M, "offset": self.offset, **self.params}
        if "Fs" in self.params:
            values["dS"] = _map_pair(lambda s, c: s - c, self.params["Fs"], self.params["Fc"])
        return np.array([values[name] if side is None else values[name][side] for name, side in names])

    def predict(self, data: Any) -> np.ndarray:
        """The force `tau_hat` [N] the model gives on `data` (a record, `EMPSIDMData` or arrays), at the
        regression (decimated) rate."""
        problem = _Problem(_LawSpec.of(self.law), self.asymmetric, _as_idm_data(data, self.preprocessing))
        names, X = problem.design(self._nonlinear())
        return X @ self._coefficients(names)

    def relative_error_on(self, data: Any) -> float:
        """`100 ||tau - tau_hat|| / ||tau||` [%] on other data with these parameters (cross-test validation,
        e.g. on `DATA_EMPS_PULSES.mat`: 5.9824 % for the reference model)."""
        problem = _Problem(_LawSpec.of(self.law), self.asymmetric, _as_idm_data(data, self.preprocessing))
        names, X = problem.design(self._nonlinear())
        error = problem.y - X @ self._coefficients(names)
        return float(100.0 * numpy_rmse(error) / numpy_rmse(problem.y))

    def friction(self, smoothing: AbstractSmoothing = Exact()) -> AbstractStaticFriction:
        """The fitted friction law as a fricjax model, offset included (e.g.
        `CoulombViscous(Fc=(Fc+, Fc-), Fv=(Fv+, Fv-), offset=0)`). Raises if a fitted value violates the law's
        constraints (e.g. a negative `Fs`)."""
        return self.law(**self.params, offset=self.offset, smoothing=smoothing)  # type: ignore[call-arg]

    def plant(self, smoothing: AbstractSmoothing = Exact()) -> Any:
        """The matching `EMPSPlant(M, friction)` for open- and closed-loop simulation."""

        return EMPSPlant(self.M, self.friction(smoothing))


def _map_pair(fn: Callable[..., float], *values: Param) -> Param:
    if isinstance(values[0], tuple):
        return tuple(fn(*(v[i] for v in values)) for i in range(2))  # type: ignore[index,return-value]
    return fn(*values)


def fit_emps_idm(
    data: Any,
    law: type[AbstractStaticFriction],
    *,
    asymmetric: bool = False,
    cutoff_hz: float = 100.0,
    decimation: int = 10,
    drop: int = 49,
    bounds: dict[str, tuple[float, float]] | None = None,
    grid: int = 41,
) -> EMPSIDMResult:
    """Fit the EMPS inverse dynamic model `tau = M q'' + F_f(q') + offset` (emps-ensemble eq. 1) by least
    squares on the decimated IDIM data.

    The eight models of the emps-ensemble paper (its Table 1): `law` is `CoulombViscous` (eqs. 4-5),
    `Threlfall` (eqs. 8-9, tolerance velocity `v0`), `Tustin` (eq. 10, Stribeck velocity `vs`) or `BoPavelescu`
    (eq. 11, `vs` and exponent `delta`), each symmetric (with `offset`) or `asymmetric` (separate `Fc`, `Fv`,
    `Fs` for q' > 0 and q' < 0, one `v0` / `vs` / `delta`, no offset). `Coulomb` (no viscous term) works too.

    - **Linear laws** (`Coulomb`, `CoulombViscous`): IDIM-LS, exactly as the benchmark's reference script.
      With the defaults, the symmetric law gives the published M = 95.1089 kg, Fv = 203.5034 N·s/m,
      Fc = 20.3935 N, offset = -3.1648 N, cond 25.9883 and relative error 4.0834 %.
    - **Nonlinear laws**: separable least squares. For given nonlinear parameters the IDM is linear in `M`,
      `Fv`, `Fc`, `Fs - Fc` and `offset`, which are solved exactly; the nonlinear parameters minimise the
      relative error by a log-spaced grid over `bounds` (`grid` points per parameter, fewer for `delta`)
      followed by a bounded local search (`scipy.optimize.minimize_scalar` in 1-D, Nelder-Mead in 2-D).

    **Arguments:**

    - `data`: an `EMPSRecord` (preprocessed with `cutoff_hz`, `decimation`, `drop`, see `emps_idm_data`), an
      `EMPSIDMData`, or a tuple of arrays `(q, qd, qdd, tau)` already at the regression rate (no decimation).
    - `law`: the fricjax law class; `asymmetric`: see above.
    - `bounds`: search intervals for `v0`, `vs` [m/s] and `delta`, default `DEFAULT_BOUNDS`.
    - `grid`: grid points per nonlinear parameter (>= 3).

    **Returns:** an `EMPSIDMResult` (parameters, standard deviations, relative error, `relative_error_on`,
    `friction()`, `plant()`).

    ```python
    >>> import fricjax as fj
    >>> train = fj.load_emps(fj.data_folder("emps") / "DATA_EMPS.mat")  # doctest: +SKIP
    >>> fit = fj.emps.fit_emps_idm(train, fj.CoulombViscous)  # doctest: +SKIP
    >>> round(fit.M, 4), round(fit.params["Fv"], 4), round(fit.params["Fc"], 4), round(fit.offset, 4)  # doctest: +SKIP
    (95.1089, 203.5034, 20.3935, -3.1648)
    >>> round(fit.relative_error_on(fj.load_emps(fj.data_folder("emps") / "DATA_EMPS_PULSES.mat")), 4)  # doctest: +SKIP
    5.9824
    >>> fj.emps.fit_emps_idm(train, fj.Tustin, asymmetric=True).friction()  # doctest: +SKIP
    ```
    """
    form = getattr(law, "regression_form", None) if isinstance(law, type) else None
    if form is None or form() is None:
        raise TypeError(
            "`law` must be one of the fricjax static law classes CoulombViscous, Threlfall, Tustin, BoPavelescu "
            f"or Coulomb (the class, not an instance); got {law!r}."
        )
    if not isinstance(asymmetric, bool):
        raise TypeError(f"`asymmetric` must be True or False, got {asymmetric!r}.")
    grid = integer(grid, "grid", "", minimum=3, hint="(grid points per nonlinear parameter)")
    spec = _LawSpec.of(law)
    bounds = _check_bounds(spec, bounds)
    preprocessing = {"cutoff_hz": cutoff_hz, "decimation": decimation, "drop": drop}
    problem = _Problem(spec, asymmetric, _as_idm_data(data, preprocessing))

    nl = _search(problem, spec, bounds, int(grid))
    names, X, solution = problem.solve(nl)
    theta, error = solution.x, solution.residual
    n, p = X.shape
    dof = n - p - len(nl)
    if dof <= 0:
        raise ValueError(f"the IDM data has {n} samples, too few for {p + len(nl)} parameters.")
    sigma_e = float(numpy_rmse(error) * np.sqrt(n / dof))  # ||e|| / sqrt(dof), scaled before squaring
    return EMPSIDMResult(
        law=law,
        asymmetric=asymmetric,
        M=_pick(names, theta, "M"),  # type: ignore[arg-type]
        offset=_pick(names, theta, "offset", default=0.0),  # type: ignore[arg-type]
        params=_friction_params(spec, names, theta, nl),
        std=_std(spec, names, np.asarray(covariance(X, error, dof))),
        relative_error=float(100.0 * numpy_rmse(error) / numpy_rmse(problem.y)),
        error_norm=float(numpy_rmse(error) * np.sqrt(n)),
        noise_std=sigma_e,
        condition_number=float(np.linalg.cond(X)),  # of the unscaled X, as the reference script reports it
        n_samples=int(n),
        preprocessing=preprocessing,
    )


def _check_bounds(spec: _LawSpec, bounds: dict[str, tuple[float, float]] | None) -> dict[str, tuple[float, float]]:
    merged = dict(DEFAULT_BOUNDS)
    for name, interval in (bounds or {}).items():
        if name not in DEFAULT_BOUNDS:
            raise ValueError(f"`bounds` has an unknown parameter {name!r}; the nonlinear ones are v0, vs, delta.")
        low, high = (float(x) for x in interval)
        if not (np.isfinite(low) and np.isfinite(high) and 0 < low < high):
            raise ValueError(f"`bounds[{name!r}]` must be an interval 0 < low < high, got {interval!r}.")
        merged[name] = (low, high)
    return {name: merged[name] for name in spec.nonlinear}


def _search(problem: _Problem, spec: _LawSpec, bounds: dict[str, tuple[float, float]], grid: int) -> dict[str, float]:
    """Minimise the relative error over the nonlinear parameters: log-grid, then a bounded local search."""
    names = spec.nonlinear
    if not names:
        return {}
    logs = [np.log(bounds[name]) for name in names]
    sizes = [grid if name != "delta" else max(3, grid // 3) for name in names]
    axes = [np.linspace(lo, hi, size) for (lo, hi), size in zip(logs, sizes, strict=True)]

    def objective(log_values: Sequence[float] | np.ndarray) -> float:
        return problem.relative_error({n: float(np.exp(x)) for n, x in zip(names, log_values, strict=True)})

    mesh = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, len(names))
    values = np.array([objective(point) for point in mesh])
    if not np.any(np.isfinite(values)):
        raise ValueError(f"the IDM fit of {spec.law.__name__} failed: no finite relative error on the search grid.")
    best = mesh[int(np.argmin(values))]
    if len(names) == 1:
        (axis,) = axes
        i = int(np.argmin(np.abs(axis - best[0])))
        low, high = axis[max(i - 1, 0)], axis[min(i + 1, len(axis) - 1)]
        result = scipy.optimize.minimize_scalar(
            lambda x: objective([x]), bounds=(low, high), method="bounded", options={"xatol": 1e-7}
        )
        x = np.array([result.x]) if result.fun <= values.min() else best
    else:
        result = scipy.optimize.minimize(
            objective,
            best,
            method="Nelder-Mead",
            bounds=logs,
            options={"xatol": 1e-7, "fatol": 1e-10, "maxiter": 2000},
        )
        x = result.x if result.fun <= values.min() else best
    return {name: float(np.exp(value)) for name, value in zip(names, x, strict=True)}


def _pick(names: Sequence[tuple[str, int | None]], values: np.ndarray, name: str, default: Any = None) -> Param:
    found = {side: float(v) for (n, side), v in zip(names, values, strict=True) if n == name}
    if not found:
        return default
    if None in found:
        return found[None]
    return (found[0], found[1])


def _friction_params(
    spec: _LawSpec, names: Sequence[tuple[str, int | None]], theta: np.ndarray, nl: dict[str, float]
) -> dict[str, Param]:
    params: dict[str, Param] = {"Fc": _pick(names, theta, "Fc")}
    if spec.amplitude:
        params["Fs"] = _map_pair(lambda c, d: c + d, params["Fc"], _pick(names, theta, "dS"))
    params.update(nl)
    if spec.viscous:
        params["Fv"] = _pick(names, theta, "Fv")
    return params


def _std(spec: _LawSpec, names: Sequence[tuple[str, int | None]], cov: np.ndarray) -> dict[str, Param]:
    variance = np.diag(cov)
    std: dict[str, Param] = {}
    for name in ("M", "Fv", "Fc", "offset"):
        value = _pick(names, np.sqrt(variance), name)
        if value is not None:
            std[name] = value
    if spec.amplitude:  # Fs = Fc + dS: var = var(Fc) + var(dS) + 2 cov(Fc, dS)
        index = {key: i for i, key in enumerate(names)}

        def fs_std(side: int | None) -> float:
            i, j = index[("Fc", side)], index[("dS", side)]
            return float(np.sqrt(cov[i, i] + cov[j, j] + 2 * cov[i, j]))

        std["Fs"] = (fs_std(0), fs_std(1)) if ("Fc", 0) in index else fs_std(None)
    return std
