"""The generic RTI core: converged SQP against IPOPT, QP data against finite differences, the
HPIPM call against CasADi's plain call, fallback on QP failure and input validation."""
from __future__ import annotations

import dataclasses

import casadi as ca
import numpy as np
import pytest

from controllers.rti import OCP, IpoptOCPSolver, RTIOptions, RTISolver
from controllers.vtnmpc import VTNMPCConfig, build_ocp, vtnmpc_parameters
from wt_inspect_env.task.geometry import standoff_state as ideal_state


@pytest.fixture(scope="module")
def cache_dir(qp_cache_dir) -> str:
    return qp_cache_dir


def pendulum_ocp(horizon: int = 20, constrained: bool = True) -> OCP:
    """A damped pendulum swung towards theta_ref (a parameter), with input bounds, an upper bound
    on the rate and a path constraint, so every constraint hook is exercised."""
    x = ca.SX.sym("x", 2)
    u = ca.SX.sym("u", 1)
    p = ca.SX.sym("p", 1)
    dt = 0.05

    def f(x_, u_):
        return ca.vertcat(x_[1], -ca.sin(x_[0]) - 0.1 * x_[1] + u_[0])

    k1 = f(x, u)
    k2 = f(x + dt / 2 * k1, u)
    k3 = f(x + dt / 2 * k2, u)
    k4 = f(x + dt * k3, u)
    F = ca.Function("F", [x, u, p], [x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)])
    r = ca.Function("r", [x, u, p], [ca.vertcat(x[0] - p[0], x[1], u[0])])
    rN = ca.Function("rN", [x, p], [ca.vertcat(x[0] - p[0], x[1])])
    kw = {}
    if constrained:
        kw = dict(x_lower=[-np.inf, -np.inf], x_upper=[np.inf, 0.6],
                  path_constraint=ca.Function("h", [x, u, p], [x[0] + 0.2 * u[0]]),
                  h_lower=[-10.0], h_upper=[1.0])
    return OCP(name="pendulum", dynamics=F, stage_residual=r, terminal_residual=rN,
               horizon=horizon, dt=dt, u_lower=[-0.8], u_upper=[0.8], fallback_input=[0.0], **kw)


PEND_W = np.array([10.0, 1.0, 0.5])
PEND_WN = np.array([50.0, 5.0])


def converge_sqp_and_ipopt(ocp: OCP, W, WN, opts: RTIOptions, x0, p, max_iter: int, qp_solver: str | None = None):
    """The RTI core's SQP mode (tol 1e-8, at most ``max_iter`` iterations) and IPOPT (tol 1e-12) on the
    same problem: (rti, ipopt) after checking the SQP converged (``SUCCESS``) and, when given, that it
    runs the QP path ``qp_solver``."""
    rti = RTISolver(ocp, W, WN, opts)
    if qp_solver is not None:
        assert rti.qp_solver == qp_solver
    rti.solve(x0, p, max_iter=max_iter, tol=1e-8)
    assert rti.last_stats.status == "SUCCESS"
    ipopt = IpoptOCPSolver(ocp, W, WN, tol=1e-12)
    ipopt.solve(x0, p)
    return rti, ipopt


def test_sqp_matches_ipopt_with_active_constraints(cache_dir):
    ocp = pendulum_ocp(horizon=40)
    x0, p = np.array([0.0, 0.0]), np.array([3.0])
    opts = RTIOptions(cache_dir=cache_dir, qp_mode="balance", qp_tol=1e-8, qp_iter_max=100)
    rti, ipopt = converge_sqp_and_ipopt(ocp, PEND_W, PEND_WN, opts, x0, p, max_iter=200)
    assert rti.last_stats.sqp_iterations < 200
    w_rti, w_ip = rti.iterate, ipopt.iterate
    xs, us = ocp.unpack(w_rti)
    # the constraints are really active, otherwise this would not test the hooks
    assert np.isclose(us.max(), 0.8, atol=1e-6)
    assert np.isclose(xs[:, 1].max(), 0.6, atol=1e-6)
    assert np.isclose((xs[:-1, 0] + 0.2 * us[:, 0]).max(), 1.0, atol=1e-6)
    np.testing.assert_allclose(w_rti, w_ip, atol=2e-6)
    assert rti.cost(p) == pytest.approx(ipopt.last_stats.cost, rel=1e-7)


