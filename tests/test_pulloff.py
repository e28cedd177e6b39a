import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxcontact as jc

G0, G1, ETA1 = 1e6, 2e5, 1e4  # tau = eta1/(G0+G1) ~ 8.3 ms
R, D0, V, DG = 1e-4, 4e-6, 1e-4, 0.05
TAU = ETA1 / (G0 + G1)
GINF = G0 * G1 / (G0 + G1)
# most histories have 2001 samples: one compiled `retract` per configuration serves them
TS = jnp.linspace(0.0, 0.1, 2001)


def sm(G0_=G0, G1_=G1, eta1_=ETA1):
    return jc.StandardModel(G0=G0_, G1=G1_, eta1=eta1_)


def run(**kw):
    args = dict(work_of_adhesion=DG, depth=D0, velocity=V, ts=TS)
    args.update(kw)
    rh = args.pop("rheology", sm())
    prof = args.pop("profile", jc.Parabola(R=R))
    return jc.retract(rh, prof, **args)


def u_g0(x, t, d0=D0, v=V):
    """docs/physics.md §4, the corrected eq. (24): elongation of the glass spring."""
    return (G1 * (d0 - v * t - x**2 / R) - G0 * TAU * v * (1 - np.exp(-t / TAU))) / (G0 + G1)


def test_standard_model_pinned_phase_closed_form():
    sol = run()
    t = np.asarray(TS)
    a0 = np.sqrt(R * D0)
    # F = 8 G0 int_0^a0 u_G0 dx, integrated in closed form
    F_ref = 8 * G0 * (
        G1 * ((D0 - V * t) * a0 - a0**3 / (3 * R)) - G0 * TAU * V * (1 - np.exp(-t / TAU)) * a0
    ) / (G0 + G1)
    pinned = np.isclose(np.asarray(sol.contact_radius), a0, rtol=1e-14, atol=0)
    assert pinned.sum() > 100
    np.testing.assert_allclose(np.asarray(sol.force)[pinned], F_ref[pinned], rtol=1e-8, atol=0)
    # the pinned phase ends where the corrected eq. (25) is first met at the edge
    crit = u_g0(a0, t) <= -np.sqrt(np.pi * a0 * DG / (2 * G0))
    assert np.argmax(crit) == np.argmin(pinned)


def test_t0_is_relaxed_state():
    sol = run()
    a0 = np.sqrt(R * D0)
    # relaxed Hertz with E* = 4 G_inf
    np.testing.assert_allclose(sol.force[0], 4 / 3 * 4 * GINF * np.sqrt(R) * D0**1.5, rtol=1e-12)
    np.testing.assert_allclose(sol.contact_radius[0], a0, rtol=1e-14)
    np.testing.assert_allclose(u_g0(0.0, 0.0), GINF / G0 * D0, rtol=1e-14)  # q = 4 G_inf u


def test_receding_front_satisfies_corrected_eq25_and_is_jkr():
    for v in [1e-6, 1e-4, 1e-2]:
        tj = run(velocity=v, ts=jnp.linspace(0.0, 3 * D0 / v + 0.1, TS.size)).jumpoff_time
        ts = jnp.linspace(0.0, 1.001 * float(tj), TS.size)
        sol = run(velocity=v, ts=ts)
        assert sol.result == jc.RESULTS.detached
        a = np.asarray(sol.contact_radius)
        t = np.asarray(ts)
        rec = (a > 0) & (a < np.sqrt(R * D0) * (1 - 1e-12))
        assert rec.sum() > 5
        resid = u_g0(a[rec], t[rec], v=v) + np.sqrt(np.pi * a[rec] * DG / (2 * G0))
        np.testing.assert_allclose(resid / D0, 0.0, atol=1e-12)
        E, dge = 4 * GINF, DG * (G0 + G1) / G1
        F_jkr = 4 * E * a[rec] ** 3 / (3 * R) - np.sqrt(8 * np.pi * E * dge * a[rec] ** 3)
        np.testing.assert_allclose(np.asarray(sol.force)[rec], F_jkr, rtol=1e-9)
        np.testing.assert_allclose(sol.jumpoff_force, -5 / 6 * np.pi * dge * R, rtol=1e-12)


