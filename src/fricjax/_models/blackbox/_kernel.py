"""Kernel (RKHS) Volterra series and NARX models (the kernel-method paper §2, eqs. 1-12).

A finite-memory Volterra series (VS) of degree D in the lagged inputs `u = [u_1, ..., u_M]`,

`y(u) = h_0 + sum_{n=1}^D sum_{m_1..m_n} h_n(m_1, ..., m_n) u_{m_1} ... u_{m_n}` (eq. 1),

is linear in its many Volterra coefficients; the kernel method writes it instead as a weighted sum of kernel
functions centred on the N training regressor vectors, `y(u) = sum_i alpha_i k(u_i, u)` (eqs. 5-6), with the
polynomial kernel `k_p(u, v) = (1 + <u, v>)^D` (eq. 7: every VS of degree <= D) or the exponential kernel
`k_e(u, v) = exp(<u, v> / p)` (eq. 8: a VS of infinite degree). Replacing the inputs by the NARX "general input
vector" of past outputs and past inputs (eqs. 11-12) gives a kernel NARX model; with no past outputs it is the
VS again. The coefficients `alpha` are the kernel ridge regression `(K + rho I) alpha = y` of the one-step
(teacher-forced) rows (the paper's footnote 3); see `fj.identify_kernel_narx`. The model stays a polynomial
(or power series) in its regressors, so its low-order Volterra kernels follow from `alpha` and the centres in
closed form (`fj.volterra_kernels`).
"""

from __future__ import annotations

import abc
import math
import string
from typing import Any

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..._constraints import Fixed, FixedScalar, as_float_array, unwrap
from ..._inputs import Motion
from ..._validation import nonnegative_int, positive_int
from ._narx import AbstractNARX, unit_mask_field
from ._regressors import NARXRegressors, fixed_array

# the largest Volterra kernel `volterra_kernels` builds (P^n numbers; 8e8 bytes in float64)
_MAX_KERNEL_ENTRIES = 10**8


class AbstractKernel(eqx.Module):
    """A dot-product kernel `k(u, v) = kappa(<u, v>)` on regressor vectors (the kernel-method paper eqs. 7-8).

    Subclasses give the profile `kappa(t)` and its Taylor coefficients `kappa^(n)(t0) / n!` (from which the
    Volterra kernels of a kernel model follow, `fj.volterra_kernels`)."""

    @abc.abstractmethod
    def profile(self, t: Array) -> Array:
        """`kappa(t)`, elementwise, for inner products `t = <u, v>`."""

    @abc.abstractmethod
    def taylor(self, t0: Array, n: int) -> Array:
        """The n-th Taylor coefficient of the profile about `t0`: `kappa^(n)(t0) / n!`, elementwise in `t0`."""

    def __call__(self, u: Float[Array, " P"], v: Float[Array, " P"]) -> Array:
        """`k(u, v)` for two regressor vectors."""
        return self.profile(jnp.dot(u, v))

    def gram(self, rows: Float[Array, "N P"], centres: Float[Array, "M P"]) -> Float[Array, "N M"]:
        """The kernel matrix `K_ij = k(rows_i, centres_j)`."""
        return self.profile(rows @ centres.T)


class PolynomialKernel(AbstractKernel):
    """The polynomial kernel of degree D, `k_p(u, v) = (1 + <u, v>)^D` (the kernel-method paper eq. 7): a kernel
    model with it is a Volterra series (or polynomial NARX) of finite degree D, every monomial of the regressors
    up to degree D. The paper's models had D = 3-4.

    **Arguments:** `degree`, the integer D >= 1 (static: it fixes the computation).

    ```python
    >>> import fricjax as fj
    >>> float(fj.PolynomialKernel(3)([1.0, 2.0], [0.5, 0.25]))  # (1 + 1) ** 3
    8.0
    ```
    """

    degree: int = eqx.field(static=True)

    def __init__(self, degree: int = 3):
        self.degree = positive_int(degree, "degree", "PolynomialKernel", hint="(D of (1 + <u, v>)^D)")

    def __call__(self, u: Any, v: Any) -> Array:
        return self.profile(jnp.dot(as_float_array(u), as_float_array(v)))

    def profile(self, t: Array) -> Array:
        return (1 + t) ** self.degree  # an integer power: exact, and finite derivatives where 1 + t = 0

    def taylor(self, t0: Array, n: int) -> Array:
        if n > self.degree:
            return jnp.zeros_like(t0)
        return math.comb(self.degree, n) * (1 + t0) ** (self.degree - n)


