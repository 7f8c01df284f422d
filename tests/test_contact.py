"""Contact observer against independent references: a float64 NumPy loop of the backward-Euler
equations (solved by bisection), the analytic critically damped response, and a floating-base
quadruped simulated in MuJoCo C with known foot forces; plus jit/vmap/grad and bad-input checks."""

from __future__ import annotations

import copy
import dataclasses
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from jaxquad.kernels import ContactObserver, ObserverParams

_OBS = ContactObserver()


def _scan(params, p0, ps, taus, Js, dts):
    def body(state, x):
        return _OBS.step(params, state, *x)

    return jax.lax.scan(body, _OBS.init(params, p0, Js.shape[1]), (ps, taus, Js, dts))


_run = jax.jit(_scan)
_step = jax.jit(_OBS.step)
_run_params_batch = jax.jit(jax.vmap(_scan, in_axes=(0, None, None, None, None, None)))
_run_robot_batch = jax.jit(jax.vmap(_scan, in_axes=(None, 0, 0, 0, 0, 0)))


def _params(mode, n_feet=1, bandwidth=30.0, **kw):
    base = dict(
        bandwidth=bandwidth,
        sharpness=100.0,
        f_max=100.0,
        alpha=np.full(n_feet, 0.2),
        threshold_on=np.full(n_feet, 1.0),
        threshold_off=np.full(n_feet, 1.0),
        soft_temperature=0.25,
        pinv_damping=0.0,
        mode=mode,
    )
    base.update(kw)
    return ObserverParams(**{k: (np.asarray(v, np.float32) if k != "mode" else v) for k, v in base.items()})


# ---------------------------------------------------------------- 1-dof: p' = tau_bar + f, J_z = [[1]]


def _one_dof_inputs(force, dt, tau=0.0, p0=0.0):
    """Exact momentum samples of a 1-dof body pushed by a piecewise-constant force (N)."""
    force = np.asarray(force, np.float64)
    ps = p0 + np.cumsum((tau + force) * dt)
    n = len(force)
    return (
        jnp.asarray(ps[:, None], jnp.float32),
        jnp.full((n, 1), tau, jnp.float32),
        jnp.ones((n, 1, 1), jnp.float32),
        jnp.full(n, dt, jnp.float32),
    )


def _reference_1dof(force, dt, b, mode, tau=0.0, sharpness=100.0):
    """Backward Euler of the observer written out for one dof, float64: the new residual r solves
        r + dt b k1(r) + dt^2 b^2 k2(r) = p - p_hat - dt (tau + f_hat)      (monotone in r)
    and f_hat += dt b^2 k2(r). Solved by bisection; k1 = 2r, k2 = r in plain mode."""
    if mode == "plain":
        k1, k2 = (lambda r: 2.0 * r), (lambda r: r)
    else:
        k1 = lambda r: math.copysign(math.sqrt(abs(r)), r) + r  # noqa: E731
        k2 = lambda r: math.tanh(sharpness * r) + k1(r)  # noqa: E731
    p = p_hat = f_hat = 0.0
    out = []
    for f in force:
        p += dt * (tau + f)
        s = p - p_hat - dt * (tau + f_hat)
        lo, hi = -abs(s) - 1.0, abs(s) + 1.0
        for _ in range(100):
            mid = 0.5 * (lo + hi)
            if mid + dt * b * k1(mid) + dt * dt * b * b * k2(mid) > s:
                hi = mid
            else:
                lo = mid
        r = 0.5 * (lo + hi)
        f_hat += dt * b * b * k2(r)
        p_hat = p - r
        out.append(f_hat)
    return np.asarray(out)


@pytest.mark.parametrize("mode", ["plain", "mixed"])
@pytest.mark.parametrize("b, dt", [(30.0, 0.002), (100.0, 0.005)])
def test_one_dof_matches_numpy_backward_euler(mode, b, dt):
    force = np.r_[np.full(150, 12.0), np.full(100, 3.0), np.zeros(100)]
    _, est = _run(_params(mode, bandwidth=b, f_max=1e6), jnp.zeros(1), *_one_dof_inputs(force, dt, tau=-4.0))
    ref = _reference_1dof(force, dt, b, mode, tau=-4.0)
    np.testing.assert_allclose(np.asarray(est.force_z[:, 0]), np.clip(ref, 0.0, None), atol=2e-3 * 12.0)
    assert np.all(np.asarray(est.valid))