def test_slow_lift_is_jkr_in_displacement():
    v, d0 = 1e-10, 1e-5  # tau v / d0 ~ 1e-7; a0 beyond the force-control radius
    ts = jnp.linspace(0.0, 2 * d0 / v, TS.size)
    sol = run(velocity=v, ts=ts, depth=d0)
    E, dge = 4 * GINF, DG * (G0 + G1) / G1
    po = jc.pull_off(jc.Parabola(R=R), effective_modulus=E, work_of_adhesion=dge)
    np.testing.assert_allclose(sol.jumpoff_displacement, po.displacement, rtol=1e-4)
    a = np.asarray(sol.contact_radius)
    rec = (a > 0) & (a < np.sqrt(R * d0) * (1 - 1e-12))
    assert rec.sum() > 100
    d_jkr = jc.jkr_displacement(jc.Parabola(R=R), a[rec], effective_modulus=E, work_of_adhesion=dge)
    np.testing.assert_allclose(np.asarray(sol.displacement)[rec], d_jkr, atol=1e-6 * d0)
    fc = jc.pull_off(jc.Parabola(R=R), effective_modulus=E, work_of_adhesion=dge, control="force")
    # a0 > force-control radius here, so the largest tensile force is the JKR one
    assert np.sqrt(R * d0) > fc.radius
    np.testing.assert_allclose(sol.max_tensile_force, -1.5 * np.pi * dge * R, rtol=1e-12)


def test_unloading_stiffness_glass_then_relaxed():
    a0 = np.sqrt(R * D0)
    ts = jnp.array([0.0, 1e-9])
    sol = run(ts=ts)
    k0 = (sol.force[1] - sol.force[0]) / (-V * 1e-9)  # dF/dd
    np.testing.assert_allclose(k0, 8 * G0 * a0, rtol=1e-5)
    # a slow lift keeps the contact pinned for many tau: the stiffness tends to 8 G_inf a0
    ts = jnp.linspace(0, 20 * TAU, 2001)
    sol = run(ts=ts, velocity=1e-6)
    np.testing.assert_allclose(sol.contact_radius, a0, rtol=1e-14)
    k_late = -(sol.force[-1] - sol.force[-2]) / (1e-6 * (ts[-1] - ts[-2]))
    np.testing.assert_allclose(k_late, 8 * GINF * a0, rtol=1e-6)


def test_diffrax_and_exact_paths_agree():
    exact = run()
    ode = run(method=jc.DiffraxODE())
    scale = np.abs(np.asarray(exact.force)).max()
    np.testing.assert_allclose(ode.force, exact.force, atol=1e-7 * scale)
    np.testing.assert_allclose(ode.jumpoff_time, exact.jumpoff_time, rtol=1e-7)
    stiff = run(method=jc.DiffraxODE(solver=diffrax.Kvaerno5(), rtol=1e-12))
    np.testing.assert_allclose(stiff.force, exact.force, atol=1e-6 * scale)
    # sampled (measured) history through the same points, both methods
    hist = D0 - V * TS
    samp = run(velocity=None, displacement=hist)
    np.testing.assert_allclose(samp.force, exact.force, atol=1e-12 * scale)
    samp_ode = run(velocity=None, displacement=hist, method=jc.DiffraxODE())
    np.testing.assert_allclose(samp_ode.force, exact.force, atol=1e-7 * scale)


