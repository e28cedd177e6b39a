r"""Linear viscoelastic rheologies in shear, and exact conversions between their forms.

All moduli are shear moduli $G$ [Pa] of an incompressible material, so one MDR spring of
width $\Delta x$ has stiffness $4G(t)\,\Delta x$ (`docs/physics.md` §3). Times are in seconds,
viscosities in Pa s, compliances in 1/Pa.

Every linear solid with a finite glass modulus and a non-zero relaxed modulus has two
equivalent discrete forms:

- **creep form** (`CreepChain`): a spring $G_0$ in series with $N$ Kelvin elements
  $(G_k, \eta_k)$, retardation times $\theta_k = \eta_k/G_k$,
  $$J(t) = \frac{1}{G_0} + \sum_k \frac{1}{G_k}\big(1 - e^{-t/\theta_k}\big);$$
- **relaxation form** (`PronySeries`): a long-time spring $G_\infty$ in parallel with $N$
  Maxwell arms $(G_k, \tau_k)$,
  $$G(t) = G_\infty + \sum_k G_k\, e^{-t/\tau_k}.$$

The glass (instantaneous) modulus is $G_0$ in the creep form and $G_\infty + \sum_k G_k$ in
the relaxation form; the relaxed modulus obeys $1/G_\infty = 1/G_0 + \sum_k 1/G_k$ (creep
form). The energetic detachment criterion uses the glass modulus.

`to_prony` and `to_creep_chain` convert exactly (to rounding) by one symmetric
eigenproblem (`jnp.linalg.eigh`) each, so they work under `jit`, `vmap` and `grad`. The
paper's standard model is `StandardModel`; `Elastic` has no arms.

Each rheology is an `equinox.Module` (a pytree). Scalar parameters must be 0-d and arm
parameters 1-D; to batch over parameters construct the rheology inside `jax.vmap` (or vmap
over a rheology whose leaves carry a leading batch axis). Parameters are checked when the
rheology is built from concrete values (`ValueError`); under `jit`/`vmap` its methods raise
at run time for parameters outside their domain (`domain()`), and the entry functions
(`retract`, `simulate`) report them per lane as `RESULTS.invalid_rheology`.
"""

from __future__ import annotations

import abc

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Complex, Float

from ._solvers import as_float
from ._validate import Constraint, float_field, guarded, module_repr

# Shape-annotated aliases (kept out of annotations so that linters do not parse the strings).
Scalar = Float[Array, ""]
Arms = Float[Array, " N"]
TimeLike = Float[ArrayLike, "..."]
Real = Float[Array, "..."]
Cplx = Complex[Array, "..."]

__all__ = [
    "AbstractRheology",
    "Elastic",
    "StandardModel",
    "CreepChain",
    "PronySeries",
]


# --------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------


def _as_float_1d(x) -> Array:
    return jnp.atleast_1d(as_float(x))


def _check_scalar(name: str, value) -> None:
    if jnp.ndim(value) != 0:
        raise ValueError(
            f"`{name}` must be a scalar (0-d); got shape {jnp.shape(value)}. "
            "To batch over parameters, build the rheology inside `jax.vmap`."
        )


def _check_arms(names: tuple[str, str], a, b) -> None:
    if jnp.ndim(a) != 1 or jnp.shape(a) != jnp.shape(b):
        raise ValueError(
            f"`{names[0]}` and `{names[1]}` must be 1-D arrays of the same length; got shapes "
            f"{jnp.shape(a)} and {jnp.shape(b)}."
        )


def _empty_like(x) -> Array:
    return jnp.zeros((0,), dtype=jnp.result_type(x))


def _exp_sum(amplitude, time, t, one_minus: bool) -> Array:
    r"""$\sum_k A_k e^{-t/T_k}$ (or $\sum_k A_k (1 - e^{-t/T_k})$), elementwise over `t`."""
    t = jnp.asarray(t)[..., None]
    x = -t / _trailing(time, t.ndim)
    e = -jnp.expm1(x) if one_minus else jnp.exp(x)
    return jnp.sum(_trailing(amplitude, t.ndim) * e, axis=-1)


def _trailing(arms, ndim: int) -> Array:
    """The per-arm vector `arms` (shape `(N,)`) as shape `(1, ..., 1, N)` of rank `ndim`
    (explicit broadcasting against `t[..., None]`)."""
    return jnp.reshape(arms, (1,) * (ndim - 1) + jnp.shape(arms))