def test_plain_one_dof_converges_to_analytic_critically_damped_response():
    # f_hat(t) = f (1 - (1 + b t) e^{-b t}) for a constant force from t = 0 (error y'' + 2b y' + b^2 y = 0).
    b, f, n = 30.0, 10.0, 350
    errors = []
    for dt in (8e-4, 4e-4, 2e-4):  # n steps cover the peak error near t = 1/b
        _, est = _run(_params("plain", bandwidth=b), jnp.zeros(1), *_one_dof_inputs(np.full(n, f), dt))
        t = dt * np.arange(1, n + 1)
        errors.append(np.abs(np.asarray(est.force_z[:, 0]) - f * (1 - (1 + b * t) * np.exp(-b * t))).max())
    assert errors[-1] < 0.005 * f
    # Backward Euler converges at first order: halving dt halves the error.
    for coarse, fine in zip(errors, errors[1:]):
        assert 1.7 < coarse / fine < 2.3


def test_postprocessing_matches_numpy_loop_with_hysteresis_and_clipping():
    dt = 0.002
    force = np.r_[np.zeros(30), np.full(80, 150.0), np.full(80, -20.0), np.full(80, 6.0), np.full(80, 2.5)]
    assert len(force) == 350
    params = _params("mixed", alpha=[0.3], threshold_on=[5.0], threshold_off=[3.0], soft_temperature=0.5)
    _, est = _run(params, jnp.zeros(1), *_one_dof_inputs(force, dt))
    raw = np.asarray(est.force_z[:, 0], np.float64)
    assert raw.min() >= 0.0 and raw.max() <= 100.0 and np.isclose(raw.max(), 100.0)
    filt, on, soft = 0.0, False, []
    filts, contacts = [], []
    for x in raw:
        threshold = 3.0 if on else 5.0
        filt = 0.3 * x + 0.7 * filt
        on = filt > threshold
        soft.append(1.0 / (1.0 + math.exp(-(filt - threshold) / 0.5)))
        filts.append(filt)
        contacts.append(on)
    np.testing.assert_allclose(np.asarray(est.force_z_filtered[:, 0]), filts, rtol=1e-5, atol=1e-4)
    np.testing.assert_array_equal(np.asarray(est.contact[:, 0]), contacts)
    np.testing.assert_allclose(np.asarray(est.contact_soft[:, 0]), soft, atol=1e-5)
    # The 2.5 N tail lies between the thresholds: contact turns off only because 2.5 < 3.
    assert not contacts[-1] and contacts[-90]


