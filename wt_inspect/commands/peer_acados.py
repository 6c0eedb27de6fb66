"""The VT-NMPC control step in acados - run by *acados'* Python, not by this project's.

``wt-inspect bench solver --acados-python PATH`` runs this file with the interpreter of a virtual
environment that has acados (the ``comma-deps-acados`` wheel, which brings its own CasADi, so it
must not share this project's environment). It imports nothing from this project: the problem
arrives as numbers in a JSON request and the formulas are written out here a second time, from the
definitions in :mod:`controllers.vtnmpc` and :mod:`wt_inspect_env.physics.dynamics`:

* model: p' = R(q) v_B, v_B' = -w x v_B + R(q)^T (g_W + a_ext) + (0, 0, T/m), q' = q (x) (w, 0) / 2
  with x = [p, v_B, q_xyzw], u = [w, T]; one classic RK4 step per stage (acados ERK, 4 stages);
* residuals: heading, horizontal distance, ROI and orthogonality of the inspection point, the
  body velocity against the point's, the tilt (qx, qy) against the level attitude for a_ext, the
  inputs against hover; terminal: velocity and tilt;
* parameters per stage: [point (3), n_x, n_y, point velocity in the body frame (3), a_ext (3)];
* input bounds only, SQP-RTI with a Gauss-Newton Hessian, HPIPM without condensing
  (``PARTIAL_CONDENSING_HPIPM`` with cond_N = N), cold-started, the request's mode, tolerance and
  iteration limit.

acados prices stage k with dt_k * 1/2 |y|^2_W; the project has no dt, so W / dt is passed: the
two objectives are then equal term by term (the ``probe`` request checks it).

One C function compiled into the solver (written by :func:`_write_update`) does the per-step
work that would otherwise be ~100 calls from Python: shift the plan by one stage, write the
parameters of every stage and pin x_0 to the measurement.

Usage: ``python peer_acados.py REQUEST.json RESULT.json``. Requests (``"mode"``):

* ``build`` - generate and compile the solver into ``build_dir`` (reused when present);
* ``replay`` - fly the recorded observations through the acados step (observation to normalised
  action, as a policy's ``act``), timing every step; returns the times [ms] and the actions;
* ``probe`` - for a given plan, parameters and x_0: the cost of the plan (the residuals and
  weights given to acados, evaluated here: this acados version's ``get_cost`` leaves out the
  terminal term) and the plan after one RTI step (the project's tests compare both with its
  solver).
"""
from __future__ import annotations

import ctypes
import json
import os
import sys
import time

import numpy as np

MODEL = "wtvt"
NX, NU, NP = 10, 4, 11

_HEADER = """#include "acados_solver_{m}.h"
int custom_update_init_function({m}_solver_capsule *capsule);
int custom_update_function({m}_solver_capsule *capsule, double *data, int n);
int custom_update_terminate_function({m}_solver_capsule *capsule);
"""

_SOURCE = """#include "{m}_update.h"
#include "acados_c/ocp_nlp_interface.h"

/* data = [shift (0/1), x_0 ({nx}), parameters ({np})] */
int custom_update_init_function({m}_solver_capsule *capsule) {{ (void)capsule; return 0; }}
int custom_update_terminate_function({m}_solver_capsule *capsule) {{ (void)capsule; return 0; }}

int custom_update_function({m}_solver_capsule *capsule, double *data, int n)
{{
    ocp_nlp_config *cfg = capsule->nlp_config;
    ocp_nlp_dims *dims = capsule->nlp_dims;
    ocp_nlp_out *out = capsule->nlp_out;
    double tmp[{nx}];
    int k;
    if (n != 1 + {nx} + {np}) return 1;
    if (data[0] != 0.0) {{
        /* stage k takes stage k+1's plan; x_N and u_(N-1) stay as they were */
        for (k = 1; k <= {N}; k++) {{
            ocp_nlp_out_get(cfg, dims, out, k, "x", tmp);
            ocp_nlp_out_set(cfg, dims, out, k - 1, "x", tmp);
            if (k < {N}) {{
                ocp_nlp_out_get(cfg, dims, out, k, "u", tmp);
                ocp_nlp_out_set(cfg, dims, out, k - 1, "u", tmp);
            }}
        }}
    }}
    for (k = 0; k <= {N}; k++)
        {m}_acados_update_params(capsule, k, data + 1 + {nx}, {np});
    ocp_nlp_constraints_model_set(cfg, dims, capsule->nlp_in, 0, "lbx", data + 1);
    ocp_nlp_constraints_model_set(cfg, dims, capsule->nlp_in, 0, "ubx", data + 1);
    return 0;
}}
"""


