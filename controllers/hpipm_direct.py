"""HPIPM called directly (not through CasADi's ``conic`` plugin) for the RTI core's QPs.

Why: measured against acados on the same VT-NMPC OCP (issue 12), the feedback QP through CasADi
3.8's HPIPM plugin cost 0.5-0.8 ms against acados' 0.10-0.18 ms. Reading the plugin, it allocates
HPIPM's dimensions, QP, solution, argument and workspace memory on every call, copies the whole QP
into them on every call, and bounds *every* state at +-1e8 (30 x 10 x 2 extra inequality
constraints, each with its own multiplier and slack in the interior-point iteration). This module
does what acados does instead:

* all HPIPM memory is allocated once, in :func:`HpipmQP` (a small C shim, compiled once with the
  machine's ``gcc`` against the ``libhpipm`` that ships inside the ``casadi`` wheel, cached like the
  generated QP data - see :mod:`controllers.codegen`);
* only finite bounds are passed (inputs; states only where the OCP bounds them);
* x_0 is eliminated (HPIPM's stage 0 has no state): the measured dx_0 enters as
  b_0 = A_0 dx_0 + b_0 and r_0 = r_0 + S_0 dx_0 - two small products in the *feedback* call, so the
  QP data of the preparation phase are loaded into HPIPM before the measurement arrives and the
  feedback is those products plus the interior-point iterations (acados' ``rti_phase`` split);
* the stage blocks come from a QP-data function with dense per-stage outputs (column-major, as
  HPIPM's setters take them), so nothing is converted on the hot path.

The shim declares the few HPIPM functions it calls itself (the wheel has no headers); every one is
part of HPIPM's stable setter/getter API. Path constraints are not supported here (the RTI solver
keeps the CasADi path for OCPs that have them).
"""
from __future__ import annotations

import ctypes
import hashlib
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import casadi as ca
import numpy as np

from .codegen import default_cache_dir

HPIPM_MODES = {"speed_abs": 0, "speed": 1, "balance": 2, "robust": 3}