def test_mixed_step_solves_its_implicit_equations_on_random_multi_foot_inputs():
    """After one mixed step, in float64: r + h k1(r) + dt J_z^T df = s0 and df = dt b^2 P k2(r), with
    r = p - p_hat_new, df = f_new - f_old, s0 = p - p_hat_old - dt (tau_bar + J_z^T f_old)."""
    rng = np.random.default_rng(7)
    n, F, nv = 64, 4, 18
    J = rng.normal(size=(n, F, nv)) * 0.3
    J[:, :, 2] = 1.0  # every foot moves with the base height
    scale = 10.0 ** rng.uniform(-5, 1, size=(n, 1))
    p_hat, tau = rng.normal(size=(n, nv)), rng.normal(size=(n, nv)) * 20
    f_old = rng.uniform(-10, 60, size=(n, F))
    b, dt = rng.uniform(10, 100, size=n), rng.uniform(1e-3, 5e-3, size=n)
    s0 = rng.normal(size=(n, nv)) * scale
    p = p_hat + dt[:, None] * (tau + np.einsum("kfn,kf->kn", J, f_old)) + s0
    base = ObserverParams.paper(F, "mixed")
    params = jax.vmap(lambda bw: dataclasses.replace(base, bandwidth=bw))(jnp.asarray(b, jnp.float32))
    state = _OBS.init(base, jnp.zeros(nv), F)
    states = jax.tree.map(lambda x: jnp.broadcast_to(x, (n, *x.shape)), state)
    states = eqx.tree_at(
        lambda s: (s.p_hat, s.f_hat), states, (jnp.asarray(p_hat, jnp.float32), jnp.asarray(f_old, jnp.float32))
    )
    f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    new, est = jax.jit(jax.vmap(_OBS.step))(params, states, f32(p), f32(tau), f32(J), f32(dt))
    assert bool(est.valid.all())
    # Residuals from the float32 state, recomputed in float64.
    p32, p_hat32, f_old32 = (np.asarray(f32(x), np.float64) for x in (p, p_hat, f_old))
    tau32, J32, dt32 = (np.asarray(f32(x), np.float64) for x in (tau, J, dt))
    r = p32 - np.asarray(new.p_hat, np.float64)
    df = np.asarray(new.f_hat, np.float64) - f_old32
    s0 = p32 - p_hat32 - dt32[:, None] * (tau32 + np.einsum("kfn,kf->kn", J32, f_old32))
    h = (b * dt32)[:, None]
    k1 = np.sign(r) * np.sqrt(np.abs(r)) + r
    k2 = np.tanh(100.0 * r) + k1
    eq1 = r + h * k1 + dt32[:, None] * np.einsum("kfn,kf->kn", J32, df) - s0
    gram = np.einsum("kfn,kgn->kfg", J32, J32) + 1e-4 * np.eye(F)
    P = np.linalg.solve(gram, J32)
    gain = (dt32 * b**2)[:, None]
    eq2 = df - gain * np.einsum("kfn,kn->kf", P, k2)
    # float32 round-off of p and p_hat (|p| ~ 1) bounds how well the equations can be checked: r is
    # known to dr ~ eps (|p| + |p_hat|), which k2 (slope 100 + 1 + 1/(2 |r|^(1/2))) and b^2 dt amplify.
    dr = 2.0**-22 * (np.abs(p32) + np.abs(np.asarray(new.p_hat, np.float64)))
    dk2 = (101.0 + 0.5 / np.sqrt(np.maximum(np.abs(r), dr))) * dr
    assert np.all(np.abs(eq1) <= 2 * dr + 1e-5 * np.abs(s0).max())
    assert np.all(np.abs(eq2) <= 2 * gain * np.einsum("kfn,kn->kf", np.abs(P), dk2) + 1e-4 * (1.0 + np.abs(df)))


# ---------------------------------------------------------------- floating-base quadruped, MuJoCo C


def _leg(name, x, y, side):
    return f"""
      <body name="{name}_hip" pos="{x} {y} 0">
        <joint name="{name}_hip" axis="1 0 0" armature="0.01"/>
        <inertial pos="0 {side * 0.05} 0" mass="0.678" diaginertia="0.0005 0.0008 0.0005"/>
        <body name="{name}_thigh" pos="0 {side * 0.0955} 0">
          <joint name="{name}_thigh" axis="0 1 0" armature="0.01"/>
          <inertial pos="0 0 -0.03" mass="1.152" diaginertia="0.005 0.005 0.001"/>
          <body name="{name}_calf" pos="0 0 -0.213">
            <joint name="{name}_calf" axis="0 1 0" armature="0.01"/>
            <inertial pos="0 0 -0.1" mass="0.241" diaginertia="0.001 0.001 0.0001"/>
            <site name="{name}_foot" pos="0 0 -0.213"/>
          </body>
        </body>
      </body>"""


_LEGS = [
    ("FL", 0.1934, 0.0465, 1),
    ("FR", 0.1934, -0.0465, -1),
    ("RL", -0.1934, 0.0465, 1),
    ("RR", -0.1934, -0.0465, -1),
]
_QUAD_XML = f"""
<mujoco model="quad">
  <option timestep="0.001" gravity="0 0 -9.81"><flag contact="disable"/></option>
  <worldbody>
    <body name="trunk" pos="0 0 0.4">
      <freejoint/>
      <inertial pos="0 0 0" mass="6.921" diaginertia="0.107 0.098 0.0245"/>
      {"".join(_leg(*leg) for leg in _LEGS)}
    </body>
  </worldbody>
  <actuator>
    {"".join(f'<motor joint="{n}_{j}"/>' for n, *_ in _LEGS for j in ("hip", "thigh", "calf"))}
  </actuator>
</mujoco>"""