# --------------------------------------------------------------------------------------
# base class
# --------------------------------------------------------------------------------------


class AbstractRheology(eqx.Module):
    r"""Base class of all linear viscoelastic rheologies (shear, incompressible).

    Provides

    - `glass_modulus`: the instantaneous modulus $G(0^+)$ [Pa];
    - `relaxed_modulus`: the long-time modulus $G_\infty = G(t\to\infty)$ [Pa];
    - `relaxation(t)`: relaxation modulus $G(t)$ [Pa] for $t \ge 0$ [s];
    - `creep(t)`: creep compliance $J(t)$ [1/Pa] for $t \ge 0$ [s];
    - `complex_modulus(omega)`: $G^*(\omega)$ [Pa] at angular frequency $\omega$ [rad/s];
    - `complex_compliance(omega)`: $J^*(\omega) = 1/G^*(\omega)$ [1/Pa];
    - `to_prony()`, `to_creep_chain()`: the exact relaxation / creep forms;
    - `domain()`: the parameters and their allowed ranges (`Constraint`s).

    Every subclass implements all of them (abstract here: no concrete method is
    overridden), closed forms where it has them and the other form otherwise.
    """

    def __check_init__(self):
        for constraint in self.domain():
            constraint.check()

    def __repr__(self) -> str:
        """``StandardModel(G0=1000000.0, G1=200000.0, eta1=10000.0)``: the values."""
        return module_repr(self)

    @abc.abstractmethod
    def domain(self) -> tuple[Constraint, ...]:
        """The parameters and their allowed ranges."""

    @property
    @abc.abstractmethod
    def glass_modulus(self) -> Array:
        """Instantaneous (glass) modulus $G(0^+)$ [Pa]."""

    @property
    @abc.abstractmethod
    def relaxed_modulus(self) -> Array:
        r"""Relaxed (long-time) modulus $G_\infty$ [Pa]."""

    @abc.abstractmethod
    def relaxation(self, t: TimeLike) -> Real:
        """Relaxation modulus $G(t)$ [Pa] at times `t` [s] (t >= 0), elementwise."""

    @abc.abstractmethod
    def creep(self, t: TimeLike) -> Real:
        """Creep compliance $J(t)$ [1/Pa] at times `t` [s] (t >= 0), elementwise."""

    @abc.abstractmethod
    def complex_modulus(self, omega: TimeLike) -> Cplx:
        r"""Complex modulus $G^*(\omega) = G' + iG''$ [Pa] at `omega` [rad/s], elementwise."""

    @abc.abstractmethod
    def complex_compliance(self, omega: TimeLike) -> Cplx:
        r"""Complex compliance $J^*(\omega) = 1/G^*(\omega)$ [1/Pa] at `omega` [rad/s]."""

    @abc.abstractmethod
    def to_prony(self) -> PronySeries:
        """The equivalent relaxation form (`PronySeries`)."""

    @abc.abstractmethod
    def to_creep_chain(self) -> CreepChain:
        """The equivalent creep form (`CreepChain`)."""


# --------------------------------------------------------------------------------------
# Prony series (relaxation form)
# --------------------------------------------------------------------------------------