class ExponentialKernel(AbstractKernel):
    """The exponential kernel of width p, `k_e(u, v) = exp(<u, v> / p)` (the kernel-method paper eq. 8): a kernel
    model with it is a Volterra series (or NARX) of infinite degree, the degree-n part weighted by
    `1 / (p^n n!)`. The paper chose p = 9.7-9.9 for its Volterra series (memory 22-23) and 1.3-1.7 for its NARX
    models (11 inputs and 1-3 past outputs), in normalised units.

    **Arguments:** `width`, p > 0 (dimensionless: the regressors are normalised); held fixed (`fj.Fixed`): a
    hyperparameter chosen by validation, not trained.

    ```python
    >>> import fricjax as fj
    >>> round(float(fj.ExponentialKernel(2.0)([1.0, 2.0], [0.5, 0.25])), 6)  # exp(1 / 2)
    1.648721
    ```
    """

    width: FixedScalar

    def __init__(self, width: Any = 1.0):
        self.width = fixed_array(width, (), "width", "ExponentialKernel", positive=True)

    def __call__(self, u: Any, v: Any) -> Array:
        return self.profile(jnp.dot(as_float_array(u), as_float_array(v)))

    def profile(self, t: Array) -> Array:
        return jnp.exp(t / unwrap(self.width))

    def taylor(self, t0: Array, n: int) -> Array:
        p = unwrap(self.width)
        return jnp.exp(t0 / p) / (p**n * math.factorial(n))


