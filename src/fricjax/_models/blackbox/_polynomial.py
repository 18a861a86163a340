"""Polynomial NARX: monomials of the NARX regressors, with terms chosen by forward orthogonal least squares.

`y_k = theta0 + sum_m theta_m phi_m(x_k)` (parlitz2004 §III-D eqs. 16-18, worden2007 §5.1 eqs. 17-19), the basis
functions `phi_m(x) = prod_i x_i^{p_im}` monomials of total degree `sum_i p_im <= D` of the regressor vector
`x_k = [u_k, ..., u_{k-n_u}, y_{k-1}, ..., y_{k-n_y}]` (`fj.NARXRegressors`: lagged, normalised inputs and fed-back
outputs). The model is linear in `theta`, so under teacher forcing it is a linear regression: its candidate
monomials are ranked by their error-reduction ratio and kept while the leave-one-out error (PRESS) falls
(`fj.select_terms`, FROLS), and `theta` is their least-squares solution (`identify_polynomial_narx`). The free run
(the papers' prediction, "NOE") is a nonlinear function of `theta`: refine it with
`fj.fit(model, data, loss=fj.SimulationLoss())`.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from typing import Any

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..._constraints import Fixed, as_float_array, unwrap
from ..._inputs import Motion
from ..._validation import positive_int
from ._narx import AbstractNARX, unit_mask_field
from ._regressors import NARXRegressors

Terms = tuple[tuple[int, ...], ...]
"""Monomials as exponent tuples over the regressor vector: `(0, 2, 1)` is `x_1^2 x_2`; `(0, 0, 0)` the constant."""


def monomial_terms(size: int, degree: int, *, constant: bool = False) -> Terms:
    """Every monomial of `size` variables with total degree 1..`degree` (0..`degree` with `constant=True`), as
    exponent tuples, graded: by degree, then in the order of `itertools.combinations_with_replacement` of the
    variable indices (`x_0, x_1, ..., x_0^2, x_0 x_1, ...`). There are `binom(size + degree, degree) - 1` of them
    (plus the constant).

    ```python
    >>> import fricjax as fj
    >>> fj.monomial_terms(2, 2)
    ((1, 0), (0, 1), (2, 0), (1, 1), (0, 2))
    ```
    """
    degree = positive_int(degree, "degree", "monomial_terms", hint="(the largest total degree of a monomial)")
    size = positive_int(size, "size", "monomial_terms", hint="(the number of variables)")
    terms = []
    for d in range(0 if constant else 1, degree + 1):
        for combination in itertools.combinations_with_replacement(range(size), d):
            terms.append(tuple(int(np.sum(np.asarray(combination) == i)) for i in range(size)))
    return tuple(terms)


def _factor_index(terms: Terms, size: int) -> np.ndarray:
    """`(M, D)` indices into `[x, 1]` (length `size + 1`): term m is the product of the entries its row names,
    `x_i` repeated by its exponent, padded with `size` (the appended 1). `D` = the largest degree (at least 1)."""
    width = max([1, *(sum(t) for t in terms)])
    index = np.full((len(terms), width), size, dtype=np.int32)
    for m, term in enumerate(terms):
        factors = [i for i, power in enumerate(term) for _ in range(power)]
        index[m, : len(factors)] = factors
    return index


def evaluate_monomials(x: Any, terms: Terms) -> Any:
    """The monomials `terms` of the regressor vectors `x` (`(..., P)`, NumPy or JAX): shape `(..., M)`.

    A gather of the factors and one product (no powers: finite derivatives at 0, one fused computation)."""
    xp = np if isinstance(x, np.ndarray) else jnp
    index = _factor_index(terms, x.shape[-1])
    extended = xp.concatenate([x, xp.ones((*x.shape[:-1], 1), dtype=x.dtype)], axis=-1)
    return xp.prod(extended[..., index], axis=-1)


def _check_terms(terms: Any, size: int) -> Terms:
    try:
        checked = tuple(tuple(int(p) for p in term) for term in terms)
    except TypeError as error:
        raise ValueError(
            f"PolynomialNARX: `terms` must be a sequence of exponent tuples (one exponent per regressor, {size} "
            "regressors), e.g. fj.monomial_terms(regressors.size, 3)."
        ) from error
    for term in checked:
        if len(term) != size or any(p < 0 for p in term):
            raise ValueError(
                f"PolynomialNARX: every term must be {size} non-negative exponents (one per regressor: "
                f"regressors.size = {size}), got {term}."
            )
    if len(set(checked)) != len(checked):
        raise ValueError("PolynomialNARX: `terms` repeats a monomial; each term may appear once.")
    return checked


class PolynomialNARX(AbstractNARX):
    """A polynomial NARX friction model (parlitz2004 §III-D eqs. 16-18, worden2007 §5.1): in normalised units,

    `y_k = theta0 + sum_m mask_m theta_m prod_i x_ki^{p_im}`,

    `x_k` the regressor vector of `regressors` (`fj.NARXRegressors`: the signals `u` = displacement or its
    increment, velocity, acceleration at lags 0..n_u, and the past forces at lags 1..n_y, each normalised), and
    the force `F_k = output_mean + output_scale * y_k` [N]. State: the regressor history (`fj.NARXState`).

    Build it from data with `fj.identify_polynomial_narx` (term selection by FROLS with PRESS, coefficients by
    least squares under teacher forcing); refine the coefficients by output error with
    `fj.fit(model, data, loss=fj.SimulationLoss())`. parlitz2004's model was a degree-3 polynomial of 32 monomials
    of the displacement at 10 lags and one past force; worden2007's one of degree 5 (84 monomials).

    **Arguments:**

    - `regressors`: an `fj.NARXRegressors` (signals, lags, normalisation).
    - `terms`: the monomials, exponent tuples of length `regressors.size` (static: they fix the computation).
    - `theta`: their coefficients, shape `(M,)` (normalised units); trainable.
    - `theta0`: the constant term (normalised); trainable.
    - `unit_mask`: 0/1 per term (default ones; fixed): sweeps over structures as masks over one candidate set.

    The regressors of the model (linear in `theta`, `theta0`) are `model.regressor_matrix(motion, force)`.

    ```python
    >>> import numpy as np, fricjax as fj
    >>> regressors = fj.NARXRegressors(("v",), input_lags=0, output_lags=1)        # x_k = [v_k, y_{k-1}]
    >>> model = fj.PolynomialNARX(regressors, terms=((1, 0), (0, 1), (1, 1)), theta=[0.5, 0.8, 0.1])
    >>> motion = fj.Motion.from_velocity(np.ones(3), dt=1e-3)
    >>> [round(float(f), 4) for f in fj.simulate(model, motion)]                 # y = 0.5 v + 0.8 y1 + 0.1 v y1
    [0.5, 0.95, 1.355]
    ```
    """

    regressors: NARXRegressors
    terms: Terms = eqx.field(static=True)
    theta: Array
    theta0: Array
    unit_mask: Fixed[Float[Array, " M"]]

    def __init__(
        self,
        regressors: NARXRegressors,
        terms: Sequence[Sequence[int]],
        theta: Any,
        theta0: Any = 0.0,
        *,
        unit_mask: Any = None,
    ):
        if not isinstance(regressors, NARXRegressors):
            raise TypeError(
                f"PolynomialNARX: `regressors` must be an fj.NARXRegressors, got {type(regressors).__name__}."
            )
        self.regressors = regressors
        self.terms = _check_terms(terms, regressors.size)
        self.theta, self.theta0 = as_float_array(theta), as_float_array(theta0)
        if self.theta.shape != (len(self.terms),) or self.theta0.shape != ():
            raise ValueError(
                f"PolynomialNARX: `theta` must have shape ({len(self.terms)},) (one coefficient per term) and "
                f"`theta0` be a scalar; got {self.theta.shape} and {self.theta0.shape}."
            )
        self.unit_mask = unit_mask_field(unit_mask, len(self.terms), "PolynomialNARX", "term")

    @property
    def degree(self) -> int:
        """The largest total degree of the model's monomials (0 for a constant model)."""
        return max([0, *(sum(t) for t in self.terms)])

    def network(self, phi: Float[Array, " P"]) -> Array:
        return self.theta0 + jnp.dot(self.theta * unwrap(self.unit_mask), evaluate_monomials(phi, self.terms))

    def regressor_matrix(self, motion: Motion, measured: Any, play_states: Any = None) -> Float[Array, "T M"]:
        """The model's monomials along a record under teacher forcing, `(T, M)` (normalised units, mask not
        applied): the one-step prediction is `denormalise(theta0 + regressor_matrix @ (mask * theta))`.
        `play_states`: with play operators among the regressors, their states along the record,
        `fj.simulate(model.regressors.play_operators, motion)`."""
        self.check_inputs(motion)
        phi = self.regressors.teacher_forced(motion.samples(self.requires), measured, play_states)
        return evaluate_monomials(phi, self.terms)

    def describe(self) -> list[str]:
        """The model's terms as strings (`"v[k-1]*F[k-2]^2"`), in the order of `terms`."""
        return [_term_name(term, self.regressors) for term in self.terms]


def _regressor_names(regressors: NARXRegressors) -> list[str]:
    names = [
        f"{s}[k]" if i == 0 else f"{s}[k-{i}]" for i in range(regressors.input_lags + 1) for s in regressors.signals
    ]
    return names + [f"F[k-{j}]" for j in range(1, regressors.output_lags + 1)]


def _term_name(term: tuple[int, ...], regressors: NARXRegressors) -> str:
    names = _regressor_names(regressors)
    factors = [name if p == 1 else f"{name}^{p}" for name, p in zip(names, term, strict=True) if p > 0]
    return "*".join(factors) or "1"