class PronySeries(AbstractRheology):
    r"""Relaxation form: spring $G_\infty$ in parallel with $N$ Maxwell arms.

    $$G(t) = G_\infty + \sum_{k=1}^N G_k\,e^{-t/\tau_k},\qquad
    G^*(\omega) = G_\infty + \sum_k G_k\,\frac{i\omega\tau_k}{1 + i\omega\tau_k}.$$

    Glass modulus $G_\infty + \sum_k G_k$, relaxed modulus $G_\infty$. Arm $k$ is a spring
    $G_k$ in series with a dashpot of viscosity $G_k\tau_k$.

    **Arguments:**

    - `G_inf`: relaxed (long-time) modulus $G_\infty$ [Pa], scalar, > 0.
    - `G`: arm moduli $G_k$ [Pa], shape `(N,)`, each > 0 (`N = 0` allowed).
    - `tau`: relaxation times $\tau_k$ [s], shape `(N,)`, each > 0.

    `to_creep_chain` needs distinct `tau` (merge arms with equal times first: a repeated
    time gives a Kelvin element of infinite stiffness and NaN gradients).
    """

    G_inf: Scalar = eqx.field(converter=float_field("G_inf", "Pa"))
    G: Arms = eqx.field(converter=float_field("G", "Pa", arms=True))
    tau: Arms = eqx.field(converter=float_field("tau", "s", arms=True))

    def __check_init__(self):
        _check_scalar("G_inf", self.G_inf)
        _check_arms(("G", "tau"), self.G, self.tau)

    def domain(self):
        return (Constraint("G_inf", self.G_inf, "Pa", kind="modulus"),
                Constraint("G", self.G, "Pa", kind="modulus"),
                Constraint("tau", self.tau, "s", kind="time"))

    @property
    @guarded
    def glass_modulus(self):
        return self.G_inf + jnp.sum(self.G)

    @property
    @guarded
    def relaxed_modulus(self):
        return self.G_inf

    @guarded
    def relaxation(self, t):
        return self.G_inf + _exp_sum(self.G, self.tau, t, one_minus=False)

    @guarded
    def creep(self, t):
        return self.to_creep_chain().creep(t)

    @guarded
    def complex_modulus(self, omega):
        w = jnp.asarray(omega)[..., None]
        iwt = 1j * w * _trailing(self.tau, w.ndim)
        return self.G_inf + jnp.sum(_trailing(self.G, w.ndim) * iwt / (1 + iwt), axis=-1)

    @guarded
    def complex_compliance(self, omega):
        return 1.0 / self.complex_modulus(omega)

    @guarded
    def to_prony(self):
        return self

    @guarded
    def to_creep_chain(self) -> CreepChain:
        r"""Exact creep form (retardation times in increasing order).

        At fixed stress $\sigma$ the dashpot strains $p$ of the arms obey
        $\mathrm{diag}(G\tau)\,\dot p = -(\mathrm{diag}(G) - G G^\top/G_g)\,p + G\,\sigma/G_g$
        with $G_g$ the glass modulus, and the strain is $\varepsilon = (\sigma + G^\top p)/G_g$.
        With $y = \sqrt{G/(\tau G_g)}$ the symmetrised matrix is
        $S = \mathrm{diag}(1/\tau) - y y^\top$ (positive definite since $G_\infty > 0$),
        $S = Q\,\mathrm{diag}(1/\theta)\,Q^\top$. The unit step in stress then gives
        $J(t) = 1/G_g + \sum_j (q_j^\top y)^2 (\theta_j/G_g)(1 - e^{-t/\theta_j})$, so
        $1/G_j = (q_j^\top y)^2\theta_j/G_g$ and $\eta_j = G_j\theta_j$.
        """
        Gg = self.glass_modulus
        if self.G.shape[0] == 0:
            return CreepChain(Gg, _empty_like(self.G), _empty_like(self.G))
        y = jnp.sqrt(self.G / (self.tau * Gg))
        S = jnp.diag(1.0 / self.tau) - y[:, None] * y[None, :]
        lam, Q = jnp.linalg.eigh(S)
        theta = 1.0 / lam[::-1]  # increasing retardation times
        proj = (Q.T @ y)[::-1]
        Gk = Gg / (proj**2 * theta)
        return CreepChain(Gg, Gk, Gk * theta)


# --------------------------------------------------------------------------------------
# creep chain (creep form)
# --------------------------------------------------------------------------------------


