"""Static friction curves F(v) of the emps-ensemble paper (eqs. 2-11), symmetric and asymmetric.

Every coefficient may be a scalar (symmetric law) or a pair `(positive, negative)` (asymmetric law: the
first value applies for v > 0, the second for v < 0, emps-ensemble eqs. 5-7). For a negative velocity the
law is evaluated with the negative-side coefficients, so e.g. Coulomb + viscous gives
`F = Fv- * v - Fc-` for v < 0. Every law also has a constant `offset` [N].

Smoothing (`smoothing=Smooth(eps)`, eps in m/s) replaces sign(v) by tanh(v / eps) and the +/- coefficient
switch by the matching smooth step; `Exact()` (default) is the paper's equation with sign(0) = 0.
"""

from __future__ import annotations

import abc
import dataclasses
from collections.abc import Callable
from typing import Any, ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from ..._constraints import (
    Fixed,
    Parameter,
    ParamLike,
    SidedParameter,
    as_float_array,
    model_dtype,
    positive,
    real,
    unwrap,
)
from ..._inputs import MotionSample
from ..._smoothing import AbstractSmoothing, Exact, is_concrete
from .._base import AbstractFrictionModel
from ._stribeck import abs_pow


def _coefficient(value: ParamLike, name: str, *, is_positive: bool, dtype: Any = None) -> Any:
    if isinstance(value, Fixed):  # a fixed (not trained) coefficient
        return Fixed(_coefficient(value.value, name, is_positive=is_positive, dtype=dtype))
    array = as_float_array(value, dtype)
    if array.ndim not in (0, 1) or (array.ndim == 1 and array.shape[0] != 2):
        raise ValueError(
            f"`{name}` must be a scalar (symmetric law) or a pair (value for v > 0, value for v < 0), "
            f"got shape {array.shape}."
        )
    if is_positive:
        return positive(array, name)
    if name == "Fv" and is_concrete(array) and bool(np.any(np.asarray(array) < 0)):
        raise ValueError(f"`Fv` (viscous coefficient, N·s/m) must be >= 0, got {value!r}.")
    return real(array, name)


@dataclasses.dataclass(frozen=True)
class LawRegression:
    """How a static law enters a linear regression of the force (the EMPS inverse-dynamics identification,
    `fj.emps.fit_emps_idm`): its columns, split into those fixed and those depending on the nonlinear parameters.
    Coefficient names: `Fc`, `Fv`, and `dS = Fs - Fc` (the Stribeck amplitude, where `amplitude`)."""

    viscous: bool  # a `v` column with coefficient Fv
    fixed_sign: bool  # a plain sign(v) column with coefficient Fc
    nonlinear: tuple[str, ...]  # the parameters the columns below depend on
    # (v, nonlinear values) -> [(coefficient name, column)] of the terms that depend on the nonlinear values
    terms: Callable[[np.ndarray, dict[str, float]], list[tuple[str, np.ndarray]]]
    amplitude: bool = False  # a Stribeck amplitude dS: Fs = Fc + dS


def _no_terms(v: np.ndarray, nl: dict[str, float]) -> list[tuple[str, np.ndarray]]:
    return []