_SIM_DT, _SUBSTEPS, _T_STEP, _T_END = 0.001, 2, 0.6, 1.2
_FORCE_BEFORE = np.array([40.0, 30.0, 35.0, 0.0])  # world z, on each foot (N)
_FORCE_AFTER = np.array([40.0, 30.0, 35.0, 25.0])


def _simulate(m, trunk, sites, qpos_adr, dof_adr, substeps=_SUBSTEPS):
    """Samples (every `substeps` ms) of p = M v, tau_bar = S^T tau + C^T v - g and J_z from MuJoCo C while
    known z forces act on the feet, a known wrench supports the trunk and PD joints track sinusoids
    (no ground, no contact); also the raw state, motor torques and support force at each sample.
    C^T v = Mdot v - C v with Mdot v by central differences of M along v, C v + g = qfrc_bias."""
    d, d_fd = mujoco.MjData(m), mujoco.MjData(m)
    q_stand = np.tile([0.0, 0.9, -1.8], 4)
    d.qpos[qpos_adr] = q_stand
    bodies = [m.site_bodyid[s] for s in sites]
    phase = np.arange(12) * 0.7
    nv, eps = m.nv, 1e-6
    M, M_plus, M_minus = (np.zeros((nv, nv)) for _ in range(3))
    jacp = np.zeros((3, nv))
    weight = -m.opt.gravity[2] * m.body_subtreemass[trunk]
    qfrc_support = np.zeros(nv)
    rows = {name: [] for name in ("p", "tau", "J", "t", "qpos", "qvel", "ctrl", "support")}
    for k in range(round(_T_END / _SIM_DT)):
        t = k * _SIM_DT
        mujoco.mj_forward(m, d)
        if k % substeps == 0:
            # A sample: qfrc_actuator is still the torque held over the interval that ends here.
            mujoco.mj_fullM(m, d, M)
            for sign, out in ((1.0, M_plus), (-1.0, M_minus)):
                d_fd.qpos[:] = d.qpos
                mujoco.mj_integratePos(m, d_fd.qpos, d.qvel, sign * eps)
                mujoco.mj_fwdPosition(m, d_fd)
                mujoco.mj_fullM(m, d_fd, out)
            mdot_v = (M_plus - M_minus) @ d.qvel / (2 * eps)
            rows["p"].append(M @ d.qvel)
            rows["tau"].append(d.qfrc_actuator + qfrc_support + mdot_v - d.qfrc_bias)
            J_z = np.zeros((len(sites), nv))
            for i, site in enumerate(sites):
                mujoco.mj_jacSite(m, d, jacp, None, site)
                J_z[i] = jacp[2]
            rows["J"].append(J_z)
            rows["t"].append(t)
            for name, value in (("qpos", d.qpos), ("qvel", d.qvel), ("ctrl", d.ctrl), ("support", qfrc_support)):
                rows[name].append(value.copy())
            # The joint PD runs at the sample rate and holds its torque until the next sample.
            q_des = q_stand + 0.3 * np.sin(2 * np.pi * 1.5 * t + phase)
            d.ctrl[:] = 40.0 * (q_des - d.qpos[qpos_adr]) - 0.6 * d.qvel[dof_adr]
        # Known support of the trunk: cancels gravity and the feet's net force and moment, so the
        # base stays nearly still; it is part of the known generalized force, like the motors.
        forces = _FORCE_BEFORE if t < _T_STEP else _FORCE_AFTER
        com = d.subtree_com[trunk]
        f_support = np.array([0.0, 0.0, weight - forces.sum()])
        m_support = -sum(np.cross(d.site_xpos[s] - com, [0.0, 0.0, fz]) for s, fz in zip(sites, forces))
        qfrc_support[:] = 0.0
        mujoco.mj_applyFT(m, d, f_support, m_support, com, trunk, qfrc_support)
        d.qfrc_applied[:] = qfrc_support
        for site, body, fz in zip(sites, bodies, forces):
            mujoco.mj_applyFT(m, d, np.array([0.0, 0.0, fz]), np.zeros(3), d.site_xpos[site], body, d.qfrc_applied)
        mujoco.mj_step(m, d)
    return {k: np.asarray(v) for k, v in rows.items()} | {"dt": substeps * _SIM_DT}