_SHIM = r"""
#include <stdlib.h>
#include <string.h>

/* HPIPM (libhpipm of the casadi wheel): opaque structs, sizes from its *_strsize/_memsize. */
typedef unsigned long hsize;
extern hsize d_ocp_qp_dim_strsize(void);
extern hsize d_ocp_qp_dim_memsize(int N);
extern void d_ocp_qp_dim_create(int N, void *dim, void *mem);
extern void d_ocp_qp_dim_set_nx(int stage, int value, void *dim);
extern void d_ocp_qp_dim_set_nu(int stage, int value, void *dim);
extern void d_ocp_qp_dim_set_nbx(int stage, int value, void *dim);
extern void d_ocp_qp_dim_set_nbu(int stage, int value, void *dim);
extern void d_ocp_qp_dim_set_ng(int stage, int value, void *dim);
extern void d_ocp_qp_dim_set_ns(int stage, int value, void *dim);
extern hsize d_ocp_qp_strsize(void);
extern hsize d_ocp_qp_memsize(void *dim);
extern void d_ocp_qp_create(void *dim, void *qp, void *mem);
extern void d_ocp_qp_set_A(int stage, double *v, void *qp);
extern void d_ocp_qp_set_B(int stage, double *v, void *qp);
extern void d_ocp_qp_set_b(int stage, double *v, void *qp);
extern void d_ocp_qp_set_Q(int stage, double *v, void *qp);
extern void d_ocp_qp_set_S(int stage, double *v, void *qp);
extern void d_ocp_qp_set_R(int stage, double *v, void *qp);
extern void d_ocp_qp_set_q(int stage, double *v, void *qp);
extern void d_ocp_qp_set_r(int stage, double *v, void *qp);
extern void d_ocp_qp_set_idxbx(int stage, int *v, void *qp);
extern void d_ocp_qp_set_lbx(int stage, double *v, void *qp);
extern void d_ocp_qp_set_ubx(int stage, double *v, void *qp);
extern void d_ocp_qp_set_idxbu(int stage, int *v, void *qp);
extern void d_ocp_qp_set_lbu(int stage, double *v, void *qp);
extern void d_ocp_qp_set_ubu(int stage, double *v, void *qp);
extern hsize d_ocp_qp_sol_strsize(void);
extern hsize d_ocp_qp_sol_memsize(void *dim);
extern void d_ocp_qp_sol_create(void *dim, void *sol, void *mem);
extern void d_ocp_qp_sol_get_u(int stage, void *sol, double *v);
extern void d_ocp_qp_sol_get_x(int stage, void *sol, double *v);
extern hsize d_ocp_qp_ipm_arg_strsize(void);
extern hsize d_ocp_qp_ipm_arg_memsize(void *dim);
extern void d_ocp_qp_ipm_arg_create(void *dim, void *arg, void *mem);
extern void d_ocp_qp_ipm_arg_set_default(int mode, void *arg);
extern void d_ocp_qp_ipm_arg_set_iter_max(int *v, void *arg);
extern void d_ocp_qp_ipm_arg_set_mu0(double *v, void *arg);
extern void d_ocp_qp_ipm_arg_set_tol_stat(double *v, void *arg);
extern void d_ocp_qp_ipm_arg_set_tol_eq(double *v, void *arg);
extern void d_ocp_qp_ipm_arg_set_tol_ineq(double *v, void *arg);
extern void d_ocp_qp_ipm_arg_set_tol_comp(double *v, void *arg);
extern hsize d_ocp_qp_ipm_ws_strsize(void);
extern hsize d_ocp_qp_ipm_ws_memsize(void *dim, void *arg);
extern void d_ocp_qp_ipm_ws_create(void *dim, void *arg, void *ws, void *mem);
extern void d_ocp_qp_ipm_solve(void *qp, void *sol, void *arg, void *ws);
extern void d_ocp_qp_ipm_get_status(void *ws, int *v);
extern void d_ocp_qp_ipm_get_iter(void *ws, int *v);

typedef struct {
    int N, nx, nu, nbx;
    void *dim, *qp, *sol, *arg, *ws;
    void *mem[5];
    int *idxbx, *idxbu;
    double *A0, *S0, *b0, *r0, *tmp_b, *tmp_r;
} vtqp;

static void *zalloc(hsize n) { void *p = calloc(1, n ? n : 1); return p; }

void vtqp_free(vtqp *h) {
    int i;
    if (!h) return;
    for (i = 0; i < 5; ++i) free(h->mem[i]);
    free(h->dim); free(h->qp); free(h->sol); free(h->arg); free(h->ws);
    free(h->idxbx); free(h->idxbu);
    free(h->A0); free(h->S0); free(h->b0); free(h->r0); free(h->tmp_b); free(h->tmp_r);
    free(h);
}

/* Stage 0 has no state (x_0 eliminated), stages 1..N have nx states; nu inputs bounded at every
   stage 0..N-1; nbx states bounded at stages 1..N (indices idxbx). mu0 <= 0 keeps the preset's. */
vtqp *vtqp_create(int N, int nx, int nu, int nbx, const int *idxbx, int mode, int iter_max,
                  double tol, double mu0) {
    int k;
    vtqp *h = (vtqp *) zalloc(sizeof(vtqp));
    h->N = N; h->nx = nx; h->nu = nu; h->nbx = nbx;
    h->dim = zalloc(d_ocp_qp_dim_strsize());
    h->mem[0] = zalloc(d_ocp_qp_dim_memsize(N));
    d_ocp_qp_dim_create(N, h->dim, h->mem[0]);
    for (k = 0; k <= N; ++k) {
        d_ocp_qp_dim_set_nx(k, k == 0 ? 0 : nx, h->dim);
        d_ocp_qp_dim_set_nu(k, k == N ? 0 : nu, h->dim);
        d_ocp_qp_dim_set_nbx(k, k == 0 ? 0 : nbx, h->dim);
        d_ocp_qp_dim_set_nbu(k, k == N ? 0 : nu, h->dim);
        d_ocp_qp_dim_set_ng(k, 0, h->dim);
        d_ocp_qp_dim_set_ns(k, 0, h->dim);
    }
    h->qp = zalloc(d_ocp_qp_strsize());
    h->mem[1] = zalloc(d_ocp_qp_memsize(h->dim));
    d_ocp_qp_create(h->dim, h->qp, h->mem[1]);
    h->sol = zalloc(d_ocp_qp_sol_strsize());
    h->mem[2] = zalloc(d_ocp_qp_sol_memsize(h->dim));
    d_ocp_qp_sol_create(h->dim, h->sol, h->mem[2]);
    h->arg = zalloc(d_ocp_qp_ipm_arg_strsize());
    h->mem[3] = zalloc(d_ocp_qp_ipm_arg_memsize(h->dim));
    d_ocp_qp_ipm_arg_create(h->dim, h->arg, h->mem[3]);
    d_ocp_qp_ipm_arg_set_default(mode, h->arg);
    d_ocp_qp_ipm_arg_set_iter_max(&iter_max, h->arg);
    d_ocp_qp_ipm_arg_set_tol_stat(&tol, h->arg);
    d_ocp_qp_ipm_arg_set_tol_eq(&tol, h->arg);
    d_ocp_qp_ipm_arg_set_tol_ineq(&tol, h->arg);
    d_ocp_qp_ipm_arg_set_tol_comp(&tol, h->arg);
    if (mu0 > 0) d_ocp_qp_ipm_arg_set_mu0(&mu0, h->arg);   /* else the mode's preset */
    h->ws = zalloc(d_ocp_qp_ipm_ws_strsize());
    h->mem[4] = zalloc(d_ocp_qp_ipm_ws_memsize(h->dim, h->arg));
    d_ocp_qp_ipm_ws_create(h->dim, h->arg, h->ws, h->mem[4]);
    h->idxbx = (int *) zalloc(sizeof(int) * (nbx > 0 ? nbx : 1));
    for (k = 0; k < nbx; ++k) h->idxbx[k] = idxbx[k];
    h->idxbu = (int *) zalloc(sizeof(int) * nu);
    for (k = 0; k < nu; ++k) h->idxbu[k] = k;
    for (k = 0; k < N; ++k) d_ocp_qp_set_idxbu(k, h->idxbu, h->qp);
    for (k = 1; k <= N; ++k) if (nbx) d_ocp_qp_set_idxbx(k, h->idxbx, h->qp);
    h->A0 = (double *) zalloc(sizeof(double) * nx * nx);
    h->S0 = (double *) zalloc(sizeof(double) * nu * nx);
    h->b0 = (double *) zalloc(sizeof(double) * nx);
    h->r0 = (double *) zalloc(sizeof(double) * nu);
    h->tmp_b = (double *) zalloc(sizeof(double) * nx);
    h->tmp_r = (double *) zalloc(sizeof(double) * nu);
    return h;
}

/* Preparation: load the linearisation (stage blocks column-major, stage k at k * block size).
   Qs: nx x nx for stages 0..N; Ss: nu x nx, Rs: nu x nu, rs: nu, As: nx x nx, Bs: nx x nu,
   bs: nx for stages 0..N-1; qs: nx for 0..N; lbu/ubu: nu per stage 0..N-1; lbx/ubx: nbx per
   stage 1..N. Stage 0's state blocks are kept for the feedback. */
void vtqp_load(vtqp *h, double *Qs, double *Ss, double *Rs, double *qs, double *rs, double *As,
               double *Bs, double *bs, double *lbu, double *ubu, double *lbx, double *ubx) {
    int k, N = h->N, nx = h->nx, nu = h->nu, nbx = h->nbx;
    for (k = 0; k < N; ++k) {
        d_ocp_qp_set_R(k, Rs + k * nu * nu, h->qp);
        d_ocp_qp_set_lbu(k, lbu + k * nu, h->qp);
        d_ocp_qp_set_ubu(k, ubu + k * nu, h->qp);
        if (k > 0) {
            d_ocp_qp_set_Q(k, Qs + k * nx * nx, h->qp);
            d_ocp_qp_set_S(k, Ss + k * nu * nx, h->qp);
            d_ocp_qp_set_q(k, qs + k * nx, h->qp);
            d_ocp_qp_set_r(k, rs + k * nu, h->qp);
            d_ocp_qp_set_A(k, As + k * nx * nx, h->qp);
        }
        d_ocp_qp_set_B(k, Bs + k * nx * nu, h->qp);
        if (k > 0) d_ocp_qp_set_b(k, bs + k * nx, h->qp);
    }
    d_ocp_qp_set_Q(N, Qs + N * nx * nx, h->qp);
    d_ocp_qp_set_q(N, qs + N * nx, h->qp);
    for (k = 1; k <= N; ++k) if (nbx) {
        d_ocp_qp_set_lbx(k, lbx + (k - 1) * nbx, h->qp);
        d_ocp_qp_set_ubx(k, ubx + (k - 1) * nbx, h->qp);
    }
    memcpy(h->A0, As, sizeof(double) * nx * nx);
    memcpy(h->S0, Ss, sizeof(double) * nu * nx);
    memcpy(h->b0, bs, sizeof(double) * nx);
    memcpy(h->r0, rs, sizeof(double) * nu);
}

/* Feedback: b_0 = A_0 dx0 + b_0, r_0 = r_0 + S_0 dx0, solve, write dw = [dx0 du0 dx1 ... dxN].
   stats[0] = HPIPM status, stats[1] = iterations. */
void vtqp_feedback(vtqp *h, const double *dx0, double *dw, int *stats) {
    int i, j, k, N = h->N, nx = h->nx, nu = h->nu, nz = nx + nu;
    for (i = 0; i < nx; ++i) h->tmp_b[i] = h->b0[i];
    for (i = 0; i < nu; ++i) h->tmp_r[i] = h->r0[i];
    for (j = 0; j < nx; ++j) {
        double v = dx0[j];
        for (i = 0; i < nx; ++i) h->tmp_b[i] += h->A0[i + j * nx] * v;
        for (i = 0; i < nu; ++i) h->tmp_r[i] += h->S0[i + j * nu] * v;
    }
    d_ocp_qp_set_b(0, h->tmp_b, h->qp);
    d_ocp_qp_set_r(0, h->tmp_r, h->qp);
    d_ocp_qp_ipm_solve(h->qp, h->sol, h->arg, h->ws);
    d_ocp_qp_ipm_get_status(h->ws, &stats[0]);
    d_ocp_qp_ipm_get_iter(h->ws, &stats[1]);
    for (i = 0; i < nx; ++i) dw[i] = dx0[i];
    for (k = 0; k < N; ++k) {
        d_ocp_qp_sol_get_u(k, h->sol, dw + k * nz + nx);
        d_ocp_qp_sol_get_x(k + 1, h->sol, dw + (k + 1) * nz);
    }
}
"""