POINT, NORMAL = np.array([1.0, 2.0, 30.0]), np.array([0.0, -1.0, 0.0])


def hard_vtnmpc_problem(cfg: VTNMPCConfig):
    """The VT-NMPC OCP of ``cfg`` from a start 2.7 m, 1.2 m/s and 34 deg of yaw off the pose
    (rate bounds become active): (ocp, W, W_N, x0, params)."""
    ocp = build_ocp(cfg)
    x0 = ideal_state(POINT, NORMAL, cfg.d_ref)
    x0[0:3] += [2.0, -1.5, 1.0]
    x0[3:6] = [1.0, -0.5, 0.5]
    x0[6:10] = [0.0, 0.0, np.sin(np.pi / 4 + 0.3), np.cos(np.pi / 4 + 0.3)]  # 34 deg yaw error
    params = vtnmpc_parameters(x0, POINT, NORMAL[:2], np.array([0.7, 0.0, 0.0]))
    return ocp, cfg.weights.stage_vector(), cfg.weights.terminal_vector(), x0, params


@pytest.mark.slow
@pytest.mark.unit
def test_vtnmpc_sqp_matches_ipopt(cache_dir):
    cfg = VTNMPCConfig(solver=RTIOptions(cache_dir=cache_dir, qp_mode="balance", qp_tol=1e-8, qp_iter_max=100))
    ocp, W, WN, x0, params = hard_vtnmpc_problem(cfg)
    rti, ipopt = converge_sqp_and_ipopt(ocp, W, WN, cfg.solver, x0, params, max_iter=100)
    xs, us = ocp.unpack(rti.iterate)
    xs_ip, us_ip = ocp.unpack(ipopt.iterate)
    np.testing.assert_allclose(xs, xs_ip, atol=2e-6)
    # inputs next to an active rate bound differ by ~3e-5 rad/s between the two solvers
    # (interior point vs active set corner); the costs agree to 1e-10
    np.testing.assert_allclose(us, us_ip, atol=1e-4)
    assert rti.cost(params) == pytest.approx(ipopt.last_stats.cost, rel=1e-9)
    # bounds active in the solution (thrust or rates), so the comparison covers them
    assert np.any(np.isclose(us, ocp.u_lower, atol=1e-6) | np.isclose(us, ocp.u_upper, atol=1e-6))


def _stacked(ocp: OCP, w: np.ndarray, p: np.ndarray, W: np.ndarray, WN: np.ndarray):
    """Weighted residuals sqrt(W) r and multiple-shooting defects F(x_k, u_k) - x_{k+1}."""
    xs, us = ocp.unpack(w)
    res, defects = [], []
    for k in range(ocp.horizon):
        res.append(np.sqrt(W) * np.asarray(ocp.stage_residual(xs[k], us[k], p)).ravel())
        defects.append(np.asarray(ocp.dynamics(xs[k], us[k], p)).ravel() - xs[k + 1])
    res.append(np.sqrt(WN) * np.asarray(ocp.terminal_residual(xs[-1], p)).ravel())
    return np.concatenate(res), np.concatenate(defects)


