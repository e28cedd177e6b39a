"""Tests for jaxcontact._rheology: closed forms, exact interconversion, limits, gradients."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads
from scipy.integrate import quad

from jaxcontact import AbstractRheology, CreepChain, Elastic, PronySeries, StandardModel

# Creep chains with 1, 2, 3 Kelvin elements; retardation times spread over up to 8 decades.
CHAINS = {
    1: (2.0e6, [5.0e5], [5.0e5 * 0.3]),
    2: (1.0e6, [3.0e5, 2.0e6], [3.0e5 * 1e-3, 2.0e6 * 1e2]),
    3: (1.0e6, [2.0e5, 3.0e6, 1.0e5], [2.0e5 * 1e-4, 3.0e6 * 1.0, 1.0e5 * 1e4]),
}
# Prony series with 1, 2, 3 arms; relaxation times spread over up to 8 decades.
PRONYS = {
    1: (1.0e5, [9.0e5], [0.02]),
    2: (4.0e5, [1.0e6, 2.5e5], [1e-3, 50.0]),
    3: (1.0e5, [7.0e5, 2.0e5, 1.5e6], [1e-4, 1.0, 1e4]),
}


def _chain_np(G0, G, eta):
    return float(G0), np.asarray(G, float), np.asarray(eta, float)


def _J_np(G0, G, eta, t):
    """Creep compliance of a chain, typed independently of the library."""
    theta = eta / G
    t = np.asarray(t, float)[..., None]
    return 1 / G0 + np.sum((1 - np.exp(-t / theta)) / G, axis=-1)


def _G_np(G_inf, G, tau, t):
    """Relaxation modulus of a Prony series, typed independently of the library."""
    t = np.asarray(t, float)[..., None]
    return G_inf + np.sum(G * np.exp(-t / tau), axis=-1)


def _Jstar_np(G0, G, eta, w):
    theta = eta / G
    w = np.asarray(w, float)[..., None]
    return 1 / G0 + np.sum(1 / (G * (1 + 1j * w * theta)), axis=-1)


def _Gstar_np(G_inf, G, tau, w):
    w = np.asarray(w, float)[..., None]
    return G_inf + np.sum(G * 1j * w * tau / (1 + 1j * w * tau), axis=-1)


def _prony_params(p):
    return float(p.G_inf), np.asarray(p.G), np.asarray(p.tau)


def _chain_params(c):
    return float(c.G0), np.asarray(c.G), np.asarray(c.eta)


# --------------------------------------------------------------------------------------
# standard model closed forms
# --------------------------------------------------------------------------------------

G0, G1, ETA1 = 1.2e6, 3.0e5, 4.5e4


def test_standard_model_closed_forms():
    m = StandardModel(G0, G1, ETA1)
    tau = ETA1 / (G0 + G1)
    G_inf = G0 * G1 / (G0 + G1)
    t = np.array([0.0, 1e-3, 0.01, 0.03, 0.1, 1.0, 10.0])
    w = np.logspace(-3, 5, 17)

    np.testing.assert_allclose(float(m.tau), tau, rtol=1e-14)
    np.testing.assert_allclose(float(m.relaxed_modulus), G_inf, rtol=1e-14)
    np.testing.assert_allclose(float(m.glass_modulus), G0, rtol=1e-14)
    np.testing.assert_allclose(
        m.relaxation(t), G_inf + (G0 - G_inf) * np.exp(-t / tau), rtol=1e-13
    )
    np.testing.assert_allclose(
        m.creep(t), 1 / G0 + (1 / G1) * (1 - np.exp(-t * G1 / ETA1)), rtol=1e-13
    )
    Gstar = G0 * (G1 + 1j * w * ETA1) / (G0 + G1 + 1j * w * ETA1)
    np.testing.assert_allclose(m.complex_modulus(w), Gstar, rtol=1e-13)
    np.testing.assert_allclose(
        m.complex_compliance(w), 1 / G0 + 1 / (G1 + 1j * w * ETA1), rtol=1e-13
    )
    # the loss modulus of the standard solid peaks at omega = 1/tau
    wpk = 1 / tau
    loss = np.imag(np.asarray(m.complex_modulus(wpk * np.array([0.9, 1.0, 1.1]))))
    assert loss[1] > loss[0] and loss[1] > loss[2]


@jax.jit
def _evaluate(model, t, w):
    return model.relaxation(t), model.creep(t), model.complex_modulus(w)


def test_standard_model_equals_chain_and_prony():
    m = StandardModel(G0, G1, ETA1)
    chain = CreepChain(G0, [G1], [ETA1])
    prony_eig = chain.to_prony()  # eigen-decomposition path
    G_inf = G0 * G1 / (G0 + G1)
    prony_typed = PronySeries(G_inf, [G0 - G_inf], [ETA1 / (G0 + G1)])
    t = np.logspace(-4, 1, 11)
    w = np.logspace(-3, 5, 9)
    ref = _evaluate(m, t, w)
    for other in (chain, prony_eig, prony_typed, m.to_prony(), m.to_creep_chain()):
        for got, want in zip(_evaluate(other, t, w), ref, strict=True):
            np.testing.assert_allclose(got, want, rtol=1e-12)
        np.testing.assert_allclose(float(other.glass_modulus), G0, rtol=1e-12)
        np.testing.assert_allclose(float(other.relaxed_modulus), G_inf, rtol=1e-12)
    np.testing.assert_allclose(np.asarray(prony_eig.tau), [ETA1 / (G0 + G1)], rtol=1e-13)
    np.testing.assert_allclose(np.asarray(prony_eig.G), [G0**2 / (G0 + G1)], rtol=1e-13)


# --------------------------------------------------------------------------------------
# exact interconversion
# --------------------------------------------------------------------------------------


def _sorted_chain(c):
    G0_, G, eta = _chain_params(c)
    o = np.argsort(eta / G)
    return G0_, G[o], eta[o]


@pytest.mark.parametrize("n", [1, 2, 3])
def test_round_trip_chain_prony_chain(n):
    G0_, G, eta = _chain_np(*CHAINS[n])
    back = CreepChain(G0_, G, eta).to_prony().to_creep_chain()
    bG0, bG, beta = _sorted_chain(back)
    o = np.argsort(eta / G)
    np.testing.assert_allclose(bG0, G0_, rtol=1e-10)
    np.testing.assert_allclose(bG, G[o], rtol=1e-10)
    np.testing.assert_allclose(beta, eta[o], rtol=1e-10)


@pytest.mark.parametrize("n", [1, 2, 3])
def test_round_trip_prony_chain_prony(n):
    G_inf, G, tau = PRONYS[n]
    G, tau = np.asarray(G, float), np.asarray(tau, float)
    back = PronySeries(G_inf, G, tau).to_creep_chain().to_prony()
    o = np.argsort(tau)
    # outputs are sorted by increasing time
    assert np.all(np.diff(np.asarray(back.tau)) > 0)
    np.testing.assert_allclose(float(back.G_inf), G_inf, rtol=1e-10)
    np.testing.assert_allclose(np.asarray(back.G), G[o], rtol=1e-10)
    np.testing.assert_allclose(np.asarray(back.tau), tau[o], rtol=1e-10)


def _convolution(Gfun, Jfun, t, breaks):
    """int_0^t J(t - s) G(s) ds by adaptive quadrature, split at the given time scales."""
    pts = sorted({b for b in breaks if 0 < b < t} | {t - b for b in breaks if 0 < b < t})
    val, err = quad(lambda s: Jfun(t - s) * Gfun(s), 0.0, t, points=pts or None, limit=500,
                    epsabs=0.0, epsrel=1e-12)
    return val


@pytest.mark.parametrize("n", [1, 2, 3])
@pytest.mark.parametrize("direction", ["chain_to_prony", "prony_to_chain"])
def test_interconversion_convolution_identity(n, direction):
    """int_0^t J(t-s) G(s) ds = t, with one side typed from the input parameters."""
    if direction == "chain_to_prony":
        chain_p = _chain_np(*CHAINS[n])
        prony_p = _prony_params(CreepChain(*chain_p).to_prony())
    else:
        G_inf, G, tau = PRONYS[n]
        prony_p = (G_inf, np.asarray(G, float), np.asarray(tau, float))
        chain_p = _chain_params(PronySeries(*prony_p).to_creep_chain())
    times = np.concatenate([chain_p[2] / chain_p[1], prony_p[2]])

    def Gfun(s):
        return float(_G_np(*prony_p, s))

    def Jfun(s):
        return float(_J_np(*chain_p, s))

    for t in np.concatenate([times * 0.5, times * 3.0, [times.max() * 30]]):
        val = _convolution(Gfun, Jfun, t, list(times) + list(times / 10) + list(times * 10))
        np.testing.assert_allclose(val, t, rtol=1e-8)


@pytest.mark.parametrize("n", [1, 2, 3])
def test_complex_modulus_times_compliance_is_one(n):
    w = np.logspace(-8, 8, 161)
    # chain -> Prony: G* from the converted Prony series, J* typed from the chain parameters
    chain_p = _chain_np(*CHAINS[n])
    prony = CreepChain(*chain_p).to_prony()
    np.testing.assert_allclose(prony.complex_modulus(w) * _Jstar_np(*chain_p, w), 1.0,
                               rtol=0, atol=1e-12)
    # Prony -> chain: J* typed from the converted chain, G* typed from the Prony input
    G_inf, G, tau = PRONYS[n]
    prony_p = (G_inf, np.asarray(G, float), np.asarray(tau, float))
    chain = PronySeries(*prony_p).to_creep_chain()
    np.testing.assert_allclose(
        _Gstar_np(*prony_p, w) * _Jstar_np(*_chain_params(chain), w), 1.0, rtol=0, atol=1e-12
    )
    np.testing.assert_allclose(
        chain.complex_compliance(w) * PronySeries(*prony_p).complex_modulus(w), 1.0,
        rtol=0, atol=1e-12,
    )


@pytest.mark.parametrize("n", [1, 2, 3])
def test_methods_match_typed_formulas(n):
    t = np.concatenate([[0.0], np.logspace(-6, 6, 49)])
    w = np.logspace(-6, 6, 25)
    chain_p = _chain_np(*CHAINS[n])
    c = CreepChain(*chain_p)
    np.testing.assert_allclose(c.creep(t), _J_np(*chain_p, t), rtol=1e-13)
    np.testing.assert_allclose(c.complex_compliance(w), _Jstar_np(*chain_p, w), rtol=1e-13)
    G_inf, G, tau = PRONYS[n]
    prony_p = (G_inf, np.asarray(G, float), np.asarray(tau, float))
    p = PronySeries(*prony_p)
    np.testing.assert_allclose(p.relaxation(t), _G_np(*prony_p, t), rtol=1e-13)
    np.testing.assert_allclose(p.complex_modulus(w), _Gstar_np(*prony_p, w), rtol=1e-13)
    # array t of any shape is elementwise
    t2 = t[1:].reshape(7, 7)
    assert p.relaxation(t2).shape == (7, 7)
    np.testing.assert_allclose(c.relaxation(t2), c.to_prony().relaxation(t2.ravel()).reshape(7, 7))


# --------------------------------------------------------------------------------------
# limits
# --------------------------------------------------------------------------------------


def _all_models():
    out = [Elastic(2.5e5), StandardModel(G0, G1, ETA1)]
    for n in (1, 2, 3):
        out.append(CreepChain(*CHAINS[n]))
        out.append(PronySeries(*PRONYS[n]))
    return out


@pytest.mark.parametrize("model", _all_models(), ids=lambda m: type(m).__name__)
def test_limits(model):
    assert isinstance(model, AbstractRheology)
    glass, relaxed = float(model.glass_modulus), float(model.relaxed_modulus)
    assert glass >= relaxed > 0
    np.testing.assert_allclose(float(model.relaxation(0.0)), glass, rtol=1e-12)
    np.testing.assert_allclose(float(model.relaxation(jnp.inf)), relaxed, rtol=1e-12)
    np.testing.assert_allclose(float(model.creep(0.0)), 1 / glass, rtol=1e-12)
    np.testing.assert_allclose(float(model.creep(jnp.inf)), 1 / relaxed, rtol=1e-12)
    np.testing.assert_allclose(complex(model.complex_modulus(0.0)), relaxed, rtol=1e-12)
    np.testing.assert_allclose(complex(model.complex_modulus(1e15)), glass, rtol=1e-6)
    # both forms agree on the two moduli
    p, c = model.to_prony(), model.to_creep_chain()
    np.testing.assert_allclose(float(p.G_inf + np.sum(p.G)), glass, rtol=1e-12)
    np.testing.assert_allclose(float(c.G0), glass, rtol=1e-12)
    np.testing.assert_allclose(1 / (1 / float(c.G0) + np.sum(1 / np.asarray(c.G))), relaxed,
                               rtol=1e-12)
    np.testing.assert_allclose(float(p.G_inf), relaxed, rtol=1e-12)
    # G monotone decreasing, J monotone increasing
    t = np.logspace(-7, 7, 57)
    assert np.all(np.diff(np.asarray(model.relaxation(t))) <= 0)
    assert np.all(np.diff(np.asarray(model.creep(t))) >= 0)


def test_elastic_has_no_arms():
    e = Elastic(3.0e5)
    p, c = e.to_prony(), e.to_creep_chain()
    assert p.G.shape == (0,) and p.tau.shape == (0,)
    assert c.G.shape == (0,) and c.eta.shape == (0,)
    t = np.array([0.0, 1.0, 1e9])
    np.testing.assert_array_equal(np.asarray(e.relaxation(t)), 3.0e5)
    np.testing.assert_array_equal(np.asarray(e.creep(t)), 1 / 3.0e5)
    # zero-arm forms convert and evaluate
    for m in (p, c, p.to_creep_chain(), c.to_prony()):
        np.testing.assert_allclose(m.relaxation(t), 3.0e5, rtol=1e-15)
        np.testing.assert_allclose(m.creep(t), 1 / 3.0e5, rtol=1e-15)
        np.testing.assert_allclose(m.complex_modulus(t), 3.0e5, rtol=1e-15)


# --------------------------------------------------------------------------------------
# gradients, jit, vmap
# --------------------------------------------------------------------------------------

# Parameters are scaled to O(1) so that finite differences are well conditioned.
_T = jnp.array([0.0, 0.03, 0.7, 5.0, 80.0])


def _chain_from(x):
    return CreepChain(1e6 * x[0], 1e6 * x[1:4], 1e6 * x[4:7] * jnp.array([1e-2, 1.0, 1e2]))


def _prony_from(x):
    return PronySeries(1e5 * x[0], 1e6 * x[1:4], x[4:7] * jnp.array([1e-2, 1.0, 1e2]))


_X = jnp.array([1.3, 0.4, 2.1, 0.7, 0.9, 1.6, 0.5])


def _check(f, x, **kw):
    check_grads(jax.jit(f), (x,), order=1, modes=("fwd", "rev"), **kw)


def test_grads_relaxation():
    def sm(x):
        return StandardModel(1e6 * x[0], 1e6 * x[1], 1e4 * x[2])

    _check(lambda x: sm(x).relaxation(_T) / 1e6, _X[:3])
    _check(lambda x: sm(x).creep(_T) * 1e6, _X[:3])
    _check(lambda x: _prony_from(x).relaxation(_T) / 1e6, _X)
    # through the eigen-decompositions
    _check(lambda x: _chain_from(x).relaxation(_T) / 1e6, _X)
    _check(lambda x: _prony_from(x).creep(_T) * 1e6, _X)
    # and w.r.t. time (fast modes: smaller finite-difference step)
    m = _chain_from(_X)
    _check(lambda t: m.relaxation(t) / 1e6, _T[1:], eps=1e-6)


def test_grads_conversions():
    def c2p(x):
        p = _chain_from(x).to_prony()
        return jnp.concatenate([p.G_inf[None] / 1e6, p.G / 1e6, jnp.log(p.tau)])

    def p2c(x):
        c = _prony_from(x).to_creep_chain()
        return jnp.concatenate([c.G0[None] / 1e6, c.G / 1e6, jnp.log(c.eta / 1e6)])

    _check(c2p, _X)
    _check(p2c, _X)
    # the round trip is the identity, so its Jacobian is the identity
    def rt(x):
        c = _prony_from(x).to_creep_chain().to_prony()
        return jnp.concatenate([c.G_inf[None] / 1e5, c.G / 1e6, c.tau / jnp.array([1e-2, 1.0, 1e2])])

    np.testing.assert_allclose(jax.jit(jax.jacfwd(rt))(_X), np.eye(7), atol=1e-9)
    np.testing.assert_allclose(jax.jit(jax.jacrev(rt))(_X), np.eye(7), atol=1e-9)


def test_jit_and_vmap():
    xs = jnp.stack([_X, _X * 1.1, _X * jnp.linspace(0.8, 1.2, 7)])

    @jax.jit
    def f(x):
        c = _chain_from(x)
        p = c.to_prony()
        return c.relaxation(_T), p.creep(_T), p.tau

    batched = jax.vmap(f)(xs)
    for i in range(xs.shape[0]):
        c = _chain_from(xs[i])
        p = c.to_prony()
        np.testing.assert_allclose(batched[0][i], c.relaxation(_T), rtol=1e-12)
        np.testing.assert_allclose(batched[1][i], p.creep(_T), rtol=1e-12)
        np.testing.assert_allclose(batched[2][i], p.tau, rtol=1e-12)

    # vmap over a module whose leaves carry a batch axis
    models = jax.vmap(lambda g0: StandardModel(g0, G1, ETA1))(jnp.array([1e6, 2e6]))
    out = jax.vmap(lambda m: m.relaxation(_T))(models)
    np.testing.assert_allclose(out[1], StandardModel(2e6, G1, ETA1).relaxation(_T), rtol=1e-14)
    # jit with the module as an argument
    m = PronySeries(*PRONYS[3])
    np.testing.assert_allclose(jax.jit(lambda m: m.to_creep_chain().G)(m),
                               m.to_creep_chain().G, rtol=1e-14)


# --------------------------------------------------------------------------------------
# validation
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "make, name",
    [
        (lambda: StandardModel(-1e6, G1, ETA1), "G0"),
        (lambda: StandardModel(G0, 0.0, ETA1), "G1"),
        (lambda: StandardModel(G0, G1, 0.0), "eta1"),
        (lambda: StandardModel(G0, G1, np.nan), "eta1"),
        (lambda: Elastic(-3.0), "G"),
        (lambda: Elastic(np.inf), "G"),
        (lambda: CreepChain(-1.0, [1.0], [1.0]), "G0"),
        (lambda: CreepChain(1.0, [1.0, -2.0], [1.0, 1.0]), "G"),
        (lambda: CreepChain(1.0, [1.0, 2.0], [1.0, 0.0]), "eta"),
        (lambda: CreepChain(1.0, [1.0, 2.0], [1.0, np.nan]), "eta"),
        (lambda: CreepChain(1.0, [1.0, 2.0], [1.0]), "eta"),
        (lambda: PronySeries(0.0, [1.0], [1.0]), "G_inf"),
        (lambda: PronySeries(np.nan, [1.0], [1.0]), "G_inf"),
        (lambda: PronySeries(1.0, [-1.0], [1.0]), "G"),
        (lambda: PronySeries(1.0, [1.0], [0.0]), "tau"),
        (lambda: PronySeries(1.0, [[1.0]], [[1.0]]), "tau"),
        (lambda: PronySeries([1.0, 2.0], [1.0], [1.0]), "G_inf"),
    ],
)
def test_bad_inputs_raise(make, name):
    with pytest.raises(ValueError, match=f"`{name}`"):
        make()


def test_error_message_names_range_and_unit():
    with pytest.raises(ValueError, match=r"`eta1` must lie in \(0, inf\) \[Pa s\]"):
        StandardModel(G0, G1, -1.0)
    with pytest.raises(ValueError, match=r"`tau` must lie in \(0, inf\) \[s\]"):
        PronySeries(1.0, [1.0], [-1.0])