class AbstractStaticFriction(AbstractFrictionModel):
    """A memoryless friction law F(v); `model(v)` evaluates it, `simulate` runs it as a (stateless) scan."""

    offset: Parameter
    smoothing: AbstractSmoothing

    requires: ClassVar[frozenset[str]] = frozenset({"v"})
    nonnegative_fields: ClassVar[frozenset[str]] = frozenset({"Fv"})

    @classmethod
    def regression_form(cls) -> LawRegression | None:
        """How the law enters a linear regression of the force (`fj.emps.fit_emps_idm`); None where it has no such
        form."""
        return None

    reads_plant: ClassVar[bool] = False  # the law reads the plant's position and drive force too (a hybrid residual)

    def plant_force(self, v: ParamLike, q: ParamLike | None = None, u: ParamLike | None = None) -> Array:
        """The friction force [N] in a plant (`fj.EMPSPlant`) at velocity `v` [m/s], position `q` [m] and drive force
        `u` [N]; a static law reads `v` only."""
        return self(v)

    def parameter_ranges(self) -> dict[str, float]:
        Fc = getattr(self, "Fc", None)
        return {} if Fc is None else {"offset": float(np.max(np.abs(np.asarray(unwrap(Fc)))))}  # N

    @abc.abstractmethod
    def _law(self, v: Array, sign: Array, pick: Any) -> Array:
        """The law without offset; `pick(c)` selects the coefficient for the side of `v`."""

    def __call__(self, v: ParamLike) -> Array:
        """Friction force F(v) [N] for velocity `v` [m/s] (any shape)."""
        p = unwrap(self)
        v = jnp.asarray(v)
        sign = p.smoothing.sign(v)
        up = p.smoothing.step(v)

        def pick(c: Array) -> Array:
            if jnp.ndim(c) == 0:
                return c
            return up * c[0] + (1.0 - up) * c[1]

        return self._law(v, sign, pick) + p.offset

    def implausible(self, record_excursion: float | None = None, *, bounds: bool = True) -> list[str]:
        p = unwrap(self)
        notes = AbstractFrictionModel.implausible(p, record_excursion, bounds=bounds)
        return notes + (p.held_at_zero(("Fv",), bounds) if hasattr(p, "Fv") else [])

    def init_state(self) -> tuple[()]:
        return ()

    def step(self, state: tuple[()], sample: MotionSample) -> tuple[tuple[()], Array]:
        return state, self(sample.v)

    @property
    def asymmetric(self) -> bool:
        """True when any coefficient has separate values for positive and negative velocity."""
        return any(jnp.ndim(leaf) == 1 for leaf in _param_leaves(unwrap(self)))


def _param_leaves(model: eqx.Module) -> list[Array]:
    return [getattr(model, f) for f in ("Fc", "Fs", "vs", "delta", "Fv", "v0") if hasattr(model, f)]


class Coulomb(AbstractStaticFriction):
    """Coulomb friction (emps-ensemble eq. 2 for v != 0): `F = Fc * sign(v) + offset`.

    **Arguments:** `Fc` Coulomb force [N] (> 0, scalar or (+, -) pair); `offset` [N]; `smoothing`.

    ```python
    >>> import fricjax as fj
    >>> float(fj.Coulomb(Fc=2.0)(-0.1))
    -2.0
    ```
    """

    Fc: SidedParameter

    @classmethod
    def regression_form(cls) -> LawRegression:
        return LawRegression(viscous=False, fixed_sign=True, nonlinear=(), terms=_no_terms)

    @classmethod
    def start_from_scales(cls, reader: Any, *, elements: int, smoothing: Any, **_: Any) -> list[Coulomb]:
        s = reader.scales
        return [cls(Fc=s.Fc, offset=s.offset, smoothing=smoothing)]

    def __init__(self, Fc: ParamLike, *, offset: ParamLike = 0.0, smoothing: AbstractSmoothing = Exact()):
        dtype = model_dtype(Fc, offset)
        self.Fc = _coefficient(Fc, "Fc", is_positive=True, dtype=dtype)
        self.offset = real(offset, "offset", dtype)
        self.smoothing = smoothing

    def _law(self, v: Array, sign: Array, pick: Any) -> Array:
        p = unwrap(self)
        return pick(p.Fc) * sign


class CoulombViscous(AbstractStaticFriction):
    """Coulomb + viscous friction (emps-ensemble eqs. 4-5): `F = Fv * v + Fc * sign(v) + offset`.

    **Arguments:** `Fc` [N] (> 0); `Fv` viscous coefficient [N·s/m] (>= 0); each scalar or (+, -) pair;
    `offset` [N]; `smoothing`.
    """

    Fc: SidedParameter
    Fv: SidedParameter

    @classmethod
    def regression_form(cls) -> LawRegression:
        return LawRegression(viscous=True, fixed_sign=True, nonlinear=(), terms=_no_terms)

    @classmethod
    def start_from_scales(cls, reader: Any, *, elements: int, smoothing: Any, **_: Any) -> list[CoulombViscous]:
        s = reader.scales
        return [cls(Fc=s.Fc, Fv=s.Fv, offset=s.offset, smoothing=smoothing)]

    def __init__(
        self, Fc: ParamLike, Fv: ParamLike, *, offset: ParamLike = 0.0, smoothing: AbstractSmoothing = Exact()
    ):
        dtype = model_dtype(Fc, Fv, offset)
        self.Fc = _coefficient(Fc, "Fc", is_positive=True, dtype=dtype)
        self.Fv = _coefficient(Fv, "Fv", is_positive=False, dtype=dtype)
        self.offset = real(offset, "offset", dtype)
        self.smoothing = smoothing

    def _law(self, v: Array, sign: Array, pick: Any) -> Array:
        p = unwrap(self)
        return pick(p.Fv) * v + pick(p.Fc) * sign