def test_piecewise_history_against_superposition():
    """Lift, stop, lift: exact update against the Boltzmann superposition integral (the
    knots 0.01 s and 0.03 s on samples of TS)."""
    ts = TS
    t = np.asarray(ts)
    d = np.where(t < 0.01, D0 - V * t, np.where(t < 0.03, D0 - V * 0.01, D0 - V * (t - 0.02)))
    sol = run(velocity=None, displacement=jnp.asarray(d), ts=ts, work_of_adhesion=1.0)
    # Q(t) = int G(t-s) ddelta(s), with piecewise-constant rate: closed-form integral
    rate = np.where(t < 0.01, -V, np.where(t < 0.03, 0.0, -V))

    def Q(tt):
        knots = [0.0, 0.01, 0.03, tt]
        rates = [-V, 0.0, -V]
        out = 0.0
        for k in range(3):
            lo, hi = min(knots[k], tt), min(knots[k + 1], tt)
            if hi <= lo:
                continue
            # int_lo^hi G(tt - s) ds, G(s) = Ginf + (G0-Ginf) e^{-s/tau}
            out += rates[k] * (
                GINF * (hi - lo)
                + (G0 - GINF) * TAU * (np.exp(-(tt - hi) / TAU) - np.exp(-(tt - lo) / TAU))
            )
        return out

    del rate
    a0 = np.sqrt(R * D0)
    F_ref = np.array([8 * (GINF * (D0 * a0 - a0**3 / (3 * R)) + Q(tt) * a0) for tt in t])
    att = np.isclose(np.asarray(sol.contact_radius), a0, rtol=1e-14, atol=0)
    assert att.sum() > 300
    np.testing.assert_allclose(np.asarray(sol.force)[att], F_ref[att], rtol=1e-9)


def test_prony_two_arms_and_equivalent_creep_chain():
    Ginf, Gk, tk = 2e5, jnp.array([5e5, 3e5]), jnp.array([2e-3, 3e-2])
    prony = jc.PronySeries(G_inf=Ginf, G=Gk, tau=tk)
    sol = run(rheology=prony)
    Gg = Ginf + float(jnp.sum(Gk))
    t = np.asarray(TS)
    a0 = np.sqrt(R * D0)
    Q = -V * (Ginf * t + sum(float(g) * float(s) * (1 - np.exp(-t / float(s))) for g, s in zip(Gk, tk, strict=True)))
    F_pin = 8 * (Ginf * (D0 * a0 - a0**3 / (3 * R)) + Q * a0)
    a = np.asarray(sol.contact_radius)
    pinned = np.isclose(a, a0, rtol=1e-14, atol=0)
    np.testing.assert_allclose(np.asarray(sol.force)[pinned], F_pin[pinned], rtol=1e-9)
    rec = (a > 0) & ~pinned
    E, dge = 4 * Ginf, DG * Gg / Ginf
    F_jkr = 4 * E * a[rec] ** 3 / (3 * R) - np.sqrt(8 * np.pi * E * dge * a[rec] ** 3)
    np.testing.assert_allclose(np.asarray(sol.force)[rec], F_jkr, rtol=1e-9)
    chain = run(rheology=prony.to_creep_chain())
    np.testing.assert_allclose(chain.force, sol.force, rtol=1e-9, atol=1e-18)


def test_cone_and_tabulated_profiles():
    cone = jc.Cone(half_angle=1.2)
    d0 = 2e-6
    ts = jnp.linspace(0, 0.08, 1601)
    sol = run(profile=cone, depth=d0, ts=ts)
    assert sol.result == jc.RESULTS.detached
    E, dge = 4 * GINF, DG * (G0 + G1) / G1
    a = np.asarray(sol.contact_radius)
    a0 = float(jc.profile_radius(cone, d0))
    rec = (a > 0) & (a < a0 * (1 - 1e-12))
    assert rec.sum() > 5
    F_jkr = jc.jkr_force(cone, a[rec], effective_modulus=E, work_of_adhesion=dge)
    np.testing.assert_allclose(np.asarray(sol.force)[rec], F_jkr, rtol=1e-9)
    po = jc.pull_off(cone, effective_modulus=E, work_of_adhesion=dge)
    np.testing.assert_allclose(sol.jumpoff_force, po.force, rtol=1e-10)
    # tabulated parabola through the generic root finder
    r = np.linspace(0, 6e-5, 1201)
    tab = jc.Tabulated(r=r, f=r**2 / (2 * R))
    ref = run()
    got = run(profile=tab)
    np.testing.assert_allclose(got.force, ref.force, rtol=1e-7, atol=1e-9 * float(ref.force[0]))
    np.testing.assert_allclose(got.jumpoff_time, ref.jumpoff_time, rtol=1e-7)