def _import_acados():
    """acados' template package, with the paths and libraries the wheel leaves to the caller."""
    import acados
    for var, attr in (("ACADOS_SOURCE_DIR", "DIR"), ("ACADOS_PYTHON_INTERFACE_PATH", "TEMPLATE_DIR"),
                      ("TERA_PATH", "TERA_PATH")):
        if hasattr(acados, attr):
            os.environ.setdefault(var, str(getattr(acados, attr)))
    lib_dir = getattr(acados, "LIB_DIR", None)
    if lib_dir:   # the wheel's libraries carry no rpath: load them globally before the solver
        for name in sorted(os.listdir(lib_dir)):
            if name.startswith(("libblasfeo", "libhpipm", "libqpOASES")) and ".so" in name:
                ctypes.CDLL(os.path.join(lib_dir, name), mode=ctypes.RTLD_GLOBAL)
    import casadi
    from acados.acados_template import AcadosModel, AcadosOcp, AcadosOcpSolver
    return casadi, AcadosModel, AcadosOcp, AcadosOcpSolver


# ---------------------------------------------------------------------------------------------
# the problem, written out again
# ---------------------------------------------------------------------------------------------

def _rot(ca, q):
    """Rotation matrix (body to world) of a unit quaternion [x, y, z, w]."""
    x, y, z, w = q[0], q[1], q[2], q[3]
    return ca.blockcat([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _rot_np(q):
    x, y, z, w = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _xdot(ca, spec, x, u, a_ext):
    q, vb, w, thrust = x[6:10], x[3:6], u[0:3], u[3]
    R = _rot(ca, q)
    g = ca.vertcat(0, 0, -spec["gravity"]) + a_ext
    # q (x) (w, 0) for [x, y, z, w] quaternions
    qdot = 0.5 * ca.vertcat(q[3] * w[0] + q[1] * w[2] - q[2] * w[1],
                            q[3] * w[1] + q[2] * w[0] - q[0] * w[2],
                            q[3] * w[2] + q[0] * w[1] - q[1] * w[0],
                            -(q[0] * w[0] + q[1] * w[1] + q[2] * w[2]))
    return ca.vertcat(R @ vb, ca.cross(vb, w) + R.T @ g + ca.vertcat(0, 0, thrust / spec["mass"]), qdot)


def _tilt(ca, spec, q, a_ext):
    """(qx, qy) minus those of the level attitude for the apparent gravity g - a_ext, at q's yaw."""
    zd = ca.vertcat(-a_ext[0], -a_ext[1], spec["gravity"] - a_ext[2])
    zd = zd / ca.norm_2(zd)
    t = ca.vertcat(-zd[1], zd[0], 1 + zd[2])
    t = t / ca.norm_2(t)
    return ca.vertcat(q[0] - (t[0] * q[3] + t[1] * q[2]) / t[2], q[1] - (t[1] * q[3] - t[0] * q[2]) / t[2])


def _residuals(ca, spec, x, u, p):
    eps, d_ref = spec["eps"], spec["d_ref"]
    a = p[0:3] - x[0:3]
    nx_, ny_ = p[3], p[4]
    dist = ca.sqrt(a[0] * a[0] + a[1] * a[1] + eps)
    R = _rot(ca, x[6:10])
    heading = (R[0, 0] * a[0] + R[1, 0] * a[1]) / dist
    along = a[0] * nx_ + a[1] * ny_
    perp = a - along * ca.vertcat(nx_, ny_, 0)
    orth = ca.sqrt(perp[0] ** 2 + perp[1] ** 2 + perp[2] ** 2 + eps)
    xstar = ca.vertcat(x[3:6] - p[5:8], _tilt(ca, spec, x[6:10], p[8:11]))
    stage = ca.vertcat(heading - 1.0, dist - d_ref, along + d_ref, orth, xstar, u - ca.DM(spec["hover"]))
    return stage, xstar


def _check_spec(spec):
    for key in ("horizon", "dt", "mass", "gravity", "d_ref", "eps", "stage_weights", "terminal_weights",
                "u_lower", "u_upper", "hover", "qp_mode", "qp_tol", "qp_iter_max"):
        if key not in spec:
            raise ValueError(f"OCP spec has no {key!r}")
    if len(spec["stage_weights"]) != 13 or len(spec["terminal_weights"]) != 5:
        raise ValueError("this peer knows the paper's VT-NMPC residuals only (13 stage, 5 terminal)")


def build(spec, build_dir):
    """The acados solver for ``spec`` in ``build_dir`` (compiled once, then loaded)."""
    _check_spec(spec)
    ca, AcadosModel, AcadosOcp, AcadosOcpSolver = _import_acados()
    os.makedirs(build_dir, exist_ok=True)
    for name, text in ((f"{MODEL}_update.h", _HEADER), (f"{MODEL}_update.c", _SOURCE)):
        with open(os.path.join(build_dir, name), "w") as f:
            f.write(text.format(m=MODEL, nx=NX, np=NP, N=int(spec["horizon"])))
    N, dt = int(spec["horizon"]), float(spec["dt"])
    x, u, p = ca.SX.sym("x", NX), ca.SX.sym("u", NU), ca.SX.sym("p", NP)
    model = AcadosModel()
    model.name = MODEL
    model.x, model.u, model.p = x, u, p
    model.f_expl_expr = _xdot(ca, spec, x, u, p[8:11])
    model.cost_y_expr, model.cost_y_expr_e = _residuals(ca, spec, x, u, p)

    ocp = AcadosOcp()
    ocp.model = model
    ocp.dims.N = N
    ocp.parameter_values = np.zeros(NP)
    ocp.cost.cost_type = ocp.cost.cost_type_e = "NONLINEAR_LS"
    ocp.cost.W = np.diag(np.asarray(spec["stage_weights"], float)) / dt
    ocp.cost.W_e = np.diag(np.asarray(spec["terminal_weights"], float))
    ocp.cost.yref, ocp.cost.yref_e = np.zeros(13), np.zeros(5)
    ocp.constraints.idxbu = np.arange(NU)
    ocp.constraints.lbu = np.asarray(spec["u_lower"], float)
    ocp.constraints.ubu = np.asarray(spec["u_upper"], float)
    ocp.constraints.x0 = np.r_[np.zeros(9), 1.0]

    opt = ocp.solver_options
    opt.tf = N * dt
    opt.nlp_solver_type = "SQP_RTI"
    opt.hessian_approx = "GAUSS_NEWTON"
    opt.integrator_type = "ERK"
    opt.sim_method_num_stages, opt.sim_method_num_steps = 4, 1
    opt.qp_solver = "PARTIAL_CONDENSING_HPIPM"
    opt.qp_solver_cond_N = N
    opt.hpipm_mode = str(spec["qp_mode"]).upper()
    opt.qp_solver_iter_max = int(spec["qp_iter_max"])
    opt.qp_tol = float(spec["qp_tol"])
    opt.qp_solver_warm_start = 0
    opt.print_level = 0
    opt.ext_fun_compile_flags = "-O2"
    opt.custom_update_filename = f"{MODEL}_update.c"
    opt.custom_update_header_filename = f"{MODEL}_update.h"
    ocp.code_export_directory = os.path.join(build_dir, "export")
    json_file = os.path.join(build_dir, "ocp.json")
    lib = os.path.join(ocp.code_export_directory, f"libacados_ocp_solver_{MODEL}.so")
    here = os.getcwd()
    os.chdir(build_dir)   # the generator copies the update files by their relative names
    try:
        if os.path.exists(lib) and os.path.exists(json_file):
            return AcadosOcpSolver(ocp, json_file=json_file, build=False, generate=False, verbose=False)
        return AcadosOcpSolver(ocp, json_file=json_file, verbose=False)
    finally:
        os.chdir(here)


class Step:
    """The acados control step with its C entry points bound once (the stock ``set``/``get``
    look every function up again on every call)."""

    def __init__(self, solver, spec):
        lib = solver.shared_lib
        self.solver, self.capsule = solver, ctypes.c_void_p(solver.capsule)
        self._update = getattr(lib, f"{MODEL}_acados_custom_update")
        self._update.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_double), ctypes.c_int]
        self._update.restype = ctypes.c_int
        self._solve = getattr(lib, f"{MODEL}_acados_solve")
        self._solve.argtypes, self._solve.restype = [ctypes.c_void_p], ctypes.c_int
        self._get_out = lib.ocp_nlp_out_get
        self._get_out.argtypes = [ctypes.c_void_p] * 3 + [ctypes.c_int, ctypes.c_char_p, ctypes.c_void_p]
        self._ptrs = (ctypes.c_void_p(solver.nlp_config), ctypes.c_void_p(solver.nlp_dims),
                      ctypes.c_void_p(solver.nlp_out))
        self.data = np.zeros(1 + NX + NP)
        self._data = self.data.ctypes.data_as(ctypes.POINTER(ctypes.c_double))
        self.u0 = np.zeros(NU)
        self._u0 = ctypes.c_void_p(self.u0.ctypes.data)
        self.lo, self.hi = np.asarray(spec["u_lower"], float), np.asarray(spec["u_upper"], float)
        self.hover = np.asarray(spec["hover"], float)
        self.N = int(spec["horizon"])
        self.reset()

    def reset(self):
        """Forget the previous episode (the next step starts cold)."""
        self.started, self.last_q, self.nxy = False, None, None

    def set_plan(self, xs, us):
        """Put the plan (xs, us) into the solver as its iterate."""
        for k in range(self.N + 1):
            self.solver.set(k, "x", np.ascontiguousarray(xs[k], float))
            if k < self.N:
                self.solver.set(k, "u", np.ascontiguousarray(us[k], float))

    def rti(self, shift, x0, params):
        """One RTI step from ``x0`` with ``params`` (``shift``: shift the plan first); returns acados' status."""
        d = self.data
        d[0] = 1.0 if shift else 0.0
        d[1:1 + NX] = x0
        d[1 + NX:] = params
        if self._update(self.capsule, self._data, d.size):
            raise RuntimeError("custom update refused its data")
        status = self._solve(self.capsule)
        self._get_out(*self._ptrs, 0, b"u", self._u0)
        return status

    def act(self, obs):
        """Normalised action for one observation (what a policy's ``act`` does)."""
        q = np.asarray(obs["quaternion"], float)
        q = q / np.linalg.norm(q)
        if self.last_q is not None and q @ self.last_q < 0.0:
            q = -q
        self.last_q = q
        x = np.concatenate([np.asarray(obs["position"], float), np.asarray(obs["velocity_body"], float), q])
        n = np.asarray(obs["normal"], float)[:2]
        norm = float(np.hypot(n[0], n[1]))
        if norm >= 1e-6:
            self.nxy = n / norm
        elif self.nxy is None:
            self.nxy = np.array([1.0, 0.0])
        v_body = _rot_np(q).T @ np.asarray(obs["point_velocity"], float)
        params = np.concatenate([np.asarray(obs["point"], float), self.nxy, v_body, np.zeros(3)])
        if not self.started:
            self.set_plan(np.tile(x, (self.N + 1, 1)), np.tile(self.hover, (self.N, 1)))
        status = self.rti(self.started, x, params)
        self.started = True
        u = np.clip(self.u0, self.lo, self.hi) if status in (0, 2) else self.hover
        return np.clip(2.0 * (u - self.lo) / (self.hi - self.lo) - 1.0, -1.0, 1.0).astype(np.float32), status