class Threlfall(AbstractStaticFriction):
    """Coulomb with a finite slope at zero velocity + viscous (Threlfall 1978; emps-ensemble eqs. 8-9).

    `F = Fv * v + Fc * K(v) * sign(v) + offset`, with `K = (1 - exp(-3|v| / v0)) / (1 - exp(-3))` for
    `|v| <= v0` and `K = 1` above (continuous at v0; the paper's eq. 9 misplaces the parenthesis).
    This law is continuous and differentiable at v = 0 already, so smoothing only affects the +/- switch.

    **Arguments:** `Fc` [N] (> 0); `Fv` [N·s/m] (>= 0); `v0` tolerance velocity [m/s] (> 0); each scalar or
    (+, -) pair; `offset` [N]; `smoothing`.
    """

    Fc: SidedParameter
    Fv: SidedParameter
    v0: SidedParameter

    @classmethod
    def regression_form(cls) -> LawRegression:
        def terms(v: np.ndarray, nl: dict[str, float]) -> list[tuple[str, np.ndarray]]:
            ratio = np.minimum(np.abs(v) / nl["v0"], 1.0)
            return [("Fc", -np.expm1(-3.0 * ratio) / -np.expm1(-3.0) * np.sign(v))]

        return LawRegression(viscous=True, fixed_sign=False, nonlinear=("v0",), terms=terms)

    def __init__(
        self,
        Fc: ParamLike,
        Fv: ParamLike,
        v0: ParamLike,
        *,
        offset: ParamLike = 0.0,
        smoothing: AbstractSmoothing = Exact(),
    ):
        dtype = model_dtype(Fc, Fv, v0, offset)
        self.Fc = _coefficient(Fc, "Fc", is_positive=True, dtype=dtype)
        self.Fv = _coefficient(Fv, "Fv", is_positive=False, dtype=dtype)
        self.v0 = _coefficient(v0, "v0", is_positive=True, dtype=dtype)
        self.offset = real(offset, "offset", dtype)
        self.smoothing = smoothing

    def _law(self, v: Array, sign: Array, pick: Any) -> Array:
        p = unwrap(self)
        v0 = pick(p.v0)
        ratio = jnp.minimum(jnp.abs(v) / v0, 1.0)
        k = -jnp.expm1(-3.0 * ratio) / -jnp.expm1(-3.0)
        return pick(p.Fv) * v + pick(p.Fc) * k * jnp.sign(v)


class AbstractStribeckLaw(AbstractStaticFriction):
    """Coulomb + viscous + Stribeck term with exponent: the shared law of `Tustin` and `BoPavelescu`."""

    Fc: SidedParameter
    Fs: SidedParameter
    vs: SidedParameter
    delta: SidedParameter
    Fv: SidedParameter

    def _law(self, v: Array, sign: Array, pick: Any) -> Array:
        p = unwrap(self)
        Fc, Fs = pick(p.Fc), pick(p.Fs)
        stribeck = Fc + (Fs - Fc) * jnp.exp(-abs_pow(v / pick(p.vs), pick(p.delta)))
        return pick(p.Fv) * v + stribeck * sign