def _casadi_lib_dir() -> Path:
    return Path(ca.__file__).parent


def shim_library(cache_dir: str | os.PathLike | None = None) -> Path:
    """The compiled shim (built once per compiler and casadi version, then cached); RuntimeError
    naming the cause when it cannot be built (no compiler, no libhpipm)."""
    libdir = _casadi_lib_dir()
    if not (libdir / "libhpipm.so").exists():
        raise RuntimeError(f"no libhpipm.so in the casadi package ({libdir})")
    exe = shutil.which(os.environ.get("CC") or "gcc")
    if exe is None:
        raise RuntimeError("no C compiler (gcc or $CC) to build the HPIPM shim")
    key = hashlib.sha256("\n".join([_SHIM, exe, ca.__version__, str(libdir)]).encode()).hexdigest()[:20]
    directory = Path(cache_dir).expanduser() if cache_dir is not None else default_cache_dir()
    directory.mkdir(parents=True, exist_ok=True)
    lib = directory / f"vt_hpipm_{key}.so"
    if lib.exists():
        return lib
    with tempfile.TemporaryDirectory(dir=directory) as tmp:
        src = Path(tmp) / "vt_hpipm.c"
        src.write_text(_SHIM)
        out = Path(tmp) / lib.name
        cmd = [exe, "-O2", "-shared", "-fPIC", str(src), "-o", str(out), f"-L{libdir}",
               f"-Wl,-rpath,{libdir}", "-lhpipm", "-lblasfeo", "-lm"]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0:
            raise RuntimeError(f"building the HPIPM shim failed: {proc.stderr.strip()[:300]}")
        os.replace(out, lib)
    return lib