def _simulate_quad(substeps):
    m = mujoco.MjModel.from_xml_string(_QUAD_XML)
    sites = [m.site(f"{n}_foot").id for n, *_ in _LEGS]
    return _simulate(m, m.body("trunk").id, sites, np.arange(7, 19), np.arange(6, 18), substeps)


@pytest.fixture(scope="module")
def quad():
    return _simulate_quad(_SUBSTEPS)


def _quad_inputs(quad, n=None):
    """Samples 1..n as observer inputs; sample 0 initialises the state (see _p0)."""
    n = len(quad["t"]) - 1 if n is None else n
    return (
        jnp.asarray(quad["p"][1 : n + 1], jnp.float32),
        jnp.asarray(quad["tau"][1 : n + 1], jnp.float32),
        jnp.asarray(quad["J"][1 : n + 1], jnp.float32),
        jnp.full(n, quad["dt"], jnp.float32),
    )


def _p0(quad):
    return jnp.asarray(quad["p"][0], jnp.float32)


@pytest.fixture(scope="module")
def quad_estimates(quad):
    inputs = _quad_inputs(quad)
    return {
        mode: jax.tree.map(np.asarray, _run(ObserverParams.paper(4, mode), _p0(quad), *inputs)[1])
        for mode in ("plain", "mixed")
    }


@pytest.mark.parametrize("mode", ["plain", "mixed"])
def test_quadruped_steady_state_force_within_two_percent(quad, quad_estimates, mode):
    est, t = quad_estimates[mode], quad["t"][1:]
    assert est.valid.all()
    for (t0, t1), truth in (((0.35, _T_STEP), _FORCE_BEFORE), ((0.95, _T_END), _FORCE_AFTER)):
        window = (t >= t0) & (t < t1)
        for name in ("force_z", "force_z_filtered"):
            err = np.abs(getattr(est, name)[window] - truth).max(axis=0)
            tol = 0.02 * np.where(truth > 0, truth, _FORCE_BEFORE.max())
            assert np.all(err <= tol), (mode, name, t0, err, tol)
        np.testing.assert_array_equal(est.contact[window], np.broadcast_to(truth > 0, est.contact[window].shape))


@pytest.mark.slow  # compiling momentum_terms (MJX) takes most of a minute on CPU
def test_go2_with_library_momentum_terms(record_property):
    """The real robot: p, tau_bar, J_z from jaxquad.dynamics.momentum_terms (MJX) agree with MuJoCo C
    on the same samples, and the observer fed with them recovers the foot forces within 2%."""
    from jaxquad.dynamics import momentum_terms
    from jaxquad.robots import load

    robot = load("go2")
    m = copy.copy(robot.mj_model)
    m.opt.timestep = _SIM_DT
    m.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    # Joint friction and damping are forces the observer is not told about: off, as in the quad test.
    m.dof_frictionloss[:] = 0.0
    m.dof_damping[:] = 0.0
    m.actuator_ctrllimited[:] = 0
    sim = _simulate(m, robot.base_body_id, robot.foot_site_ids, robot.qpos_adr, robot.dof_adr)
    terms = jax.jit(jax.vmap(lambda q, v, tau: momentum_terms(robot, q, v, tau, passive=False)))
    p, tau_bar, J_z = (
        np.asarray(x, np.float64) for x in terms(*(jnp.asarray(sim[k]) for k in ("qpos", "qvel", "ctrl")))
    )
    np.testing.assert_allclose(p, sim["p"], atol=1e-3 * np.abs(sim["p"]).max())
    np.testing.assert_allclose(tau_bar + sim["support"], sim["tau"], atol=2e-3 * np.abs(sim["tau"]).max())
    np.testing.assert_allclose(J_z, sim["J"], atol=1e-5)

    t = sim["t"][1:]
    inputs = _quad_inputs({"p": p, "tau": tau_bar + sim["support"], "J": J_z, "t": sim["t"], "dt": sim["dt"]})
    for mode in ("plain", "mixed"):
        est = jax.tree.map(np.asarray, _run(ObserverParams.paper(4, mode), jnp.asarray(p[0], jnp.float32), *inputs)[1])
        for (t0, t1), truth in (((0.35, _T_STEP), _FORCE_BEFORE), ((0.95, _T_END), _FORCE_AFTER)):
            window = (t >= t0) & (t < t1)
            err = np.abs(est.force_z[window] - truth).max(axis=0)
            assert np.all(err <= 0.02 * np.where(truth > 0, truth, _FORCE_BEFORE.max())), (mode, t0, err)
        record_property(f"go2_lag_{mode}_ms", round(float(1e3 * _detection_lag(est, t)), 3))