class CreepChain(AbstractRheology):
    r"""Creep form: spring $G_0$ in series with $N$ Kelvin elements $(G_k, \eta_k)$.

    $$J(t) = \frac{1}{G_0} + \sum_{k=1}^N \frac{1}{G_k}\big(1 - e^{-t/\theta_k}\big),\qquad
    \theta_k = \eta_k/G_k,$$
    $$J^*(\omega) = \frac{1}{G_0} + \sum_k \frac{1}{G_k (1 + i\omega\theta_k)}.$$

    Glass modulus $G_0$; relaxed modulus $G_\infty = (1/G_0 + \sum_k 1/G_k)^{-1}$.

    **Arguments:**

    - `G0`: instantaneous (glass) spring $G_0$ [Pa], scalar, > 0.
    - `G`: Kelvin moduli $G_k$ [Pa], shape `(N,)`, each > 0 (`N = 0` allowed).
    - `eta`: Kelvin viscosities $\eta_k$ [Pa s], shape `(N,)`, each > 0.

    `to_prony` needs distinct retardation times $\theta_k$ (merge equal ones first).
    """

    G0: Scalar = eqx.field(converter=float_field("G0", "Pa"))
    G: Arms = eqx.field(converter=float_field("G", "Pa", arms=True))
    eta: Arms = eqx.field(converter=float_field("eta", "Pa s", arms=True))

    def __check_init__(self):
        _check_scalar("G0", self.G0)
        _check_arms(("G", "eta"), self.G, self.eta)

    def domain(self):
        return (Constraint("G0", self.G0, "Pa", kind="modulus"),
                Constraint("G", self.G, "Pa", kind="modulus"),
                Constraint("eta", self.eta, "Pa s", kind="viscosity"))

    @property
    @guarded
    def retardation_time(self) -> Arms:
        r"""Retardation times $\theta_k = \eta_k/G_k$ [s], shape `(N,)`."""
        return self.eta / self.G

    @property
    @guarded
    def glass_modulus(self):
        return self.G0

    @property
    @guarded
    def relaxed_modulus(self):
        return 1.0 / (1.0 / self.G0 + jnp.sum(1.0 / self.G))

    @guarded
    def relaxation(self, t):
        return self.to_prony().relaxation(t)

    @guarded
    def creep(self, t):
        return 1.0 / self.G0 + _exp_sum(1.0 / self.G, self.retardation_time, t, one_minus=True)

    @guarded
    def complex_compliance(self, omega):
        w = jnp.asarray(omega)[..., None]
        iwt = 1j * w * _trailing(self.retardation_time, w.ndim)
        return 1.0 / self.G0 + jnp.sum(1.0 / (_trailing(self.G, w.ndim) * (1 + iwt)), axis=-1)

    @guarded
    def complex_modulus(self, omega):
        return 1.0 / self.complex_compliance(omega)

    @guarded
    def to_creep_chain(self):
        return self

    @guarded
    def to_prony(self) -> PronySeries:
        r"""Exact relaxation form (relaxation times in increasing order).

        At fixed total strain $\varepsilon$ the Kelvin elongations $u$ obey
        $\mathrm{diag}(\eta)\,\dot u = -(\mathrm{diag}(G) + G_0 \mathbf 1\mathbf 1^\top)\,u
        + G_0\varepsilon\mathbf 1$ and the stress is $\sigma = G_0(\varepsilon - \mathbf 1^\top u)$.
        With $z = \sqrt{G_0/\eta}$ the symmetrised matrix is
        $S = \mathrm{diag}(1/\theta) + z z^\top = Q\,\mathrm{diag}(1/\tau)\,Q^\top$. The unit
        strain step gives $G(t) = G_0 - \sum_j G_0 (q_j^\top z)^2\tau_j (1 - e^{-t/\tau_j})$,
        so the arm moduli are $G_j = G_0 (q_j^\top z)^2 \tau_j$; $G_\infty$ is taken from
        $1/G_\infty = 1/G_0 + \sum_k 1/G_k$ (no cancellation).
        """
        Ginf = self.relaxed_modulus
        if self.G.shape[0] == 0:
            return PronySeries(Ginf, _empty_like(self.G), _empty_like(self.G))
        z = jnp.sqrt(self.G0 / self.eta)
        S = jnp.diag(1.0 / self.retardation_time) + z[:, None] * z[None, :]
        lam, Q = jnp.linalg.eigh(S)
        tau = 1.0 / lam[::-1]  # increasing relaxation times
        proj = (Q.T @ z)[::-1]
        return PronySeries(Ginf, self.G0 * proj**2 * tau, tau)


# --------------------------------------------------------------------------------------
# special cases
# --------------------------------------------------------------------------------------