class HpipmQP:
    """One OCP's QP in HPIPM, memory allocated once (see the module docstring).

    ``load(...)`` in the preparation phase, ``feedback(dx0, dw)`` with the measurement. Arrays
    passed to :meth:`load` must stay alive and keep their layout until the next :meth:`load`
    (HPIPM copies them, but the shim keeps stage 0's blocks).
    """

    _lib: ctypes.CDLL | None = None

    def __init__(self, N: int, nx: int, nu: int, idxbx: np.ndarray, mode: str = "speed_abs",
                 iter_max: int = 50, tol: float = 1e-6, mu0: float | None = None,
                 cache_dir: str | os.PathLike | None = None) -> None:
        lib = self._load_lib(cache_dir)
        self._lib = lib
        self.N, self.nx, self.nu = int(N), int(nx), int(nu)
        self.idxbx = np.ascontiguousarray(idxbx, dtype=np.int32)
        self._handle = lib.vtqp_create(self.N, self.nx, self.nu, int(self.idxbx.size),
                                       self.idxbx.ctypes.data, HPIPM_MODES[mode], int(iter_max), float(tol),
                                       -1.0 if mu0 is None else float(mu0))
        if not self._handle:
            raise RuntimeError("HPIPM shim: allocation failed")
        self._stats = np.zeros(2, dtype=np.int32)
        self._stats_ptr = self._stats.ctypes.data

    @classmethod
    def _load_lib(cls, cache_dir) -> ctypes.CDLL:
        if cls._lib is None:
            lib = ctypes.CDLL(str(shim_library(cache_dir)))
            vp, ip, dp = ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p
            lib.vtqp_create.restype = vp
            lib.vtqp_create.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_int, ctypes.c_int, ip,
                                        ctypes.c_int, ctypes.c_int, ctypes.c_double, ctypes.c_double]
            lib.vtqp_load.restype = None
            lib.vtqp_load.argtypes = [vp] + [dp] * 12
            lib.vtqp_feedback.restype = None
            lib.vtqp_feedback.argtypes = [vp, dp, dp, ip]
            lib.vtqp_free.restype = None
            lib.vtqp_free.argtypes = [vp]
            cls._lib = lib
        return cls._lib

    def load(self, *ptrs: int) -> None:
        """Load the stage blocks (pointers to float64 arrays, in the shim's ``vtqp_load`` order:
        Qs, Ss, Rs, qs, rs, As, Bs, bs, lbu, ubu, lbx, ubx)."""
        self._lib.vtqp_load(self._handle, *ptrs)

    def feedback(self, dx0_ptr: int, dw_ptr: int) -> tuple[int, int]:
        """Solve for the measured dx_0; the step is written to ``dw``; returns (status, iterations)."""
        self._lib.vtqp_feedback(self._handle, dx0_ptr, dw_ptr, self._stats_ptr)
        return int(self._stats[0]), int(self._stats[1])

    def __del__(self) -> None:
        handle = getattr(self, "_handle", None)
        if handle and self._lib is not None:
            self._lib.vtqp_free(handle)
            self._handle = None