def replay(solver, spec, observations):
    """Step the acados solver through the recorded observations; per step its action, status, time
    [ms] and QP iterations."""
    step = Step(solver, spec)
    keys = list(observations)
    n = len(observations[keys[0]])
    obs = [{k: np.asarray(observations[k][i], dtype=np.float32) for k in keys} for i in range(n)]
    times, actions, statuses, qp_iter, qp_ms = [], [], [], [], []
    for o in obs:
        t0 = time.perf_counter()
        a, status = step.act(o)
        times.append((time.perf_counter() - t0) * 1e3)
        actions.append(a.tolist())
        statuses.append(int(status))
        qp_iter.append(int(np.ravel(solver.get_stats("qp_iter"))[-1]))   # (outside the timed step)
        qp_ms.append(float(np.ravel(solver.get_stats("time_qp"))[-1]) * 1e3)
    return {"step_ms": times, "actions": actions, "status": statuses, "qp_iterations": qp_iter, "qp_ms": qp_ms}


def probe(solver, spec, xs, us, params, x0):
    """Cost of the plan (xs, us) and the plan after one RTI step from it for x_0."""
    step = Step(solver, spec)
    step.set_plan(xs, us)
    ca = _import_acados()[0]
    x, u, p = ca.SX.sym("x", NX), ca.SX.sym("u", NU), ca.SX.sym("p", NP)
    stage = ca.Function("r", [x, u, p], list(_residuals(ca, spec, x, u, p)))
    W, WN = np.asarray(spec["stage_weights"], float), np.asarray(spec["terminal_weights"], float)
    cost = 0.0
    for k in range(step.N):   # the residuals and weights handed to acados (W / dt times its dt)
        r = np.asarray(stage(xs[k], us[k], params)[0]).ravel()
        cost += 0.5 * float(r @ (W * r))
    terminal = np.asarray(stage(xs[step.N], us[-1], params)[1]).ravel()
    cost += 0.5 * float(terminal @ (WN * terminal))
    status = step.rti(False, np.asarray(x0, float), np.asarray(params, float))
    return {"cost": cost, "status": int(status),
            "xs": [solver.get(k, "x").tolist() for k in range(step.N + 1)],
            "us": [solver.get(k, "u").tolist() for k in range(step.N)]}


def main(argv):
    """Answer the JSON request in the file ``argv[1]`` (build, replay or probe) with one JSON object."""
    with open(argv[1]) as f:
        req = json.load(f)
    t0 = time.perf_counter()
    solver = build(req["ocp"], req["build_dir"])
    out = {"setup_s": time.perf_counter() - t0}
    if req["mode"] == "replay":
        out.update(replay(solver, req["ocp"], req["observations"]))
    elif req["mode"] == "probe":
        out.update(probe(solver, req["ocp"], req["xs"], req["us"], req["params"], req["x0"]))
    elif req["mode"] != "build":
        raise ValueError(f"unknown mode {req['mode']!r}")
    with open(argv[2], "w") as f:
        json.dump(out, f)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
