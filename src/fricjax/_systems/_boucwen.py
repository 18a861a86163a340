"""The Bouc-Wen hysteretic oscillator of the Noël & Schoukens (2016) benchmark, as a model for `fj.simulate`.

    m y'' + c y' + k y + z(y, y') = u(t),
    z' = alpha y' - beta (gamma |y'| |z|^(nu - 1) z + delta y' |z|^nu),

input force u [N], output displacement y [m], hysteretic restoring force z [N]. The benchmark's parameters
(`BoucWen.benchmark()`): m = 2 kg, c = 10 N s/m, k = 5e4 N/m, alpha = 5e4 N/m, beta = 1e3 m^-1, gamma = 0.8,
delta = -1.1, nu = 1. The official data were made by Newmark integration at 15 kHz and decimation to 750 Hz;
here the force is interpolated linearly between samples (first-order hold: the record holds `u` and
`u_next`, built by `boucwen_inputs`) and `substeps` classical Runge-Kutta steps (RK4) advance the state over
it (20 by default: 15 kHz), one `lax.fori_loop` inside the step of `fj.simulate`. Against the official
noise-free test outputs this reproduces the multisine period to 7.3e-6 m RMS and the sine sweep to 4.7e-6 m
(the residual is the difference between the benchmark's Newmark scheme / input interpolation and this one).
`|z|^nu` is written `exp(nu log|z|)` away from z = 0 (0 at z = 0), so the gradient with respect to `nu` is finite.
"""

from __future__ import annotations

from typing import Any, ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array

from .._constraints import Parameter, ParamLike, model_dtype, positive, real, unwrap
from .._inputs import InputRecord
from .._models._base import AbstractSystem
from .._validation import positive_int

# the benchmark's published parameters (Noël & Schoukens 2016)
BENCHMARK_PARAMETERS = {
    "m": 2.0,
    "c": 10.0,
    "k": 5e4,
    "alpha": 5e4,
    "beta": 1e3,
    "gamma": 0.8,
    "delta": -1.1,
    "nu": 1.0,
}


def _abs_pow(z: Array, nu: Array) -> Array:
    """`|z|^nu`, 0 at z = 0, with finite gradients in z and nu everywhere."""
    a = jnp.abs(z)
    nonzero = a > 0
    safe = jnp.where(nonzero, a, 1.0)
    return jnp.where(nonzero, jnp.exp(nu * jnp.log(safe)), 0.0)


