"""Wavelet-network NARX: MATLAB's `wavenet` nonlinearity (the default of `nlarx`) on the NARX regressors.

The emps-ensemble paper (§3.2, eqs. 13-15) models friction-related error with a nonlinear ARX model whose map
`F` is a wavelet network (Oussar et al. 1998; Zhang 1997), estimated with MATLAB's `nlarx` and its `wavenet`
estimator. This is that estimator's function (the MATLAB reference page of `wavenet` / `idWaveletNetwork`):

`F(x) = (x - r) P L + sum_k a_k f(b_k ((x - r) Q - c_k)) + sum_k s_k g(beta_k ((x - r) Q - gamma_k)) + d`

with the radial wavelet (a "Mexican hat") and scaling function of the projected vector `z` (length `q`)

`f(z) = (q - |z|^2) exp(-|z|^2 / 2)`,   `g(z) = exp(-|z|^2 / 2)`,

`x` the regressor vector `phi_k` (`fj.NARXRegressors`: normalised lags of the inputs, optional play operators,
past forces), `r` its mean over the training record, `P` `(m, p)` and `Q` `(m, q)` fixed projections (MATLAB: from
a principal-component analysis of the regressors), `L` the linear weights, `a_k`, `b_k > 0`, `c_k` the wavelets'
coefficients, dilations and centres (translations), `s_k`, `beta_k > 0`, `gamma_k` the scaling functions' and `d`
the offset. The paper's eq. 14 writes a product of one-dimensional wavelets per unit (Oussar's form); MATLAB's,
implemented here, is radial: one dilation per unit, the same in every (projected) direction.

The network is linear in `(L, a, s, d)` once the units' centres and dilations are placed: `fj.identify_wavelet_narx`
places them from the data and solves those by least squares under teacher forcing; `fj.fit(model, data,
loss=fj.SimulationLoss())` then refines every parameter by output error (NOE).
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..._constraints import Fixed, Positive, as_float_array, real, unwrap
from ..._inputs import Motion
from ._narx import AbstractNARX, unit_mask_field
from ._regressors import NARXRegressors, fixed_array


def wavelet(z2: Any, dim: int) -> Any:
    """MATLAB's radial wavelet `f(z) = (dim - |z|^2) exp(-|z|^2 / 2)` of the squared norm `z2 = |z|^2`."""
    return (dim - z2) * jnp.exp(-0.5 * z2)


def scaling_function(z2: Any) -> Any:
    """MATLAB's radial scaling function `g(z) = exp(-|z|^2 / 2)` of the squared norm `z2 = |z|^2`."""
    return jnp.exp(-0.5 * z2)


def _squared_distances(z: Array, centres: Array, dilations: Array) -> Array:
    """`|dilation_k (z - centre_k)|^2`, shape `(..., K)` for `z` `(..., q)`, `centres` `(K, q)`."""
    difference = z[..., None, :] - centres
    return dilations**2 * jnp.sum(difference * difference, axis=-1)