@pytest.mark.parametrize("mode", ["plain", "mixed"])
def test_quadruped_high_bandwidth_at_4ms_samples_stays_within_two_percent(mode):
    # h = b dt = 0.4, where an explicit k2 update of the mixed observer chatters (limit cycle of b^2 dt = 40 N).
    quad = _simulate_quad(4)
    t = quad["t"][1:]
    est = jax.tree.map(
        np.asarray, _run(ObserverParams.paper(4, mode, bandwidth=100.0), _p0(quad), *_quad_inputs(quad))[1]
    )
    for (t0, t1), truth in (((0.35, _T_STEP), _FORCE_BEFORE), ((0.95, _T_END), _FORCE_AFTER)):
        window = (t >= t0) & (t < t1)
        err = np.abs(est.force_z[window] - truth).max(axis=0)
        assert np.all(err <= 0.02 * np.where(truth > 0, truth, _FORCE_BEFORE.max())), (mode, t0, err)


def _detection_lag(est, t):
    after = t >= _T_STEP
    return t[after][np.argmax(est.contact[after, 3])] - _T_STEP


def test_mixed_mode_detects_a_force_step_sooner_than_plain(quad, quad_estimates, record_property):
    t = quad["t"][1:]
    lags = {mode: _detection_lag(quad_estimates[mode], t) for mode in ("plain", "mixed")}
    for mode in lags:
        est = quad_estimates[mode]
        assert not est.contact[(t > 0.3) & (t < _T_STEP), 3].any()  # no false contact before the step
        assert est.contact[t >= _T_STEP + 0.1, 3].all()
        record_property(f"lag_{mode}_ms", round(float(1e3 * lags[mode]), 3))
    print(
        f"\ncontact detection lag after a 0 -> 25 N step (b = 30 rad/s, dt = 2 ms): "
        f"plain {1e3 * lags['plain']:.1f} ms, mixed {1e3 * lags['mixed']:.1f} ms"
    )
    assert lags["mixed"] < lags["plain"]


# ---------------------------------------------------------------- jit, vmap, grad, bad input


@pytest.mark.parametrize("mode", ["plain", "mixed"])
def test_vmap_over_params_matches_single_runs_without_recompiling(quad, mode):
    inputs = _quad_inputs(quad)
    singles = [ObserverParams.paper(4, mode, bandwidth=b) for b in (15.0, 30.0, 90.0)]
    before = _run._cache_size()
    outs = [_run(p, _p0(quad), *inputs)[1].force_z for p in singles]
    assert _run._cache_size() - before <= 1  # one trace per mode, whatever the numbers
    stacked = jax.tree.map(lambda *x: jnp.stack(x), *singles)
    batch = _run_params_batch(stacked, _p0(quad), *inputs)[1].force_z
    for i, out in enumerate(outs):
        np.testing.assert_allclose(batch[i], out, rtol=1e-4, atol=1e-3)