def test_flat_punch_detaches_from_pinned_state():
    a0 = 1e-5
    sol = run(profile=jc.FlatPunch(radius=a0))
    assert sol.result == jc.RESULTS.detached
    # Kendall with the glass-modulus criterion: q(a0) = -sqrt(8 pi a0 dgamma G0)
    np.testing.assert_allclose(sol.jumpoff_force, -2 * a0 * np.sqrt(8 * np.pi * a0 * DG * G0), rtol=1e-12)
    np.testing.assert_allclose(sol.jumpoff_radius, a0)


def test_jumpoff_time_refined_between_samples():
    coarse = run(ts=jnp.linspace(0, 0.1, 51))
    fine = run(ts=jnp.linspace(0, 0.1, 200001))
    # the sampled estimate is only good to the sampling interval; the refined one is exact
    np.testing.assert_allclose(coarse.jumpoff_time, fine.jumpoff_time, rtol=1e-12)
    assert abs(float(coarse.jumpoff_time) - float(fine.jumpoff_time)) < 2e-3
    # the refined time satisfies d_eff(t_j) = fold value of the corrected eq. (25)
    tj = float(coarse.jumpoff_time)
    at = run(ts=jnp.array([tj]))
    E, dge = 4 * GINF, DG * (G0 + G1) / G1
    po = jc.pull_off(jc.Parabola(R=R), effective_modulus=E, work_of_adhesion=dge)
    np.testing.assert_allclose(at.details.effective_displacement[0], po.displacement, rtol=1e-10)


def test_after_jumpoff_exactly_zero_and_no_detachment_reported():
    sol = run()
    a = np.asarray(sol.contact_radius)
    after = np.asarray(TS) > float(sol.jumpoff_time)
    assert np.all(a[after] == 0) and np.all(np.asarray(sol.force)[after] == 0)
    short = run(ts=jnp.linspace(0, 0.005, 11))
    assert short.result == jc.RESULTS.in_contact
    assert np.isnan(short.jumpoff_time) and np.isnan(short.jumpoff_force)


def fd(f, x, rel=1e-6):
    h = rel * x
    return (f(x + h) - f(x - h)) / (2 * h)