class Elastic(AbstractRheology):
    r"""Purely elastic material: $G(t) = G$, $J(t) = 1/G$, $G^*(\omega) = G$.

    **Arguments:**

    - `G`: shear modulus [Pa], scalar, > 0.

    `to_prony()` / `to_creep_chain()` return forms with zero arms (shape-`(0,)` arrays).
    """

    G: Scalar = eqx.field(converter=float_field("G", "Pa"))

    def __check_init__(self):
        _check_scalar("G", self.G)

    def domain(self):
        return (Constraint("G", self.G, "Pa", kind="modulus"),)

    @property
    @guarded
    def glass_modulus(self):
        return self.G

    @property
    @guarded
    def relaxed_modulus(self):
        return self.G

    @guarded
    def relaxation(self, t):
        return jnp.broadcast_to(self.G, jnp.shape(t))

    @guarded
    def creep(self, t):
        return 1.0 / self.relaxation(t)

    @guarded
    def complex_modulus(self, omega):
        return self.relaxation(omega) + 0j

    @guarded
    def complex_compliance(self, omega):
        return 1.0 / self.complex_modulus(omega)

    @guarded
    def to_prony(self):
        return PronySeries(self.G, _empty_like(self.G), _empty_like(self.G))

    @guarded
    def to_creep_chain(self):
        return CreepChain(self.G, _empty_like(self.G), _empty_like(self.G))


class StandardModel(AbstractRheology):
    r"""The paper's standard model in creep form: spring $G_0$ in series with a Kelvin
    element $(G_1, \eta_1)$.

    $$J(t) = \frac{1}{G_0} + \frac{1}{G_1}\big(1 - e^{-tG_1/\eta_1}\big),\qquad
    G(t) = G_\infty + (G_0 - G_\infty)\,e^{-t/\tau},$$

    with the relaxation time at fixed strain $\tau = \eta_1/(G_0 + G_1)$ and the relaxed
    modulus $G_\infty = G_0 G_1/(G_0 + G_1)$; $G_0 - G_\infty = G_0^2/(G_0 + G_1)$, and
    $G^*(\omega) = G_0(G_1 + i\omega\eta_1)/(G_0 + G_1 + i\omega\eta_1)$.

    **Arguments:**

    - `G0`: instantaneous (glass) modulus $G_0$ [Pa], scalar, > 0.
    - `G1`: Kelvin spring $G_1$ [Pa], scalar, > 0.
    - `eta1`: Kelvin viscosity $\eta_1$ [Pa s], scalar, > 0.
    """

    G0: Scalar = eqx.field(converter=float_field("G0", "Pa"))
    G1: Scalar = eqx.field(converter=float_field("G1", "Pa"))
    eta1: Scalar = eqx.field(converter=float_field("eta1", "Pa s"))

    def __check_init__(self):
        for name in ("G0", "G1", "eta1"):
            _check_scalar(name, getattr(self, name))

    def domain(self):
        return (Constraint("G0", self.G0, "Pa", kind="modulus"),
                Constraint("G1", self.G1, "Pa", kind="modulus"),
                Constraint("eta1", self.eta1, "Pa s", kind="viscosity"))

    @property
    @guarded
    def tau(self) -> Scalar:
        r"""Relaxation time at fixed strain $\tau = \eta_1/(G_0 + G_1)$ [s]."""
        return self.eta1 / (self.G0 + self.G1)

    @property
    @guarded
    def retardation_time(self) -> Scalar:
        r"""Retardation (creep) time $\theta = \eta_1/G_1$ [s]."""
        return self.eta1 / self.G1

    @property
    @guarded
    def glass_modulus(self):
        return self.G0

    @property
    @guarded
    def relaxed_modulus(self):
        return self.G0 * self.G1 / (self.G0 + self.G1)

    def _arm(self):
        return self.G0**2 / (self.G0 + self.G1)

    @guarded
    def relaxation(self, t):
        t = jnp.asarray(t)
        return self.relaxed_modulus + self._arm() * jnp.exp(-t / self.tau)

    @guarded
    def creep(self, t):
        t = jnp.asarray(t)
        return 1.0 / self.G0 - jnp.expm1(-t / self.retardation_time) / self.G1

    @guarded
    def complex_modulus(self, omega):
        iwt = 1j * jnp.asarray(omega) * self.tau
        return self.relaxed_modulus + self._arm() * iwt / (1 + iwt)

    @guarded
    def complex_compliance(self, omega):
        iwt = 1j * jnp.asarray(omega) * self.retardation_time
        return 1.0 / self.G0 + 1.0 / (self.G1 * (1 + iwt))

    @guarded
    def to_prony(self):
        return PronySeries(self.relaxed_modulus, self._arm()[None], self.tau[None])

    @guarded
    def to_creep_chain(self):
        return CreepChain(self.G0, self.G1[None], self.eta1[None])