class WaveletNARX(AbstractNARX):
    """A wavelet-network NARX friction model: MATLAB's `wavenet` (the emps-ensemble paper's `nlarx` estimator),
    in normalised units,

    `y_k = (x_k - r) P L + sum_j a_j f(b_j ((x_k - r) Q - c_j)) + sum_j s_j g(beta_j ((x_k - r) Q - gamma_j)) + d`,

    `f(z) = (q - |z|^2) exp(-|z|^2/2)` (wavelet), `g(z) = exp(-|z|^2/2)` (scaling function), `q` = the columns of
    `Q`, `x_k` the regressor vector of `regressors` (`fj.NARXRegressors`), and the force
    `F_k = output_mean + output_scale * y_k` [N]. State: the regressor history (`fj.NARXState`). Smooth: the
    exact and smooth modes coincide (except for play-operator regressors, smoothed by `regressors.smoothing`).

    Build it from data with `fj.identify_wavelet_narx` (PCA projection, units placed on a dyadic grid of
    dilations at data-spread centres and chosen by orthogonal least squares, linear coefficients by least
    squares under teacher forcing); refine by output error with `fj.fit(model, data, loss=fj.SimulationLoss())`.

    **Arguments:**

    - `regressors`: an `fj.NARXRegressors` (signals, lags, normalisation, optional play operators); `m =
      regressors.size`.
    - `center`: `r`, shape `(m,)` (fixed: the regressors' mean over the training record).
    - `Q`: `(m, q)`, the projection of the units' inputs (fixed; PCA, from `identify_wavelet_narx`).
    - `L`: `(p,)` linear weights (trainable).
    - `a`, `b`, `c`: the wavelets' coefficients `(Kw,)`, dilations `(Kw,)` (> 0, stored as logs) and centres
      `(Kw, q)` (trainable; `Kw` may be 0).
    - `s`, `beta`, `gamma`: the scaling functions' coefficients `(Ks,)`, dilations `(Ks,)` (> 0) and centres
      `(Ks, q)` (trainable; `Ks` may be 0).
    - `d`: the offset (normalised; trainable).
    - `P`: `(m, p)`, the projection of the linear part (fixed; default the identity, `p = m`).
    - `unit_mask`: 0/1 per unit, wavelets first then scaling functions, shape `(Kw + Ks,)` (default ones; fixed):
      sweeps over network sizes as masks over one maximal network.

    `model.regressor_matrix(motion, force)` gives the columns the network is linear in (`L`, `a`, `s`) under
    teacher forcing; `fj.fit(..., separable=("L", "a", "s", "d"))` solves them by least squares in a free run
    when the model feeds back no outputs (`output_lags=0`, e.g. play-operator regressors).

    ```python
    >>> import numpy as np, fricjax as fj
    >>> regressors = fj.NARXRegressors(("v",), input_lags=0, output_lags=1)    # x_k = [v_k, y_{k-1}]
    >>> model = fj.WaveletNARX(regressors, center=[0.0, 0.0], Q=np.eye(2), L=[0.5, 0.8], a=[0.1], b=[1.0],
    ...                        c=[[0.0, 0.0]], s=[], beta=[], gamma=np.zeros((0, 2)), d=0.0)
    >>> motion = fj.Motion.from_velocity(np.ones(3), dt=1e-3)
    >>> [round(float(f), 4) for f in fj.simulate(model, motion)]
    [0.5607, 0.9841, 1.2884]
    ```
    """

    regressors: NARXRegressors
    center: Fixed[Float[Array, " m"]]
    P: Fixed[Float[Array, "m p"]]
    Q: Fixed[Float[Array, "m q"]]
    L: Array
    a: Array
    b: Positive
    c: Array
    s: Array
    beta: Positive
    gamma: Array
    d: Array
    unit_mask: Fixed[Float[Array, " Kw+Ks"]]

    def __init__(
        self,
        regressors: NARXRegressors,
        *,
        center: Any,
        Q: Any,
        L: Any,
        a: Any,
        b: Any,
        c: Any,
        s: Any,
        beta: Any,
        gamma: Any,
        d: Any = 0.0,
        P: Any = None,
        unit_mask: Any = None,
    ):
        name = "WaveletNARX"
        if not isinstance(regressors, NARXRegressors):
            raise TypeError(f"{name}: `regressors` must be an fj.NARXRegressors, got {type(regressors).__name__}.")
        m = regressors.size
        self.regressors = regressors
        self.center = fixed_array(center, (m,), "center", name)
        q_shape = np.shape(unwrap(Q))
        if len(q_shape) != 2 or q_shape[0] != m or q_shape[1] < 1:
            raise ValueError(
                f"{name}: `Q` (the units' projection) must have shape ({m}, q) with q >= 1 (one row per regressor, "
                f"regressors.size = {m}), got {q_shape}."
            )
        q = int(q_shape[1])
        self.Q = fixed_array(Q, (m, q), "Q", name)
        P = np.eye(m) if P is None else P
        p_shape = np.shape(unwrap(P))
        if len(p_shape) != 2 or p_shape[0] != m:
            raise ValueError(f"{name}: `P` (the linear projection) must have shape ({m}, p), got {p_shape}.")
        self.P = fixed_array(P, p_shape, "P", name)
        self.L = _real(L, (int(p_shape[1]),), "L", "one weight per column of P")
        self.a = _real(a, _length(a), "a", "one coefficient per wavelet")
        self.s = _real(s, _length(s), "s", "one coefficient per scaling function")
        kw, ks = self.a.shape[0], self.s.shape[0]
        self.b = _dilations(b, kw, "b", "wavelet")
        self.beta = _dilations(beta, ks, "beta", "scaling function")
        self.c = _real(c, (kw, q), "c", "a centre of length q per wavelet")
        self.gamma = _real(gamma, (ks, q), "gamma", "a centre of length q per scaling function")
        self.d = _real(d, (), "d", "one number")
        self.unit_mask = unit_mask_field(unit_mask, kw + ks, name, "unit (wavelets, then scaling functions)")

    @property
    def num_wavelets(self) -> int:
        """`Kw`, the number of wavelet units."""
        return int(self.a.shape[0])

    @property
    def num_scaling(self) -> int:
        """`Ks`, the number of scaling-function units."""
        return int(self.s.shape[0])

    @property
    def dim(self) -> int:
        """`q`, the dimension of the units' (projected) input."""
        return int(np.shape(unwrap(self.Q))[1])

    def features(self, phi: Float[Array, "... m"]) -> Float[Array, "... n"]:
        """The columns the network is linear in, for regressor vectors `phi` (`(..., m)`):
        `[(phi - r) P, f(b_j ((phi - r) Q - c_j)) for each wavelet, g(beta_j ((phi - r) Q - gamma_j)) for each
        scaling function]`, shape `(..., p + Kw + Ks)` (mask not applied)."""
        p = unwrap(self)
        x = phi - p.center
        z = x @ p.Q
        wavelets = wavelet(_squared_distances(z, p.c, p.b), self.dim)
        scaling = scaling_function(_squared_distances(z, p.gamma, p.beta))
        return jnp.concatenate([x @ p.P, wavelets, scaling], axis=-1)

    @property
    def weights(self) -> Array:
        """The linear coefficients of `features`: `[L, mask * a, mask * s]`."""
        p = unwrap(self)
        return jnp.concatenate([p.L, jnp.concatenate([p.a, p.s]) * p.unit_mask])

    def network(self, phi: Float[Array, " m"]) -> Array:
        return jnp.dot(self.features(phi), self.weights) + self.d

    def regressor_matrix(self, motion: Motion, measured: Any, play_states: Any = None) -> Float[Array, "T n"]:
        """The network's linear-in-parameters columns along a record under teacher forcing, `(T, p + Kw + Ks)`
        (normalised units, mask not applied): the one-step prediction is
        `regressors.denormalise(d + regressor_matrix @ [L, mask * a, mask * s])`. `play_states`: with play
        operators among the regressors, their states along the record,
        `fj.simulate(model.regressors.play_operators, motion)`."""
        self.check_inputs(motion)
        return self.features(self.regressors.teacher_forced(motion.samples(self.requires), measured, play_states))


def _length(value: Any) -> tuple[int]:
    return (int(np.size(unwrap(value))),)


def _real(value: Any, shape: tuple[int, ...], name: str, what: str) -> Array:
    try:
        array = real(value, name)
    except ValueError as error:
        raise ValueError(f"WaveletNARX: {error}") from None
    if array.size == 0 and int(np.prod(shape)) == 0:
        array = jnp.reshape(array, shape)  # [] for an empty set of units
    if array.shape != shape:
        raise ValueError(f"WaveletNARX: `{name}` must have shape {shape} ({what}), got {array.shape}.")
    return array


def _dilations(value: Any, units: int, name: str, what: str) -> Positive:
    array = as_float_array(value)
    if array.size == 0:
        array = jnp.reshape(array, (0,))
    if array.shape != (units,):
        raise ValueError(
            f"WaveletNARX: `{name}` must have shape ({units},) (one dilation per {what}), got {array.shape}."
        )
    try:
        return Positive(array, name=name)
    except ValueError as error:
        raise ValueError(f"WaveletNARX: {error} (`{name}` holds dilations, each > 0)") from None
