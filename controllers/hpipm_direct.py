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
part of HPIPM's stable setter/getter API. Path constraints (the MPCs' clearance constraint) are
HPIPM's general constraints ``lg <= C x + D u <= ug``, an infinite side masked out; at stage 0 they
are shifted by ``C_0 dx_0`` in the feedback like the dynamics. The tangential predictor holds only
input bounds active: it is skipped when a path constraint is active at its base solution and
falls back to the full QP when the prediction would reach one.
"""
from __future__ import annotations

import ctypes
import hashlib
import os
import shutil
import subprocess
from pathlib import Path

import casadi as ca
import numpy as np

from .codegen import CompileError, LibraryCache

HPIPM_MODES = {"speed_abs": 0, "speed": 1, "balance": 2, "robust": 3}

_SHIM = r"""
#include <stdlib.h>
#include <string.h>
#include <math.h>

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
extern void d_ocp_qp_set_C(int stage, double *v, void *qp);
extern void d_ocp_qp_set_D(int stage, double *v, void *qp);
extern void d_ocp_qp_set_lg(int stage, double *v, void *qp);
extern void d_ocp_qp_set_ug(int stage, double *v, void *qp);
extern void d_ocp_qp_set_lg_mask(int stage, double *v, void *qp);
extern void d_ocp_qp_set_ug_mask(int stage, double *v, void *qp);
extern hsize d_ocp_qp_sol_strsize(void);
extern hsize d_ocp_qp_sol_memsize(void *dim);
extern void d_ocp_qp_sol_create(void *dim, void *sol, void *mem);
extern void d_ocp_qp_sol_get_u(int stage, void *sol, double *v);
extern void d_ocp_qp_sol_get_x(int stage, void *sol, double *v);
extern void d_ocp_qp_sol_get_lam_lbu(int stage, void *sol, double *v);
extern void d_ocp_qp_sol_get_lam_ubu(int stage, void *sol, double *v);
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
    int N, nx, nu, nbx, ng;
    /* general (path) constraints lg <= C x + D u <= ug at stages 0..N-1: stage 0's C and bounds
       kept for the feedback (x_0 eliminated), all stages' blocks for the predictor's checks */
    double *C0, *lg0, *ug0, *tmp_lg, *tmp_ug, *lg_mask, *ug_mask;
    double *Cs, *Ds, *lgs, *ugs;
    void *dim, *qp, *sol, *arg, *ws;
    void *mem[5];
    int *idxbx, *idxbu;
    double *A0, *S0, *b0, *r0, *tmp_b, *tmp_r;
    /* tangential predictor: stage data of the last load, gains, base solution */
    double *Qs, *Ss, *Rs, *As, *Bs, *lbu, *ubu;
    double *K, *P, *G, *Huu, *Hux, *dx, *dxn, *du, *dw_base, *dx0_base, *lam;
    int *active, pred_valid;
} vtqp;

static void *zalloc(hsize n) { void *p = calloc(1, n ? n : 1); return p; }

void vtqp_free(vtqp *h) {
    int i;
    if (!h) return;
    for (i = 0; i < 5; ++i) free(h->mem[i]);
    free(h->dim); free(h->qp); free(h->sol); free(h->arg); free(h->ws);
    free(h->idxbx); free(h->idxbu);
    free(h->A0); free(h->S0); free(h->b0); free(h->r0); free(h->tmp_b); free(h->tmp_r);
    free(h->K); free(h->P); free(h->G); free(h->Huu); free(h->Hux); free(h->dx); free(h->dxn);
    free(h->du); free(h->dw_base); free(h->dx0_base); free(h->active); free(h->lam);
    free(h->C0); free(h->lg0); free(h->ug0); free(h->tmp_lg); free(h->tmp_ug); free(h->lg_mask); free(h->ug_mask);
    free(h);
}