@pytest.mark.parametrize("phase", ["pinned", "receding", "last"])
def test_gradients_against_finite_differences(phase):
    sol = run()
    a = np.asarray(sol.contact_radius)
    a0 = np.sqrt(R * D0)
    last = int(np.flatnonzero(a > 0)[-1])  # just before jump-off (4 us before it)
    index = {"pinned": 300, "receding": (last + 700) // 2, "last": last}[phase]
    assert a[index] > 0
    assert np.isclose(a[index], a0, rtol=1e-14) == (phase == "pinned")

    def force(p):
        G0_, G1_, eta1_, dg_ = p
        s = jc.retract(sm(G0_, G1_, eta1_), jc.Parabola(R=R), work_of_adhesion=dg_, depth=D0, velocity=V, ts=TS)
        return s.force[index]

    p0 = jnp.array([G0, G1, ETA1, DG])
    g = jax.grad(force)(p0)
    for k in range(4):
        e = np.zeros(4)
        e[k] = 1.0
        num = fd(lambda x, e=e, k=k: force(p0 + (x - p0[k]) * e), float(p0[k]), rel=1e-7)
        np.testing.assert_allclose(g[k], num, rtol=2e-5, atol=1e-9 * abs(float(sol.force[index])) / float(p0[k]))


def test_gradients_of_events_and_finite_after_jumpoff():
    def events(p):
        G0_, G1_, eta1_, dg_, v = p
        s = jc.retract(sm(G0_, G1_, eta1_), jc.Parabola(R=R), work_of_adhesion=dg_, depth=D0, velocity=v, ts=TS)
        return jnp.stack([s.jumpoff_time, s.jumpoff_force, s.max_tensile_force, s.force[1800]])

    p0 = jnp.array([G0, G1, ETA1, DG, V])
    J = jax.jacfwd(events)(p0)
    Jr = jax.jacrev(events)(p0)
    assert np.all(np.isfinite(J)) and np.all(np.isfinite(Jr))
    np.testing.assert_allclose(J, Jr, rtol=1e-9, atol=1e-30)
    assert np.all(J[3] == 0)  # sample after jump-off
    for k in range(5):
        e = np.zeros(5)
        e[k] = 1.0
        num = fd(lambda x, e=e, k=k: events(p0 + (x - p0[k]) * e)[:3], float(p0[k]))
        np.testing.assert_allclose(J[:3, k], num, rtol=1e-5, atol=1e-12 * np.abs(num).max() + 1e-30)


def test_jit_and_vmap_over_parameters_speeds_profiles():
    @jax.jit
    def f(G0_, dg_, v, Rr):
        return jc.retract(sm(G0_, G1, ETA1), jc.Parabola(R=Rr), work_of_adhesion=dg_, depth=D0, velocity=v, ts=TS, throw=False)

    Gs = jnp.array([8e5, 1e6, 1.2e6])
    vs = jnp.array([1e-5, 1e-4, 1e-3])
    Rs = jnp.array([5e-5, 1e-4, 2e-4])
    out = jax.vmap(f)(Gs, jnp.full(3, DG), vs, Rs)
    for i in range(3):
        ref = jc.retract(sm(float(Gs[i]), G1, ETA1), jc.Parabola(R=float(Rs[i])), work_of_adhesion=DG, depth=D0, velocity=float(vs[i]), ts=TS)
        np.testing.assert_allclose(out.force[i], ref.force, rtol=1e-12, atol=1e-25)
        np.testing.assert_allclose(out.jumpoff_time[i], ref.jumpoff_time, rtol=1e-12)


def test_advancing_history_is_an_error():
    hist = D0 + 1e-7 * jnp.sin(jnp.linspace(0, 3, TS.shape[0]))
    with pytest.raises(eqx.EquinoxRuntimeError, match="beyond the initial contact radius"):
        run(velocity=None, displacement=hist)
    sol = run(velocity=None, displacement=hist, throw=False)
    assert sol.result == jc.RESULTS.advancing_contact


@pytest.mark.parametrize(
    "kw, name",
    [
        (dict(depth=-1e-6), "depth"),
        (dict(velocity=-1.0), "velocity"),
        (dict(work_of_adhesion=float("nan")), "work_of_adhesion"),
        (dict(ts=jnp.array([0.0, 0.2, 0.1])), "ts"),
        (dict(rheology="x"), None),
    ],
)
def test_bad_inputs(kw, name):
    if name is None:
        with pytest.raises(TypeError, match="rheology"):
            run(**kw)
        return
    with pytest.raises(ValueError, match=name):
        run(**kw)
    with pytest.raises(ValueError, match="G0"):
        sm(G0_=-1.0)
    with pytest.raises(ValueError, match="exactly one"):
        jc.retract(sm(), jc.Parabola(R=R), work_of_adhesion=DG, depth=D0, ts=TS)


def test_float32_path_against_float64():
    """float32 inputs keep float32; error measured against float64 (documented in README)."""
    f32 = jnp.float32
    sol32 = jc.retract(
        jc.StandardModel(G0=f32(G0), G1=f32(G1), eta1=f32(ETA1)), jc.Parabola(R=f32(R)),
        work_of_adhesion=f32(DG), depth=f32(D0), velocity=f32(V), ts=TS.astype(f32),
    )
    sol64 = run()
    assert sol32.force.dtype == jnp.float32
    scale = float(jnp.max(jnp.abs(sol64.force)))
    err = np.abs(np.asarray(sol32.force, dtype=float) - np.asarray(sol64.force))
    # away from the jump-off sample (which may flip by one sample) the error is float32 round-off
    keep = np.abs(np.asarray(TS) - float(sol64.jumpoff_time)) > 1e-4
    assert err[keep].max() < 1e-5 * scale
    np.testing.assert_allclose(float(sol32.jumpoff_time), float(sol64.jumpoff_time), rtol=1e-4)


def test_sampled_arm_states_against_sequential_recurrence():
    # the arm states of a sampled history (associative scan, custom JVP through two fixed
    # sensitivities) against the plain sequential recurrence w_i = a_i w_{i-1} + b_i with
    # JAX's own derivatives: values, parameter tangents (the fitting Jacobian's path) and
    # tangents of the sampling itself (times and displacements), for relaxation times from
    # far below to far above the sampling interval (x = dt/tau from 1e-4 to 30)
    from jaxcontact._arms import states_samples as _states_samples

    rng = np.random.default_rng(3)
    n = 97
    ts = jnp.asarray(np.cumsum(rng.uniform(0.5, 1.5, n)) - 0.7)
    delta = jnp.asarray(np.cumsum(rng.normal(size=n)))
    ratio = jnp.array([0.2, 0.3, 0.1])
    tau = jnp.array([0.03, 2.0, 1e4])

    def sequential(ts, delta, ratio, tau):
        dt = jnp.diff(ts, prepend=ts[:1])[:, None]
        dd = jnp.diff(delta, prepend=0.0)[:, None]
        x = dt / tau[None, :]  # explicit broadcasting (strict rank promotion)
        safe = jnp.where(x > 0, x, 1.0)
        b = ratio[None, :] * dd * jnp.where(x > 0, -jnp.expm1(-safe) / safe, 1.0)

        def step(w, ab):
            w = ab[0] * w + ab[1]
            return w, w

        return jax.lax.scan(step, jnp.zeros_like(tau), (jnp.exp(-x), b))[1]

    args = (ts, delta, ratio, tau)
    w, ref = _states_samples(*args), sequential(*args)
    assert float(jnp.max(jnp.abs(w - ref))) <= 1e-13 * float(jnp.max(jnp.abs(ref)))
    # parameter tangents only (symbolic zeros for the sampling), then all four
    zero_ts, zero_d = jnp.zeros_like(ts), jnp.zeros_like(delta)
    for tangent in [(zero_ts, zero_d, ratio * 0.7, tau * -1.3),
                    tuple(jnp.asarray(rng.normal(size=np.shape(a))) for a in args)]:
        if tangent[0] is zero_ts:
            _, d_w = jax.jvp(lambda r, t: _states_samples(ts, delta, r, t), (ratio, tau),
                             tangent[2:])
        else:
            _, d_w = jax.jvp(_states_samples, args, tangent)
        _, d_ref = jax.jvp(sequential, args, tangent)
        assert float(jnp.max(jnp.abs(d_w - d_ref))) <= 1e-12 * float(jnp.max(jnp.abs(d_ref)))
    # reverse mode (transposed through the same rule) against the sequential recurrence
    loss = lambda f: lambda r, t: jnp.sum(jnp.sin(f(ts, delta, r, t)))  # noqa: E731
    g, g_ref = jax.grad(loss(_states_samples), (0, 1))(ratio, tau), jax.grad(
        loss(sequential), (0, 1))(ratio, tau)
    for a, b in zip(g, g_ref, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-11)