class KernelNARX(AbstractNARX):
    """A kernel NARX friction model, or a kernel Volterra series (the kernel-method paper §2, eqs. 5-12):

    `F_k = output_mean + output_scale * (b + sum_i mask_i alpha_i k(c_i, phi_k))`,

    `phi_k` the regressor vector of `regressors` (`fj.NARXRegressors`: normalised lags of the input signals, the
    paper's memory M = `input_lags + 1` samples of the displacement, and `output_lags` = the paper's N_AR past
    forces; `output_lags=0` is the Volterra series), `k` a dot-product kernel (`fj.PolynomialKernel(D)`,
    finite degree, or `fj.ExponentialKernel(p)`, infinite degree), `c_i` the centres (the training regressor
    rows, or Nyström landmarks), `alpha_i` their coefficients and `b` a constant (normalised units). State: the
    regressor history (`fj.NARXState`).

    The centres, the kernel's width and the normalisation are fixed (`fj.Fixed`); `alpha` and `b` are trainable,
    so a model identified by kernel ridge regression on the one-step rows (`fj.identify_kernel_narx`) can be
    refined by output error: `fj.fit(model, data, loss=fj.SimulationLoss())`. Its Volterra kernels are
    `fj.volterra_kernels(model, order)`.

    **Arguments:**

    - `regressors`: an `fj.NARXRegressors` (signals, lags, normalisation, optional play operators).
    - `kernel`: an `fj.PolynomialKernel` or `fj.ExponentialKernel`.
    - `centres`: shape `(m, regressors.size)`, normalised regressor vectors; fixed.
    - `alpha`: shape `(m,)`, the kernel coefficients; trainable.
    - `b`: the constant (normalised); trainable.
    - `unit_mask`: 0/1 per centre (default ones; fixed): sweeps over centre sets as masks of one shape.

    ```python
    >>> import numpy as np, fricjax as fj
    >>> regressors = fj.NARXRegressors(("x",), input_lags=1, output_lags=0)     # phi_k = [x_k, x_{k-1}]
    >>> model = fj.KernelNARX(regressors, fj.PolynomialKernel(2), centres=[[1.0, 0.0]], alpha=[0.5])
    >>> motion = fj.Motion.from_position(np.array([1.0, 2.0]), dt=1e-3)
    >>> [float(f) for f in fj.simulate(model, motion)]                           # 0.5 (1 + x_k)^2
    [2.0, 4.5]
    ```
    """

    regressors: NARXRegressors
    kernel: AbstractKernel
    centres: Fixed[Float[Array, "M P"]]
    alpha: Array
    b: Array
    unit_mask: Fixed[Float[Array, " M"]]

    def __init__(
        self,
        regressors: NARXRegressors,
        kernel: AbstractKernel,
        centres: Any,
        alpha: Any,
        b: Any = 0.0,
        *,
        unit_mask: Any = None,
    ):
        if not isinstance(regressors, NARXRegressors):
            raise TypeError(f"KernelNARX: `regressors` must be an fj.NARXRegressors, got {type(regressors).__name__}.")
        if not isinstance(kernel, AbstractKernel):
            raise TypeError(
                "KernelNARX: `kernel` must be an fj.PolynomialKernel(degree) or fj.ExponentialKernel(width), got "
                f"{type(kernel).__name__}."
            )
        self.regressors, self.kernel = regressors, kernel
        self.alpha, self.b = as_float_array(alpha), as_float_array(b)
        count = self.alpha.shape[0] if self.alpha.ndim == 1 else -1
        if count < 0 or self.b.shape != ():
            raise ValueError(
                f"KernelNARX: `alpha` must have shape (m,) (one coefficient per centre) and `b` be a scalar; got "
                f"{self.alpha.shape} and {self.b.shape}."
            )
        raw = centres.value if isinstance(centres, Fixed) else centres
        if np.shape(raw) != (count, regressors.size):
            raise ValueError(
                f"KernelNARX: `centres` must have shape ({count}, {regressors.size}) (one normalised regressor vector "
                f"per coefficient, regressors.size = {regressors.size}), got {np.shape(raw)}."
            )
        self.centres = fixed_array(raw, (count, regressors.size), "centres", "KernelNARX")
        self.unit_mask = unit_mask_field(unit_mask, count, "KernelNARX", "centre")

    @property
    def num_centres(self) -> int:
        """The number m of centres (and of coefficients `alpha`)."""
        return int(self.alpha.shape[0])

    def network(self, phi: Float[Array, " P"]) -> Array:
        p = unwrap(self)
        values = p.kernel.profile(p.centres @ phi)
        return p.b + jnp.dot(p.alpha * p.unit_mask, values)

    def regressor_matrix(self, motion: Motion, measured: Any, play_states: Any = None) -> Float[Array, "T M"]:
        """The kernel matrix of the record's teacher-forced regressor rows against the centres, `(T, m)` (the
        model is linear in `alpha`: its one-step prediction is `denormalise(b + regressor_matrix @ (mask *
        alpha))`). It is `T x m` numbers: for long records use `fj.simulate(model, motion, measured=...)`.
        `play_states`: with play operators among the regressors, their states along the record,
        `fj.simulate(model.regressors.play_operators, motion)`."""
        self.check_inputs(motion)
        rows = self.regressors.teacher_forced(motion.samples(self.requires), measured, play_states)
        p = unwrap(self)
        return p.kernel.gram(rows, p.centres)