@pytest.mark.parametrize("mode", ["plain", "mixed"])
def test_vmap_over_robots_and_bad_input_flagged_and_held(quad, mode):
    params = ObserverParams.paper(4, mode)
    p, tau, J, dt = _quad_inputs(quad)
    bad = 120
    p_nan, J_inf, dt_zero = p.at[bad, 3].set(jnp.nan), J.at[bad + 1, 0, 5].set(jnp.inf), dt.at[bad + 2].set(0.0)
    batch = jax.tree.map(lambda *x: jnp.stack(x), (p, tau, J, dt), (p_nan, tau, J_inf, dt_zero))
    p0 = jnp.stack([_p0(quad)] * 2)
    (_, est) = _run_robot_batch(params, p0, *batch)
    clean = _run(params, _p0(quad), p, tau, J, dt)[1]
    np.testing.assert_allclose(est.force_z[0], clean.force_z, rtol=1e-5, atol=1e-4)
    assert bool(est.valid[0].all())
    valid = np.asarray(est.valid[1])
    assert not valid[bad : bad + 3].any() and valid[:bad].all() and valid[bad + 3 :].all()
    for field in ("force_z", "force_z_filtered", "contact", "contact_soft"):
        held = np.asarray(getattr(est, field)[1])
        assert np.isfinite(held.astype(float)).all()
        for k in (bad, bad + 1, bad + 2):
            np.testing.assert_array_equal(held[k], held[bad - 1])
    # A rejected step returns the state it was given, bit for bit.
    state = _run(params, _p0(quad), p, tau, J, dt)[0]
    held_state, out = _step(params, state, p_nan[bad], tau[bad], J[bad], dt[bad])
    assert not bool(out.valid)
    for a, b in zip(jax.tree.leaves(held_state), jax.tree.leaves(state)):
        np.testing.assert_array_equal(a, b)


def _loss(params, inputs, p0):
    # Feet that carry force only: the clip at 0 N makes the idle foot's estimate kinked in the params.
    _, est = _scan(params, p0, *inputs)
    return est.contact_soft[:, :3].sum() + 0.01 * est.force_z_filtered[:, :3].sum()


_value_and_grad = jax.jit(jax.value_and_grad(_loss))


@pytest.mark.parametrize("mode", ["plain", "mixed"])
def test_gradients_through_200_steps_finite_and_match_finite_differences(quad, mode):
    params, inputs, p0 = ObserverParams.paper(4, mode), _quad_inputs(quad, 200), _p0(quad)
    _, g = _value_and_grad(params, inputs, p0)
    for name in ("bandwidth", "alpha", "threshold_on", "threshold_off", "sharpness", "f_max", "soft_temperature"):
        assert np.isfinite(getattr(g, name)).all(), name
    for name in ("bandwidth", "alpha", "threshold_on"):
        assert np.abs(getattr(g, name)).max() > 0, name
    # d loss / d bandwidth against a central difference (step small against the tanh kink scale).
    step = 0.05
    shifted = [dataclasses.replace(params, bandwidth=params.bandwidth + d) for d in (step, -step)]
    fd = (_value_and_grad(shifted[0], inputs, p0)[0] - _value_and_grad(shifted[1], inputs, p0)[0]) / (2 * step)
    np.testing.assert_allclose(g.bandwidth, fd, rtol=0.02)
    # Zero residual at every step: a body at rest with no force, where |s|^(1/2) is singular.
    n, nv = 200, quad["p"].shape[1]
    rest = (jnp.zeros((n, nv)), jnp.zeros((n, nv)), inputs[2], jnp.full(n, 0.002))
    _, g0 = _value_and_grad(params, rest, jnp.zeros(nv))
    assert all(np.isfinite(leaf).all() for leaf in jax.tree.leaves(g0))


def test_bad_shapes_and_modes_raise():
    params = ObserverParams.paper(4)
    state = _OBS.init(params, jnp.zeros(18), 4)
    with pytest.raises(ValueError, match="J_z"):
        _OBS.step(params, state, jnp.zeros(18), jnp.zeros(18), jnp.zeros((3, 18)), 0.002)
    with pytest.raises(ValueError, match="n_feet"):
        _OBS.init(params, jnp.zeros(18), 2)
    # An unknown mode is rejected by the explicit check, or first by the tests' runtime type checker (Literal).
    with pytest.raises((ValueError, TypeError), match="mode"):
        _params("sliding")
    with pytest.raises(ValueError, match="even"):
        ObserverParams.paper(3)