/* Stage 0 has no state (x_0 eliminated), stages 1..N have nx states; nu inputs bounded at every
   stage 0..N-1; nbx states bounded at stages 1..N (indices idxbx); ng general constraints at
   stages 0..N-1, a side whose mask entry is 0 left open. mu0 <= 0 keeps the preset's. */
vtqp *vtqp_create(int N, int nx, int nu, int nbx, const int *idxbx, int mode, int iter_max,
                  double tol, double mu0, int ng, const double *lg_mask, const double *ug_mask) {
    int k;
    vtqp *h = (vtqp *) zalloc(sizeof(vtqp));
    h->N = N; h->nx = nx; h->nu = nu; h->nbx = nbx; h->ng = ng;
    h->dim = zalloc(d_ocp_qp_dim_strsize());
    h->mem[0] = zalloc(d_ocp_qp_dim_memsize(N));
    d_ocp_qp_dim_create(N, h->dim, h->mem[0]);
    for (k = 0; k <= N; ++k) {
        d_ocp_qp_dim_set_nx(k, k == 0 ? 0 : nx, h->dim);
        d_ocp_qp_dim_set_nu(k, k == N ? 0 : nu, h->dim);
        d_ocp_qp_dim_set_nbx(k, k == 0 ? 0 : nbx, h->dim);
        d_ocp_qp_dim_set_nbu(k, k == N ? 0 : nu, h->dim);
        d_ocp_qp_dim_set_ng(k, k == N ? 0 : ng, h->dim);
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
    h->lg_mask = (double *) zalloc(sizeof(double) * (ng > 0 ? ng : 1));
    h->ug_mask = (double *) zalloc(sizeof(double) * (ng > 0 ? ng : 1));
    for (k = 0; k < ng; ++k) { h->lg_mask[k] = lg_mask[k]; h->ug_mask[k] = ug_mask[k]; }
    if (ng) for (k = 0; k < N; ++k) {
        d_ocp_qp_set_lg_mask(k, h->lg_mask, h->qp);
        d_ocp_qp_set_ug_mask(k, h->ug_mask, h->qp);
    }
    h->C0 = (double *) zalloc(sizeof(double) * (ng > 0 ? ng : 1) * nx);
    h->lg0 = (double *) zalloc(sizeof(double) * (ng > 0 ? ng : 1));
    h->ug0 = (double *) zalloc(sizeof(double) * (ng > 0 ? ng : 1));
    h->tmp_lg = (double *) zalloc(sizeof(double) * (ng > 0 ? ng : 1));
    h->tmp_ug = (double *) zalloc(sizeof(double) * (ng > 0 ? ng : 1));
    h->A0 = (double *) zalloc(sizeof(double) * nx * nx);
    h->S0 = (double *) zalloc(sizeof(double) * nu * nx);
    h->b0 = (double *) zalloc(sizeof(double) * nx);
    h->r0 = (double *) zalloc(sizeof(double) * nu);
    h->tmp_b = (double *) zalloc(sizeof(double) * nx);
    h->tmp_r = (double *) zalloc(sizeof(double) * nu);
    h->K = (double *) zalloc(sizeof(double) * N * nu * nx);
    h->P = (double *) zalloc(sizeof(double) * nx * nx * 3);
    h->G = (double *) zalloc(sizeof(double) * nu * nx);
    h->Huu = (double *) zalloc(sizeof(double) * N * nu * nu);
    h->Hux = (double *) zalloc(sizeof(double) * N * nu * nx);
    h->lam = (double *) zalloc(sizeof(double) * N * nu * 2);
    h->dx = (double *) zalloc(sizeof(double) * nx);
    h->dxn = (double *) zalloc(sizeof(double) * nx);
    h->du = (double *) zalloc(sizeof(double) * nu);
    h->dw_base = (double *) zalloc(sizeof(double) * (N * (nx + nu) + nx));
    h->dx0_base = (double *) zalloc(sizeof(double) * nx);
    h->active = (int *) zalloc(sizeof(int) * N * nu);
    return h;
}

/* Preparation: load the linearisation (stage blocks column-major, stage k at k * block size).
   Qs: nx x nx for stages 0..N; Ss: nu x nx, Rs: nu x nu, rs: nu, As: nx x nx, Bs: nx x nu,
   bs: nx for stages 0..N-1; qs: nx for 0..N; lbu/ubu: nu per stage 0..N-1; lbx/ubx: nbx per
   stage 1..N; Cs: ng x nx, Ds: ng x nu, lgs/ugs: ng for stages 0..N-1 (ignored when ng = 0).
   Stage 0's state blocks are kept for the feedback. */
void vtqp_load(vtqp *h, double *Qs, double *Ss, double *Rs, double *qs, double *rs, double *As,
               double *Bs, double *bs, double *lbu, double *ubu, double *lbx, double *ubx,
               double *Cs, double *Ds, double *lgs, double *ugs) {
    int k, N = h->N, nx = h->nx, nu = h->nu, nbx = h->nbx, ng = h->ng;
    if (ng) {
        for (k = 0; k < N; ++k) {
            d_ocp_qp_set_D(k, Ds + k * ng * nu, h->qp);
            if (k > 0) {
                d_ocp_qp_set_C(k, Cs + k * ng * nx, h->qp);
                d_ocp_qp_set_lg(k, lgs + k * ng, h->qp);
                d_ocp_qp_set_ug(k, ugs + k * ng, h->qp);
            }
        }
        memcpy(h->C0, Cs, sizeof(double) * ng * nx);
        memcpy(h->lg0, lgs, sizeof(double) * ng);
        memcpy(h->ug0, ugs, sizeof(double) * ng);
        h->Cs = Cs; h->Ds = Ds; h->lgs = lgs; h->ugs = ugs;
    }
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
    h->Qs = Qs; h->Ss = Ss; h->Rs = Rs; h->As = As; h->Bs = Bs; h->lbu = lbu; h->ubu = ubu;
    h->pred_valid = 0;
}

/* Cholesky solve of the free block of Huu (n = nu, free rows/cols where !act): X = -Huu_FF^-1 Hux_F,
   written into the free rows of K (nu x nx, column-major), zero rows for active inputs. */
static int gain_rows(int nu, int nx, const int *act, double *Huu, const double *Hux, double *K) {
    int f[16], nf = 0, i, j, c, l;
    double L[256];
    for (i = 0; i < nu; ++i) if (!act[i]) f[nf++] = i;
    for (i = 0; i < nu * nx; ++i) K[i] = 0.0;
    if (nf == 0) return 0;
    for (i = 0; i < nf; ++i) for (j = 0; j <= i; ++j) {
        double v = Huu[f[i] + f[j] * nu];
        for (l = 0; l < j; ++l) v -= L[i + l * nf] * L[j + l * nf];
        if (i == j) { if (v <= 0) return -1; L[i + i * nf] = sqrt(v); }
        else L[i + j * nf] = v / L[j + j * nf];
    }
    for (c = 0; c < nx; ++c) {
        double y[16];
        for (i = 0; i < nf; ++i) {           /* L y = -Hux_F[:, c] */
            double v = -Hux[f[i] + c * nu];
            for (l = 0; l < i; ++l) v -= L[i + l * nf] * y[l];
            y[i] = v / L[i + i * nf];
        }
        for (i = nf - 1; i >= 0; --i) {      /* L^T x = y */
            double v = y[i];
            for (l = i + 1; l < nf; ++l) v -= L[l + i * nf] * y[l];
            y[i] = v / L[i + i * nf];
        }
        for (i = 0; i < nf; ++i) K[f[i] + c * nu] = y[i];
    }
    return 0;
}

/* Whether some open-side-masked general constraint of the step dw (= [dx0 du0 dx1 ...]) is within
   tol of its bound (or beyond it): C_k dx_k + D_k du_k against [lg_k, ug_k]. */
static int general_violated(const vtqp *h, const double *dw, double tol) {
    int i, j, k, N = h->N, nx = h->nx, nu = h->nu, ng = h->ng, nz = nx + nu;
    for (k = 0; k < N; ++k) for (i = 0; i < ng; ++i) {
        double g = 0;
        const double *C = h->Cs + k * ng * nx, *D = h->Ds + k * ng * nu;
        for (j = 0; j < nx; ++j) g += C[i + j * ng] * dw[k * nz + j];
        for (j = 0; j < nu; ++j) g += D[i + j * ng] * dw[k * nz + nx + j];
        if (h->lg_mask[i] != 0.0 && g - h->lgs[k * ng + i] < tol) return 1;
        if (h->ug_mask[i] != 0.0 && h->ugs[k * ng + i] - g < tol) return 1;
    }
    return 0;
}

/* Tangential predictor, preparation side: after a solve for dx0 (the base), hold the active
   input bounds and compute the gains of the solution w.r.t. dx0 by a Riccati recursion on the
   free inputs: u_k = K_k dx_k; keep each stage's Huu, Hux (the change of the inputs' gradient,
   which moves the active bounds' multipliers) and the base multipliers. Returns 0, or -1 when the
   base solve failed or a reduced Hessian is not positive definite (the feedback then solves the
   full QP). */
int vtqp_sens(vtqp *h, const double *dx0, const double *dw, double act_tol, int status) {
    int i, j, k, l, N = h->N, nx = h->nx, nu = h->nu, nz = nx + nu;
    double *P = h->P, *Pn = h->P + nx * nx, *PA = h->P + 2 * nx * nx;
    h->pred_valid = 0;
    if (status != 0 || nu > 16) return -1;
    memcpy(h->dw_base, dw, sizeof(double) * (N * nz + nx));
    memcpy(h->dx0_base, dx0, sizeof(double) * nx);
    for (k = 0; k < N; ++k) {
        d_ocp_qp_sol_get_lam_lbu(k, h->sol, h->lam + 2 * k * nu);
        d_ocp_qp_sol_get_lam_ubu(k, h->sol, h->lam + 2 * k * nu + nu);
    }
    if (h->ng && general_violated(h, dw, act_tol)) return -1;   /* only inactive path constraints */
    for (k = 0; k < N; ++k) for (i = 0; i < nu; ++i) {
        double u = dw[k * nz + nx + i], lo = h->lbu[k * nu + i], hi = h->ubu[k * nu + i];
        double scale = act_tol * (hi - lo > 1.0 ? hi - lo : 1.0);
        h->active[k * nu + i] = (u - lo < scale) || (hi - u < scale);
    }
    memcpy(P, h->Qs + N * nx * nx, sizeof(double) * nx * nx);
    for (k = N - 1; k >= 0; --k) {
        const double *A = h->As + k * nx * nx, *B = h->Bs + k * nx * nu;
        const double *R = h->Rs + k * nu * nu, *S = h->Ss + k * nu * nx;
        double *K = h->K + k * nu * nx, *Huu = h->Huu + k * nu * nu, *Hux = h->Hux + k * nu * nx;
        /* G = B^T P (nu x nx) */
        for (i = 0; i < nu; ++i) for (j = 0; j < nx; ++j) {
            double v = 0; for (l = 0; l < nx; ++l) v += B[l + i * nx] * P[l + j * nx]; h->G[i + j * nu] = v; }
        for (i = 0; i < nu; ++i) for (j = 0; j < nu; ++j) {
            double v = R[i + j * nu];
            for (l = 0; l < nx; ++l) v += h->G[i + l * nu] * B[l + j * nx];
            Huu[i + j * nu] = v; }
        for (i = 0; i < nu; ++i) for (j = 0; j < nx; ++j) {
            double v = S[i + j * nu];
            for (l = 0; l < nx; ++l) v += h->G[i + l * nu] * A[l + j * nx];
            Hux[i + j * nu] = v; }
        if (gain_rows(nu, nx, h->active + k * nu, Huu, Hux, K)) return -1;
        if (k == 0) break;
        /* Pn = Q + A^T (P A) + Hux^T K  (then symmetrised) */
        for (i = 0; i < nx; ++i) for (j = 0; j < nx; ++j) {
            double v = 0; for (l = 0; l < nx; ++l) v += P[i + l * nx] * A[l + j * nx]; PA[i + j * nx] = v; }
        for (i = 0; i < nx; ++i) for (j = 0; j < nx; ++j) {
            double v = h->Qs[k * nx * nx + i + j * nx];
            for (l = 0; l < nx; ++l) v += A[l + i * nx] * PA[l + j * nx];
            for (l = 0; l < nu; ++l) v += Hux[l + i * nu] * K[l + j * nu];
            Pn[i + j * nx] = v;
        }
        for (i = 0; i < nx; ++i) for (j = 0; j < nx; ++j) P[i + j * nx] = 0.5 * (Pn[i + j * nx] + Pn[j + i * nx]);
    }
    h->pred_valid = 1;
    return 0;
}

/* Tangential predictor, feedback side: dw = dw_base + the response to dx0 - dx0_base with the
   active set held. Returns 0, or 1 when the active set would change - a free input leaving its
   bounds, or an active bound's multiplier turning negative - or no valid prediction exists: the
   caller then solves the full QP. */
int vtqp_predict(vtqp *h, const double *dx0, double *dw) {
    int i, j, k, N = h->N, nx = h->nx, nu = h->nu, nz = nx + nu;
    double *dx = h->dx, *dxn = h->dxn, *du = h->du;
    if (!h->pred_valid) return 1;
    for (i = 0; i < nx; ++i) { dx[i] = dx0[i] - h->dx0_base[i]; dw[i] = dx0[i]; }
    for (k = 0; k < N; ++k) {
        const double *A = h->As + k * nx * nx, *B = h->Bs + k * nx * nu, *K = h->K + k * nu * nx;
        const double *Huu = h->Huu + k * nu * nu, *Hux = h->Hux + k * nu * nx, *lam = h->lam + 2 * k * nu;
        for (i = 0; i < nu; ++i) {
            double v = 0; for (j = 0; j < nx; ++j) v += K[i + j * nu] * dx[j]; du[i] = v;
            v += h->dw_base[k * nz + nx + i];
            if (!h->active[k * nu + i] && (v < h->lbu[k * nu + i] || v > h->ubu[k * nu + i])) return 1;
            dw[k * nz + nx + i] = v;
        }
        for (i = 0; i < nu; ++i) if (h->active[k * nu + i]) {
            double g = 0;   /* change of d(cost-to-go)/du_i: moves lam_lb by +g, lam_ub by -g */
            for (j = 0; j < nu; ++j) g += Huu[i + j * nu] * du[j];
            for (j = 0; j < nx; ++j) g += Hux[i + j * nu] * dx[j];
            if (lam[i] >= lam[nu + i] ? lam[i] + g < 0.0 : lam[nu + i] - g < 0.0) return 1;   /* lower : upper */
        }
        for (i = 0; i < nx; ++i) {
            double v = 0;
            for (j = 0; j < nx; ++j) v += A[i + j * nx] * dx[j];
            for (j = 0; j < nu; ++j) v += B[i + j * nx] * du[j];
            dxn[i] = v;
            dw[(k + 1) * nz + i] = h->dw_base[(k + 1) * nz + i] + v;
        }
        for (i = 0; i < nx; ++i) dx[i] = dxn[i];
    }
    if (h->ng && general_violated(h, dw, 0.0)) return 1;   /* a path constraint would become active */
    return 0;
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
    if (h->ng) {   /* stage 0: lg - C_0 dx0 <= D_0 du0 <= ug - C_0 dx0 */
        for (i = 0; i < h->ng; ++i) { h->tmp_lg[i] = h->lg0[i]; h->tmp_ug[i] = h->ug0[i]; }
        for (j = 0; j < nx; ++j) for (i = 0; i < h->ng; ++i) {
            h->tmp_lg[i] -= h->C0[i + j * h->ng] * dx0[j];
            h->tmp_ug[i] -= h->C0[i + j * h->ng] * dx0[j];
        }
        d_ocp_qp_set_lg(0, h->tmp_lg, h->qp);
        d_ocp_qp_set_ug(0, h->tmp_ug, h->qp);
    }
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


def load_shim(cache_dir: str | os.PathLike | None = None) -> tuple[ctypes.CDLL, Path]:
    """The compiled shim, loaded (built once per compiler and casadi version, then cached in the
    guarded library cache of :mod:`controllers.codegen`: digest-checked, rebuilt if corrupt);
    RuntimeError naming the cause when it cannot be built (no compiler, no libhpipm), CacheDirError
    (a ValueError) when the cache directory cannot be trusted."""
    libdir = _casadi_lib_dir()
    if not (libdir / "libhpipm.so").exists():
        raise RuntimeError(f"no libhpipm.so in the casadi package ({libdir})")
    exe = shutil.which(os.environ.get("CC") or "gcc")
    if exe is None:
        raise RuntimeError("no C compiler (gcc or $CC) to build the HPIPM shim")
    key = hashlib.sha256("\n".join([_SHIM, exe, ca.__version__, str(libdir)]).encode()).hexdigest()[:20]
    name = f"vt_hpipm_{key}.so"

    def build(tmp: Path) -> Path:
        src = tmp / "vt_hpipm.c"
        src.write_text(_SHIM)
        out = tmp / name
        cmd = [exe, "-O2", "-shared", "-fPIC", str(src), "-o", str(out), f"-L{libdir}",
               f"-Wl,-rpath,{libdir}", "-lhpipm", "-lblasfeo", "-lm"]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode != 0:
            raise CompileError(f"building the HPIPM shim failed: {proc.stderr.strip()[:300]}")
        return out

    lib, path, _ = LibraryCache.open(cache_dir).load(name, build, lambda p: ctypes.CDLL(str(p)))
    return lib, path


def shim_library(cache_dir: str | os.PathLike | None = None) -> Path:
    """Path of the compiled (digest-checked, loadable) shim; see :func:`load_shim`."""
    return load_shim(cache_dir)[1]


class HpipmQP:
    """One OCP's QP in HPIPM, memory allocated once (see the module docstring).

    ``load(...)`` in the preparation phase, ``feedback(dx0, dw)`` with the measurement. Arrays
    passed to :meth:`load` must stay alive and keep their layout until the next :meth:`load`
    (HPIPM copies them, but the shim keeps stage 0's blocks).
    """

    _lib: ctypes.CDLL | None = None

    def __init__(self, N: int, nx: int, nu: int, idxbx: np.ndarray, mode: str = "speed_abs",
                 iter_max: int = 50, tol: float = 1e-6, mu0: float | None = None,
                 cache_dir: str | os.PathLike | None = None, g_lower_open: np.ndarray | None = None,
                 g_upper_open: np.ndarray | None = None) -> None:
        lib = self._load_lib(cache_dir)
        self._lib = lib
        self.N, self.nx, self.nu = int(N), int(nx), int(nu)
        self.idxbx = np.ascontiguousarray(idxbx, dtype=np.int32)
        # General (path) constraints: one entry per row, True where that side is open (infinite).
        lo_open = np.zeros(0, bool) if g_lower_open is None else np.asarray(g_lower_open, bool)
        hi_open = np.zeros(len(lo_open), bool) if g_upper_open is None else np.asarray(g_upper_open, bool)
        if lo_open.shape != hi_open.shape:
            raise ValueError("g_lower_open and g_upper_open must have one entry per general constraint")
        self.ng = len(lo_open)
        self._g_masks = (np.ascontiguousarray(~lo_open, dtype=np.float64),
                         np.ascontiguousarray(~hi_open, dtype=np.float64))
        self._handle = lib.vtqp_create(self.N, self.nx, self.nu, int(self.idxbx.size),
                                       self.idxbx.ctypes.data, HPIPM_MODES[mode], int(iter_max), float(tol),
                                       -1.0 if mu0 is None else float(mu0), self.ng,
                                       self._g_masks[0].ctypes.data, self._g_masks[1].ctypes.data)
        if not self._handle:
            raise RuntimeError("HPIPM shim: allocation failed")
        self._stats = np.zeros(2, dtype=np.int32)
        self._stats_ptr = self._stats.ctypes.data

    @classmethod
    def _load_lib(cls, cache_dir) -> ctypes.CDLL:
        if cls._lib is None:
            try:
                lib, _ = load_shim(cache_dir)
            except OSError as exc:   # a freshly built shim that does not load
                raise RuntimeError(f"the HPIPM shim does not load: {exc}") from None
            vp, ip, dp = ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p
            lib.vtqp_create.restype = vp
            lib.vtqp_create.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_int, ctypes.c_int, ip,
                                        ctypes.c_int, ctypes.c_int, ctypes.c_double, ctypes.c_double,
                                        ctypes.c_int, dp, dp]
            lib.vtqp_load.restype = None
            lib.vtqp_load.argtypes = [vp] + [dp] * 16
            lib.vtqp_feedback.restype = None
            lib.vtqp_feedback.argtypes = [vp, dp, dp, ip]
            lib.vtqp_sens.restype = ctypes.c_int
            lib.vtqp_sens.argtypes = [vp, dp, dp, ctypes.c_double, ctypes.c_int]
            lib.vtqp_predict.restype = ctypes.c_int
            lib.vtqp_predict.argtypes = [vp, dp, dp]
            lib.vtqp_free.restype = None
            lib.vtqp_free.argtypes = [vp]
            cls._lib = lib
        return cls._lib

    def load(self, *ptrs: int) -> None:
        """Load the stage blocks (pointers to float64 arrays, in the shim's ``vtqp_load`` order:
        Qs, Ss, Rs, qs, rs, As, Bs, bs, lbu, ubu, lbx, ubx, Cs, Ds, lgs, ugs)."""
        self._lib.vtqp_load(self._handle, *ptrs)

    def feedback(self, dx0_ptr: int, dw_ptr: int) -> tuple[int, int]:
        """Solve for the measured dx_0; the step is written to ``dw``; returns (status, iterations)."""
        self._lib.vtqp_feedback(self._handle, dx0_ptr, dw_ptr, self._stats_ptr)
        return int(self._stats[0]), int(self._stats[1])

    def sensitivities(self, dx0_ptr: int, dw_ptr: int, status: int, active_tol: float = 1e-6) -> bool:
        """After a solve for ``dx0`` (its solution in ``dw``): the gains of the solution with the
        active input bounds held (tangential predictor). False when there is no valid prediction."""
        return self._lib.vtqp_sens(self._handle, dx0_ptr, dw_ptr, float(active_tol), int(status)) == 0

    def predict(self, dx0_ptr: int, dw_ptr: int) -> bool:
        """The predicted solution for a new ``dx0`` into ``dw``; False (and ``dw`` not to be used)
        when a free input would leave its bounds or no prediction is prepared."""
        return self._lib.vtqp_predict(self._handle, dx0_ptr, dw_ptr) == 0

    def __del__(self) -> None:
        handle = getattr(self, "_handle", None)
        if handle and self._lib is not None:
            self._lib.vtqp_free(handle)
            self._handle = None