class BoPavelescu(AbstractStribeckLaw):
    """Coulomb + viscous + Stribeck with shape exponent (Bo & Pavelescu 1982; emps-ensemble eq. 11).

    `F = Fv * v + (Fc + (Fs - Fc) * exp(-|v / vs| ** delta)) * sign(v) + offset`.

    **Arguments:** `Fc` [N], `Fs` [N], `vs` [m/s], `delta` (all > 0); `Fv` [N·s/m] (>= 0); each scalar or
    (+, -) pair; `offset` [N]; `smoothing`.

    ```python
    >>> import fricjax as fj
    >>> law = fj.BoPavelescu(Fc=20.0, Fs=25.0, vs=0.01, delta=2.0, Fv=200.0)
    >>> round(float(law(1e-9)), 3)
    25.0
    ```
    """

    @classmethod
    def regression_form(cls) -> LawRegression:
        def terms(v: np.ndarray, nl: dict[str, float]) -> list[tuple[str, np.ndarray]]:
            return [("dS", np.exp(-((np.abs(v) / nl["vs"]) ** nl["delta"])) * np.sign(v))]

        return LawRegression(viscous=True, fixed_sign=True, nonlinear=("vs", "delta"), terms=terms, amplitude=True)

    @classmethod
    def start_from_scales(cls, reader: Any, *, elements: int, smoothing: Any, **_: Any) -> list[BoPavelescu]:
        s = reader.scales
        return [cls(Fc=s.Fc, Fs=s.Fs, vs=s.vs, delta=2.0, Fv=s.Fv, offset=s.offset, smoothing=smoothing)]

    def __init__(
        self,
        Fc: ParamLike,
        Fs: ParamLike,
        vs: ParamLike,
        delta: ParamLike = 2.0,
        Fv: ParamLike = 0.0,
        *,
        offset: ParamLike = 0.0,
        smoothing: AbstractSmoothing = Exact(),
    ):
        dtype = model_dtype(Fc, Fs, vs, delta, Fv, offset)
        self.Fc = _coefficient(Fc, "Fc", is_positive=True, dtype=dtype)
        self.Fs = _coefficient(Fs, "Fs", is_positive=True, dtype=dtype)
        self.vs = _coefficient(vs, "vs", is_positive=True, dtype=dtype)
        self.delta = _coefficient(delta, "delta", is_positive=True, dtype=dtype)
        self.Fv = _coefficient(Fv, "Fv", is_positive=False, dtype=dtype)
        self.offset = real(offset, "offset", dtype)
        self.smoothing = smoothing


class Tustin(AbstractStribeckLaw):
    """Tustin's model (emps-ensemble eq. 10): the Stribeck law with exponent 1 (fixed, not trained).

    `F = Fv * v + (Fc + (Fs - Fc) * exp(-|v| / vs)) * sign(v) + offset` (the Stribeck term carries sign(v) so
    the law is odd, as in Tustin 1947; the paper's eq. 10 drops it).

    **Arguments:** `Fc` [N], `Fs` [N], `vs` [m/s] (> 0); `Fv` [N·s/m] (>= 0); each scalar or (+, -) pair;
    `offset` [N]; `smoothing`.
    """

    @classmethod
    def regression_form(cls) -> LawRegression:
        def terms(v: np.ndarray, nl: dict[str, float]) -> list[tuple[str, np.ndarray]]:
            return [("dS", np.exp(-np.abs(v) / nl["vs"]) * np.sign(v))]

        return LawRegression(viscous=True, fixed_sign=True, nonlinear=("vs",), terms=terms, amplitude=True)

    @classmethod
    def start_from_scales(cls, reader: Any, *, elements: int, smoothing: Any, **_: Any) -> list[Tustin]:
        s = reader.scales
        return [cls(Fc=s.Fc, Fs=s.Fs, vs=s.vs, Fv=s.Fv, offset=s.offset, smoothing=smoothing)]

    def __init__(
        self,
        Fc: ParamLike,
        Fs: ParamLike,
        vs: ParamLike,
        Fv: ParamLike = 0.0,
        *,
        offset: ParamLike = 0.0,
        smoothing: AbstractSmoothing = Exact(),
    ):
        dtype = model_dtype(Fc, Fs, vs, Fv, offset)
        self.Fc = _coefficient(Fc, "Fc", is_positive=True, dtype=dtype)
        self.Fs = _coefficient(Fs, "Fs", is_positive=True, dtype=dtype)
        self.vs = _coefficient(vs, "vs", is_positive=True, dtype=dtype)
        self.delta = Fixed(jnp.ones((), dtype))
        self.Fv = _coefficient(Fv, "Fv", is_positive=False, dtype=dtype)
        self.offset = real(offset, "offset", dtype)
        self.smoothing = smoothing
