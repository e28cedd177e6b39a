"""The forward model inside a user's sharded program: ``jit(vmap(f), out_shardings=...)`` over
inputs sharded on 4 virtual CPU devices, in JAX's automatic and explicit axis modes, gives
the values of the plain ``vmap`` (`jaxcontact._sharding`): `retract`, the elastic
functions, `simulate` (both also with the exact sphere), `bem_simulate` and the fitting
objective (residuals and their Jacobian, `fitting.residuals`), each closing over a time grid
created before the mesh (as a user's program does). The devices must be set before JAX
starts, so the check runs in a fresh interpreter."""

import os
import subprocess
import sys
import textwrap

import pytest

SCRIPT = textwrap.dedent('''
    import os
    os.environ["XLA_FLAGS"] = "--xla_force_host_platform_device_count=4"
    import jax, jax.numpy as jnp, numpy as np
    jax.config.update("jax_enable_x64", True)
    from jax.sharding import AxisType, NamedSharding, PartitionSpec as P
    import jaxcontact as jc

    ts = jnp.linspace(0.0, 0.05, 64)
    prof = jc.Parabola(R=1e-4)
    G0s = jnp.linspace(0.8e6, 1.2e6, 8)
    disp = 4e-6 * jnp.sin(jnp.pi * ts / ts[-1])

    def rh(G0):
        return jc.StandardModel(G0=G0, G1=2e5, eta1=1e4)

    def f_retract(G0):
        s = jc.retract(rh(G0), prof, work_of_adhesion=0.05, depth=4e-6, velocity=1e-4,
                       ts=ts, throw=False)
        return s.force, s.jumpoff_time, s.max_tensile_force, s.result._value

    def f_elastic(G0):
        p = jc.pull_off(prof, effective_modulus=4 * G0, work_of_adhesion=0.05)
        return p.force, jc.jkr_force(prof, jnp.asarray(1e-6), effective_modulus=4 * G0,
                                     work_of_adhesion=0.05)

    def f_simulate(G0):
        s = jc.simulate(rh(G0), prof, 0.05, ts, disp, grid=16, throw=False)
        return s.force, s.result._value

    # the exact sphere (its own roots and eager depth check), closed over as a user would
    sphere = jc.Sphere(R=5e-6)

    def f_sphere(G0):
        s = jc.simulate(rh(G0), sphere, 0.05, ts, disp, grid=16, throw=False)
        r = jc.retract(rh(G0), sphere, work_of_adhesion=0.05, depth=4e-6, velocity=1e-4,
                       ts=ts, throw=False)
        return s.force, s.result._value, r.force, r.jumpoff_time, r.result._value

    bem_grid = jc.BEMGrid(16, 4e-5)

    def f_bem(G0):
        s = jc.bem_simulate(rh(G0), prof, 0.05, ts[:6], 0.2 * disp[:6], grid=bem_grid,
                            throw=False)
        return s.force, s.result._value

    # the fitting objective: residuals and their forward-mode Jacobian (what every
    # Levenberg-Marquardt step evaluates) of a prepared curve closed over, per lane
    import fitting
    from fitting._objective import jacobian_fn

    curve_sol = jc.retract(rh(1e6), prof, work_of_adhesion=0.05, depth=4e-6,
                           velocity=1e-4, ts=ts)
    curve = fitting.Curve(time=np.asarray(ts), displacement=np.asarray(curve_sol.displacement),
                          force=np.asarray(curve_sol.force), segment=np.zeros(ts.size, int),
                          segment_names=("retract",))
    spec = fitting.make_spec("relaxed", "standard")
    data = fitting.prepare_curves([curve], spec, radius=1e-4)

    def f_objective(G0):
        p = jnp.stack([G0, 2e5 + 0 * G0, 1e4 + 0 * G0, 0.05 + 0 * G0])
        r, J = jacobian_fn(lambda q: fitting.residuals(q, data, spec))(p)
        return r, J

    cases = [(mode, name, f) for mode in ("auto", "explicit")
             for name, f in (("retract", f_retract), ("elastic", f_elastic),
                             ("simulate", f_simulate), ("sphere", f_sphere), ("bem", f_bem),
                             ("objective", f_objective))]
    for mode, name, f in cases:
        kind = AxisType.Explicit if mode == "explicit" else AxisType.Auto
        mesh = jax.make_mesh((4,), ("b",), axis_types=(kind,))
        ref = jax.vmap(f)(G0s)
        with jax.set_mesh(mesh):
            x = jax.device_put(G0s, NamedSharding(mesh, P("b")))
            out = jax.jit(jax.vmap(f), out_shardings=NamedSharding(mesh, P("b")))(x)
        leaves = jax.tree.leaves(out)
        assert all(len(leaf.sharding.device_set) == 4 for leaf in leaves), (mode, name)
        for a, b in zip(leaves, jax.tree.leaves(ref), strict=True):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-12, atol=0)
        print(mode, name, "ok", flush=True)
    # the lift reaches the jump-off on some lanes, so the event path is exercised
    assert np.any(np.isfinite(np.asarray(jax.vmap(f_retract)(G0s)[1])))
''')


@pytest.mark.slow  # extended: `python -m pytest -m slow` (the default run's time)
def test_forward_model_inside_sharded_jit_vmap(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    out = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True,
                         env=env, timeout=1800)
    assert out.returncode == 0, out.stdout + out.stderr
    assert out.stdout.count(" ok") == 12, out.stdout