@pytest.mark.slow
@pytest.mark.unit
def test_qp_data_matches_finite_differences(cache_dir):
    cfg = VTNMPCConfig(horizon=6, solver=RTIOptions(cache_dir=cache_dir))
    ocp = build_ocp(cfg)
    W, WN = cfg.weights.stage_vector(), cfg.weights.terminal_vector()
    rng = np.random.default_rng(3)
    point, normal = np.array([0.0, 0.0, 20.0]), np.array([0.6, 0.8, 0.0])
    x_ref = ideal_state(point, normal, cfg.d_ref)
    xs = x_ref + 0.3 * rng.standard_normal((ocp.horizon + 1, ocp.nx))
    xs[:, 6:10] /= np.linalg.norm(xs[:, 6:10], axis=1, keepdims=True)
    us = cfg.hover_input + rng.standard_normal((ocp.horizon, ocp.nu)) * [0.3, 0.3, 0.3, 3.0]
    w = ocp.pack(xs, us)
    params = vtnmpc_parameters(xs[0], point, normal[:2], rng.standard_normal(3),
                               disturbance_accel=0.5 * rng.standard_normal(3))
    solver = RTISolver(ocp, W, WN, cfg.solver)
    qp = solver.qp_matrices(params, w)

    res0, def0 = _stacked(ocp, w, params, W, WN)
    eps = 1e-6
    n = w.size
    J = np.empty((res0.size, n))
    D = np.empty((def0.size, n))
    for i in range(n):
        e = np.zeros(n)
        e[i] = eps
        rp, dp = _stacked(ocp, w + e, params, W, WN)
        rm, dm = _stacked(ocp, w - e, params, W, WN)
        J[:, i] = (rp - rm) / (2 * eps)
        D[:, i] = (dp - dm) / (2 * eps)
    # dynamics rows: A dw = d(defects); bounds: minus the defects
    np.testing.assert_allclose(qp["A"], D, atol=1e-6)
    np.testing.assert_allclose(qp["lba"].ravel(), -def0, atol=1e-12)
    np.testing.assert_allclose(qp["uba"].ravel(), -def0, atol=1e-12)
    # Gauss-Newton: g = J^T W r (exact gradient of the cost), H = J^T W J
    np.testing.assert_allclose(qp["g"].ravel(), J.T @ res0, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(qp["H"], J.T @ J, rtol=1e-6, atol=1e-5)
    assert qp["cost"].item() == pytest.approx(0.5 * res0 @ res0, rel=1e-12)


def test_feedback_solution_equals_plain_qp_call(cache_dir):
    """Guards the zero-copy HPIPM path (a reused CasADi buffer returned stale solutions)."""
    ocp = pendulum_ocp(constrained=False)
    rti = RTISolver(ocp, PEND_W, PEND_WN, RTIOptions(cache_dir=cache_dir))
    p = np.array([1.0])
    rti.initialize(np.zeros(2))
    for x0 in (np.array([0.0, 0.0]), np.array([0.3, -0.2]), np.array([-0.4, 0.5])):
        rti.prepare(p)
        w_before = rti.iterate
        qp = rti.qp_matrices(p)
        lbx = np.clip(rti._lb_abs - w_before, -1e8, 1e8)
        ubx = np.clip(rti._ub_abs - w_before, -1e8, 1e8)
        lbx[:2] = ubx[:2] = x0 - w_before[:2]
        ref = rti._qp(h=ca.sparsify(ca.DM(qp["H"])), g=qp["g"], a=ca.sparsify(ca.DM(qp["A"])),
                      lba=qp["lba"], uba=qp["uba"], lbx=lbx, ubx=ubx)
        rti.feedback(x0)
        np.testing.assert_allclose(rti.iterate - w_before, np.asarray(ref["x"]).ravel(),
                                   atol=1e-9)
        np.testing.assert_allclose(rti.iterate[:2], x0, atol=1e-9)
        rti.shift()


def test_rti_converges_along_closed_loop_to_the_sqp_solution(cache_dir):
    """With a fixed measurement, repeated RTI steps without shift are SQP iterations."""
    ocp = pendulum_ocp()
    x0, p = np.array([0.2, 0.0]), np.array([0.7])
    a = RTISolver(ocp, PEND_W, PEND_WN, RTIOptions(cache_dir=cache_dir))
    b = RTISolver(ocp, PEND_W, PEND_WN, RTIOptions(cache_dir=cache_dir))
    a.solve(x0, p, tol=1e-9)
    b.initialize(x0)
    for _ in range(60):
        b.prepare(p)
        b.feedback(x0)
    np.testing.assert_allclose(a.iterate, b.iterate, atol=1e-7)


def test_shift_moves_plan_one_stage():
    ocp = pendulum_ocp(horizon=4, constrained=False)
    rti = RTISolver(ocp, PEND_W, PEND_WN, RTIOptions(compiled=False))
    xs = np.arange(10.0).reshape(5, 2)
    us = np.arange(4.0).reshape(4, 1) / 10
    rti.initialize(xs[0], inputs=us, states=xs)
    rti.shift()
    np.testing.assert_array_equal(rti.states, np.vstack([xs[1:], xs[-1:]]))
    np.testing.assert_array_equal(rti.inputs, np.vstack([us[1:], us[-1:]]))


def test_forced_qp_failure_falls_back_to_shifted_plan_then_hover(cache_dir):
    ocp = pendulum_ocp(horizon=5, constrained=False)
    rti = RTISolver(ocp, PEND_W, PEND_WN, RTIOptions(cache_dir=cache_dir))
    p = np.array([1.0])
    x = np.array([0.1, 0.0])
    for _ in range(5):
        rti.step(x, p)
    assert rti.last_stats.status == "SUCCESS" and not rti.last_stats.fallback
    # weights so large that the Hessian overflows: HPIPM cannot solve the QP
    rti.set_weights(np.full(3, 1e300), np.full(2, 1e300))
    sources = []
    for _ in range(ocp.horizon + 2):
        plan_next = rti.inputs[0].copy()      # the shifted previous plan's next input
        u = rti.step(x, p)
        st = rti.last_stats
        assert st.fallback and st.status != "SUCCESS"
        sources.append(st.fallback_source)
        if st.fallback_source == "shifted_plan":
            np.testing.assert_array_equal(u, plan_next)
        else:
            np.testing.assert_array_equal(u, ocp.fallback_input)
        assert np.all(np.isfinite(u))
    assert sources[:ocp.horizon - 1] == ["shifted_plan"] * (ocp.horizon - 1)
    assert sources[-1] == "hover"
    # recovery once the QP is solvable again
    rti.set_weights(PEND_W, PEND_WN)
    rti.step(x, p)
    assert rti.last_stats.status == "SUCCESS" and not rti.last_stats.fallback


def test_iteration_limit_reports_status_and_falls_back(cache_dir):
    ocp = pendulum_ocp(horizon=10)
    rti = RTISolver(ocp, PEND_W, PEND_WN, RTIOptions(cache_dir=cache_dir, qp_iter_max=1))
    rti.initialize(np.zeros(2))
    u = rti.step(np.zeros(2), np.array([1.0]))
    st = rti.last_stats
    assert st.status == "MAX_ITER" and st.fallback and st.qp_iterations == 1
    np.testing.assert_array_equal(u, [0.0])  # the initial plan is hover
    assert st.feedback_ms > 0 and st.prepare_ms > 0


@pytest.mark.parametrize("horizon", [0, -3, 2.5, True, "30"])
def test_invalid_horizon_names_field(horizon):
    base = pendulum_ocp(horizon=3, constrained=False)
    with pytest.raises(ValueError, match="horizon"):
        OCP(name="p", dynamics=base.dynamics, stage_residual=base.stage_residual,
            terminal_residual=base.terminal_residual, horizon=horizon, dt=0.05, u_lower=[-1],
            u_upper=[1], fallback_input=[0])


@pytest.mark.parametrize("W, WN, field", [
    ([1.0, -2.0, 1.0], [1.0, 1.0], r"stage_weights\[1\]"),
    ([1.0, 1.0], [1.0, 1.0], "stage_weights"),
    ([1.0, np.nan, 1.0], [1.0, 1.0], "stage_weights"),
    ([1.0, 1.0, 1.0], [1.0, -1.0], r"terminal_weights\[1\]"),
])
def test_invalid_weights_name_field(W, WN, field):
    ocp = pendulum_ocp(horizon=3, constrained=False)
    with pytest.raises(ValueError, match=field):
        RTISolver(ocp, W, WN, RTIOptions(compiled=False))


def test_invalid_ocp_fields_are_named():
    base = pendulum_ocp(horizon=3, constrained=False)
    kw = dict(name="p", dynamics=base.dynamics, stage_residual=base.stage_residual,
              terminal_residual=base.terminal_residual, horizon=3, dt=0.05, u_lower=[-1],
              u_upper=[1], fallback_input=[0])
    for field, bad in (("dt", -0.1), ("u_lower", [2.0]), ("fallback_input", [5.0]),
                       ("u_upper", [1.0, 2.0]), ("name", "has space")):
        with pytest.raises(ValueError, match=field):
            OCP(**{**kw, field: bad})
    with pytest.raises(ValueError, match="qp_mode"):
        RTIOptions(qp_mode="fast")
    with pytest.raises(ValueError, match="qp_iter_max"):
        RTIOptions(qp_iter_max=0)
    rti = RTISolver(OCP(**kw), PEND_W, PEND_WN, RTIOptions(compiled=False))
    with pytest.raises(ValueError, match="x0"):
        rti.initialize([np.nan, 0.0])
    rti.initialize([0.0, 0.0])
    with pytest.raises(ValueError, match="params"):
        rti.prepare([1.0, 2.0])


def test_uncompiled_and_compiled_give_the_same_step(cache_dir):
    ocp = pendulum_ocp()
    a = RTISolver(ocp, PEND_W, PEND_WN, RTIOptions(cache_dir=cache_dir))
    b = RTISolver(ocp, PEND_W, PEND_WN, RTIOptions(compiled=False))
    assert a.qp_data.compiled and not b.qp_data.compiled
    for x in (np.zeros(2), np.array([0.3, 0.1])):
        np.testing.assert_allclose(a.step(x, [1.0]), b.step(x, [1.0]), atol=1e-10)


def test_compiled_library_is_cached(cache_dir):
    ocp = pendulum_ocp(horizon=7)
    first = RTISolver(ocp, PEND_W, PEND_WN, RTIOptions(cache_dir=cache_dir)).qp_data
    second = RTISolver(ocp, PEND_W, PEND_WN, RTIOptions(cache_dir=cache_dir)).qp_data
    assert first.compiled and second.cache_hit and second.path == first.path
    other = RTISolver(pendulum_ocp(horizon=8), PEND_W, PEND_WN,
                      RTIOptions(cache_dir=cache_dir)).qp_data
    assert other.path != first.path   # another problem, another key


def test_missing_compiler_warns_and_runs_uncompiled(cache_dir, monkeypatch):
    monkeypatch.setenv("CC", "no-such-compiler-xyz")
    ocp = pendulum_ocp(horizon=5)
    with pytest.warns(RuntimeWarning, match="no C compiler"):
        rti = RTISolver(ocp, PEND_W, PEND_WN, RTIOptions(cache_dir=cache_dir))
    assert not rti.qp_data.compiled
    rti.step(np.zeros(2), [1.0])
    assert rti.last_stats.status == "SUCCESS"


@pytest.mark.slow
@pytest.mark.unit
def test_direct_hpipm_sqp_matches_ipopt_and_the_plugin(cache_dir):
    """qp_solver='hpipm' (HPIPM called directly, x_0 eliminated, finite bounds only) converges to
    IPOPT's solution, and one RTI step agrees with CasADi's HPIPM plugin where no bound is
    active (at an active bound the plugin's speed preset stops ~7e-3 short of it, measured)."""
    base = dict(cache_dir=cache_dir, qp_mode="balance", qp_tol=1e-8, qp_iter_max=100)
    cfg = VTNMPCConfig(solver=RTIOptions(qp_solver="hpipm", **base))
    ocp, W, WN, x0, params = hard_vtnmpc_problem(cfg)
    rti, ipopt = converge_sqp_and_ipopt(ocp, W, WN, cfg.solver, x0, params, max_iter=100, qp_solver="hpipm")
    np.testing.assert_allclose(rti.iterate, ipopt.iterate, atol=1e-4)
    assert rti.cost(params) == pytest.approx(ipopt.last_stats.cost, rel=1e-9)
    us = ocp.unpack(rti.iterate)[1]
    assert np.any(np.isclose(us, ocp.u_lower, atol=1e-6) | np.isclose(us, ocp.u_upper, atol=1e-6))
    # one step from the stand-off pose (no bound active): the two QP paths agree
    x1 = ideal_state(POINT, NORMAL, cfg.d_ref)
    x1[0:3] += [0.1, -0.1, 0.05]
    p1 = vtnmpc_parameters(x1, POINT, NORMAL[:2], np.array([0.3, 0.0, 0.0]))
    steps = []
    for qs in ("hpipm", "casadi"):
        s = RTISolver(ocp, W, WN, RTIOptions(qp_solver=qs, **base))
        s.initialize(x1)
        s.prepare(p1)
        steps.append((s.feedback(x1), s.iterate, s.last_stats))
    (u_d, w_d, st_d), (u_c, w_c, st_c) = steps
    assert st_d.status == st_c.status == "SUCCESS" and not st_d.fallback
    np.testing.assert_allclose(u_d, u_c, atol=1e-6)
    np.testing.assert_allclose(w_d, w_c, atol=1e-6)
    assert st_d.cost == pytest.approx(st_c.cost, rel=1e-12)


@pytest.mark.slow
@pytest.mark.unit
def test_direct_hpipm_with_active_state_bounds_and_its_fallback(cache_dir):
    """State bounds go to HPIPM as bounds of the states that have them (here the rate, active in
    the solution), path constraints as its general constraints (active too): both converge to
    IPOPT's solution."""
    full = pendulum_ocp(horizon=40)
    ocp = dataclasses.replace(full, path_constraint=None, h_lower=None, h_upper=None)
    x0, p = np.array([0.0, 0.0]), np.array([3.0])
    opts = RTIOptions(cache_dir=cache_dir, qp_mode="balance", qp_tol=1e-8, qp_iter_max=100, qp_solver="hpipm")
    rti, ipopt = converge_sqp_and_ipopt(ocp, PEND_W, PEND_WN, opts, x0, p, max_iter=200, qp_solver="hpipm")
    xs, _ = ocp.unpack(rti.iterate)
    assert np.isclose(xs[:, 1].max(), 0.6, atol=1e-6)
    np.testing.assert_allclose(rti.iterate, ipopt.iterate, atol=2e-6)
    # With the path constraint (active in the solution), through HPIPM's general constraints.
    con, ref = converge_sqp_and_ipopt(full, PEND_W, PEND_WN, opts, x0, p, max_iter=200, qp_solver="hpipm")
    xs, us = full.unpack(con.iterate)
    assert np.isclose((xs[:-1, 0] + 0.2 * us[:, 0]).max(), 1.0, atol=1e-6)
    np.testing.assert_allclose(con.iterate, ref.iterate, atol=1e-6)
    with pytest.raises(ValueError, match="qp_solver"):
        RTIOptions(qp_solver="qpoases")


def test_qp_mu0_reaches_both_qp_paths(cache_dir):
    """qp_mu0 (HPIPM's initial barrier parameter) is passed to the plugin and the direct call:
    with acados' 1.0 the direct VT-NMPC step takes no more interior-point iterations than with the
    speed_abs preset's 10 and lands much closer to a tight solve (rate bounds active)."""
    cfg = VTNMPCConfig()
    ocp, W, WN, x0, params = hard_vtnmpc_problem(cfg)

    def step(**opts):
        s = RTISolver(ocp, W, WN, RTIOptions(cache_dir=cache_dir, **opts))
        s.initialize(x0)
        s.prepare(params)
        s.feedback(x0)
        assert s.last_stats.status == "SUCCESS"
        return s.iterate, s.last_stats.qp_iterations

    tight, _ = step(qp_mode="robust", qp_tol=1e-10, qp_iter_max=200, qp_solver="hpipm")
    w10, it10 = step(qp_mode="speed_abs", qp_solver="hpipm")
    w1, it1 = step(qp_mode="speed_abs", qp_solver="hpipm", qp_mu0=1.0)
    assert it1 <= it10
    assert np.max(np.abs(w1 - tight)) < 0.2 * np.max(np.abs(w10 - tight))
    # the plugin takes it too (its +-1e8 state bounds make the iteration count differ)
    p10, _ = step(qp_mode="speed_abs", qp_solver="casadi")
    p1, _ = step(qp_mode="speed_abs", qp_solver="casadi", qp_mu0=1.0)
    assert np.max(np.abs(p1 - p10)) > 1e-6
    with pytest.raises(ValueError, match="qp_mu0"):
        RTIOptions(qp_mu0=0.0)


@pytest.mark.slow
@pytest.mark.unit
def test_tangential_predictor_is_the_qp_solution_while_the_active_set_holds(cache_dir):
    """With tangential_predictor the preparation solves the QP for the plan's x_0 and its gains;
    the feedback for a nearby measurement is then the full QP's solution (no bound active here:
    to 1e-8), flagged ``predicted``; when the active set changes (the hard start, measured far
    from the plan) the feedback solves the full QP instead, and gives its solution."""
    fast = dict(cache_dir=cache_dir, qp_mode="speed_abs", qp_solver="hpipm", qp_mu0=1.0)
    cfg = VTNMPCConfig()
    ocp, W, WN, x_hard, p_hard = hard_vtnmpc_problem(cfg)
    x0 = ideal_state(POINT, NORMAL, cfg.d_ref)
    x0[0:3] += [0.3, -0.2, 0.1]
    p0 = vtnmpc_parameters(x0, POINT, NORMAL[:2], np.array([0.5, 0.0, 0.0]))
    rng = np.random.default_rng(1)

    def both(x_plan, params, x_meas):
        out = []
        for pred in (True, False):
            s = RTISolver(ocp, W, WN, RTIOptions(tangential_predictor=pred, **fast))
            s.initialize(x_plan)
            s.prepare(params)
            s.feedback(x_meas)
            out.append((s.iterate, s.last_stats))
        return out

    for _ in range(3):
        x_meas = x0 + 0.02 * rng.standard_normal(10) * np.r_[np.ones(6), 0.1 * np.ones(4)]
        (w_p, st_p), (w_f, st_f) = both(x0, p0, x_meas)
        assert st_p.predicted and not st_f.predicted and st_p.status == "SUCCESS"
        np.testing.assert_allclose(w_p, w_f, atol=1e-8)
    changed = 0
    for _ in range(4):
        x_far = x_hard + 0.1 * rng.standard_normal(10) * np.r_[np.ones(6), 0.1 * np.ones(4)]
        (w_p, st_p), (w_f, _) = both(x_hard, p_hard, x_far)
        if not st_p.predicted:
            changed += 1
            np.testing.assert_allclose(w_p, w_f, atol=1e-12)   # the same full QP
    assert changed >= 1   # the active set did change for some of these measurements
    with pytest.raises(ValueError, match="tangential_predictor"):
        RTIOptions(tangential_predictor=True)   # needs qp_solver='hpipm'


@pytest.mark.parametrize("compiled", [True, False])
def test_rollout_is_the_ocp_stepped_stage_by_stage(cache_dir, compiled):
    """The compiled rollout (the safety filter's pass-through check) against the OCP's own
    dynamics called stage by stage, with stage-wise parameters, and its margins against the path
    constraint's nearer bound (h in [-10, 1]: the upper side binds here)."""
    from controllers.rti.rollout import Rollout
    ocp = pendulum_ocp(horizon=12)
    roll = Rollout(ocp, compiled=compiled, cache_dir=cache_dir)
    rng = np.random.default_rng(3)
    x0 = np.array([0.4, -0.2])
    U = rng.uniform(-0.8, 0.8, (12, 1))
    P = rng.uniform(-1.0, 1.0, (13, 1))
    X, margin = roll(x0, U, P)
    x = x0
    for k in range(12):
        np.testing.assert_allclose(X[k], x, rtol=0, atol=1e-12)
        h = float(ocp.path_constraint(x, U[k], P[k]))
        assert margin[k, 0] == pytest.approx(min(h + 10.0, 1.0 - h), abs=1e-12)
        x = np.asarray(ocp.dynamics(x, U[k], P[k])).ravel()
    np.testing.assert_allclose(X[12], x, rtol=0, atol=1e-12)
    # a violated bound is a negative margin: push the angle past h_upper = 1
    X, margin = roll(np.array([1.5, 0.0]), np.full((12, 1), 0.8), P)
    assert margin[0, 0] == pytest.approx(1.0 - (1.5 + 0.16), abs=1e-12) and margin[0, 0] < 0