class BoucWen(AbstractSystem):
    """A mass-spring-damper with a Bouc-Wen hysteretic restoring force (Noël & Schoukens 2016), for `fj.simulate`.

    Input record: `fj.boucwen_inputs(u)` = `fj.InputRecord(dt=..., u=..., u_next=...)` (force [N], linear
    between samples). State `(y, y', z)`
    [m, m/s, N], at rest by default. Output at sample k: `y(k)` [m]; then the state is advanced to k+1 by
    `substeps` RK4 steps (see the module docstring).

    **Arguments:** `m` mass [kg], `c` damping [N s/m], `k` stiffness [N/m], `alpha` [N/m], `beta` [1/m],
    `nu` (> 0; all these positive, stored as logs), `gamma`, `delta` (real, dimensionless), `substeps` (static,
    default 20). `BoucWen.benchmark()` gives the published system.

    ```python
    >>> import numpy as np, fricjax as fj
    >>> system = fj.BoucWen.benchmark()
    >>> y = fj.simulate(system, fj.boucwen_inputs(np.full(750, 10.0)))
    >>> y.shape
    (750,)
    ```
    """

    m: Parameter
    c: Parameter
    k: Parameter
    alpha: Parameter
    beta: Parameter
    gamma: Array
    delta: Array
    nu: Parameter
    substeps: int = eqx.field(static=True, default=20)

    requires: ClassVar[frozenset[str]] = frozenset({"u", "u_next"})
    units: ClassVar[dict[str, str] | None] = {
        "m": "kg",
        "c": "N s/m",
        "k": "N/m",
        "alpha": "N/m",
        "beta": "1/m",
        "gamma": "-",
        "delta": "-",
        "nu": "-",
    }

    def __init__(
        self,
        m: ParamLike,
        c: ParamLike,
        k: ParamLike,
        alpha: ParamLike,
        beta: ParamLike,
        gamma: ParamLike,
        delta: ParamLike,
        nu: ParamLike = 1.0,
        substeps: int = 20,
    ):
        dtype = model_dtype(m, c, k, alpha, beta, gamma, delta, nu)
        self.m = positive(m, "m", dtype, scalar=True)
        self.c = positive(c, "c", dtype, scalar=True)
        self.k = positive(k, "k", dtype, scalar=True)
        self.alpha = positive(alpha, "alpha", dtype, scalar=True)
        self.beta = positive(beta, "beta", dtype, scalar=True)
        self.gamma = real(gamma, "gamma", dtype, scalar=True)
        self.delta = real(delta, "delta", dtype, scalar=True)
        self.nu = positive(nu, "nu", dtype, scalar=True)
        self.substeps = positive_int(
            substeps, "substeps", "BoucWen", hint="(RK4 steps per sample; 20 is 15 kHz at 750 Hz)"
        )

    @classmethod
    def benchmark(cls, substeps: int = 20) -> BoucWen:
        """The benchmark's published system (Noël & Schoukens 2016): the "true model" of `load_boucwen`'s data."""
        return cls(**BENCHMARK_PARAMETERS, substeps=substeps)

    def init_state(self) -> tuple[Array, Array, Array]:
        zero = jnp.zeros((), jnp.result_type(self.gamma))
        return zero, zero, zero

    def derivative(self, state: tuple[Array, Array, Array], u: Array) -> tuple[Array, Array, Array]:
        """`(y', y'', z')` at `state = (y, y', z)` under the force `u` [N]."""
        p = unwrap(self)
        y, v, z = state
        zn = _abs_pow(z, p.nu)
        dz = p.alpha * v - p.beta * (p.gamma * jnp.abs(v) * jnp.sign(z) * zn + p.delta * v * zn)
        return v, (u - p.c * v - p.k * y - z) / p.m, dz

    def step(self, state: tuple[Array, Array, Array], sample: dict[str, Array]) -> tuple[Any, Array]:
        u0, u1 = sample["u"], sample["u_next"]
        h = sample["dt"] / self.substeps
        du = (u1 - u0) / self.substeps
        derivative = self.derivative

        def rk4(i: Any, x: tuple[Array, Array, Array]) -> tuple[Array, Array, Array]:
            ua = u0 + i * du
            k1 = derivative(x, ua)
            k2 = derivative(tuple(a + 0.5 * h * b for a, b in zip(x, k1, strict=True)), ua + 0.5 * du)  # type: ignore[arg-type]
            k3 = derivative(tuple(a + 0.5 * h * b for a, b in zip(x, k2, strict=True)), ua + 0.5 * du)  # type: ignore[arg-type]
            k4 = derivative(tuple(a + h * b for a, b in zip(x, k3, strict=True)), ua + du)  # type: ignore[arg-type]
            return tuple(  # type: ignore[return-value]
                a + h / 6 * (b1 + 2 * b2 + 2 * b3 + b4) for a, b1, b2, b3, b4 in zip(x, k1, k2, k3, k4, strict=True)
            )

        new = jax.lax.fori_loop(0, self.substeps, rk4, tuple(state))
        return new, state[0]


def boucwen_inputs(u: Any, dt: float = 1.0 / 750.0, *, periodic: bool = False) -> InputRecord:
    """The input record of `BoucWen`: `InputRecord(dt, u=u, u_next=u shifted by one)` (the force [N] at samples
    k and k+1, linear in between). `u_next` of the last sample is `u[0]` with `periodic=True` (one period of a
    multisine), else `u[-1]` (held). Works on NumPy / JAX arrays of shape `(T,)`."""
    u = jnp.asarray(u)
    if u.ndim != 1 or u.shape[0] < 1:
        raise ValueError(f"boucwen_inputs: `u` must be a force signal of shape (T,), got shape {u.shape}.")
    last = u[:1] if periodic else u[-1:]
    return InputRecord(dt=dt, u=u, u_next=jnp.concatenate([u[1:], last]))