def volterra_kernels(model: KernelNARX, order: int, *, physical: bool = False) -> tuple[Array, ...]:
    """The Volterra kernels `h_0, h_1, ..., h_order` of a kernel model (the kernel-method paper §2 and §4 (4)).

    A dot-product kernel expands in powers of the inner product, so the model is a power series in its
    regressor vector `z`:

    `F(z) = h_0 + sum_j h_1[j] z_j + sum_{j,l} h_2[j, l] z_j z_l + ...`, with
    `h_n[j_1, ..., j_n] = sum_i w_i^(n) d_{i j_1} ... d_{i j_n}` (symmetric),

    where for the polynomial kernel of degree D (eq. 7) `w_i^(n) = alpha_i binom(D, n) (1 + a_i)^(D - n)` (zero for
    n > D: `order = D` gives the whole model) and for the exponential kernel of width p (eq. 8)
    `w_i^(n) = alpha_i exp(a_i / p) / (p^n n!)`.

    - `physical=False` (default): `z` is the normalised regressor vector `phi` (masks applied) and `F` the
      normalised force: `d_i = c_i`, `a_i = 0`, `h_0` includes `b`.
    - `physical=True`: `z` holds the raw regressors in their units (each input signal in SI units at its lags,
      the play states, the past forces [N]) and `F` is in N: the normalisation is folded in (`phi = mask (z -
      mean) / scale` gives `d_i = c_i mask / scale`, `a_i = -<d_i, mean>`), and the output's scale and mean too.

    For a NARX (`output_lags > 0`) these are the kernels of the paper's eq. 12, in the "general input vector" of
    past inputs and past outputs (in the regressor order of `fj.NARXRegressors`: inputs lag-major, then the
    plays, then the outputs `F_{k-1}, ..., F_{k-n_y}`); for a Volterra series the `h_n` of eq. 1.

    **Arguments:** `model`, an `fj.KernelNARX`; `order`, the highest order n >= 0 wanted (a tensor of `P^n`
    numbers, `P = regressors.size`); `physical`, see above.

    **Returns:** a tuple `(h_0, h_1, ..., h_order)`, `h_n` of shape `(P,) * n`.

    ```python
    >>> import fricjax as fj
    >>> regressors = fj.NARXRegressors(("x",), input_lags=1, output_lags=0)
    >>> model = fj.KernelNARX(regressors, fj.PolynomialKernel(2), centres=[[1.0, 0.0]], alpha=[0.5])
    >>> h0, h1, h2 = fj.volterra_kernels(model, 2)                      # 0.5 (1 + x_k)^2
    >>> float(h0), h1.tolist(), h2.tolist()
    (0.5, [1.0, 0.0], [[0.5, 0.0], [0.0, 0.0]])
    ```
    """
    if not isinstance(model, KernelNARX):
        raise TypeError(f"volterra_kernels: `model` must be an fj.KernelNARX, got {type(model).__name__}.")
    order = nonnegative_int(order, "order", "volterra_kernels", hint="(the highest kernel wanted)")
    size = model.regressors.size
    if order > len(string.ascii_letters) - 1 or size**order > _MAX_KERNEL_ENTRIES:
        raise ValueError(
            f"volterra_kernels: `order` {order} asks for a tensor of {size}^{order} numbers (regressors.size = "
            f"{size}); the limit is {_MAX_KERNEL_ENTRIES:.0e}: lower `order`."
        )
    p = unwrap(model)
    centres = p.centres
    weights = p.alpha * p.unit_mask
    if physical:
        mean, scale, mask = _regressor_affine(p.regressors)
        directions = centres * (mask / scale)
        shifts = -(directions @ mean)
        gain, offset = p.regressors.output_scale, p.regressors.output_mean
    else:
        directions, shifts = centres, jnp.zeros(centres.shape[0], centres.dtype)
        gain, offset = jnp.ones((), centres.dtype), jnp.zeros((), centres.dtype)
    kernels = []
    letters = string.ascii_letters[1:]
    for n in range(int(order) + 1):
        w = weights * p.kernel.taylor(shifts, n)
        if n == 0:
            h = jnp.sum(w) + p.b
        else:
            indices = letters[:n]
            spec = "a," + ",".join(f"a{c}" for c in indices) + "->" + indices
            h = jnp.einsum(spec, w, *([directions] * n), optimize="greedy")
        kernels.append(gain * h + (offset if n == 0 else 0.0))
    return tuple(kernels)


def _regressor_affine(regressors: NARXRegressors) -> tuple[Array, Array, Array]:
    """Per entry of the regressor vector: the mean and scale that normalise it and its mask, so that
    `phi = mask * (z - mean) / scale` for the raw regressors `z` (inputs lag-major, plays, past outputs)."""
    r = unwrap(regressors)
    lags, plays, outputs = regressors.input_lags + 1, regressors.num_plays, regressors.output_lags
    dtype = jnp.result_type(r.output_scale)
    mean = jnp.concatenate(
        [jnp.tile(r.input_mean, lags), jnp.zeros(plays, dtype), jnp.full((outputs,), r.output_mean, dtype)]
    )
    scale = jnp.concatenate(
        [jnp.tile(r.input_scale, lags), jnp.ones(plays, dtype), jnp.full((outputs,), r.output_scale, dtype)]
    )
    mask = jnp.concatenate(
        [jnp.repeat(r.input_mask, len(regressors.signals)), jnp.ones(plays, dtype), r.output_mask.astype(dtype)]
    )
    return mean, scale, mask
