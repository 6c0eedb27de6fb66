/* The flight core of wt-inspect: N quadrotors' rate loop, mixer, motor lag, drag and rigid-body
 * integration, advanced through all physics sub-steps of one control step in one call.
 *
 * The Python side (flight_core.py) owns every array; this file only reads and writes them. The
 * operations mirror the project's Python reference implementation (rate_control.RateController,
 * rate_control.Mixer, sim.SubstepConstants) and, for the rigid body, the step Bullet applies to a
 * free btMultiBody base with damping off:
 *   - forces and torques given in the body frame are rotated to the world with the rotation of the
 *     quaternion at the start of the sub-step; gravity m g is added to the force;
 *   - angular acceleration from Euler's equations in the body frame (gyroscopic term included),
 *     rotated to the world; linear acceleration F / m; both applied to the world velocities,
 *     which Bullet then clamps to +-100 per component (m_maxCoordinateVelocity);
 *   - semi-implicit Euler: position += dt * (new velocity); orientation by the exponential map of
 *     the new world angular velocity (Taylor series of the sinc below 0.001 rad/s, the rotation
 *     per step limited to pi/4), then normalised.
 * Compiled without fast-math or FMA contraction so that the arithmetic is the one written here.
 */
#include <math.h>
#include <stdint.h>

typedef struct {
    int64_t n;          /* drones */
    int64_t nsub;       /* physics sub-steps per control step */
    int64_t rate_loop;  /* 1: PX4-like rate loop; 0: commanded rates imposed on the body */
    double dt;          /* physics step [s] */
    double gravity;     /* [m/s^2], acting along -z */
    /* rate loop of the nominal airframe (RateController's folded gains) */
    double kp[3], kd[3], ki_dt[3], J[3], ilim[3], d_beta;
    /* mixer: f_i = T bt[i] + tx bx[i] + ty by[i] + tz bz[i], limits [f_lo, f_hi] */
    double bt[4], bx[4], by[4], bz[4], f_lo, f_hi;
    /* per drone plant: mass (n), inertia (n*3), motor-lag fractions alpha, beta (n),
     * torque rows of the rotor wrench (n*12: rows tau_x, tau_y, tau_z of 4 rotors),
     * linear and quadratic drag (n*3 each), thrust factor (n) */
    double *mass, *inertia, *alpha, *beta, *a_tau, *lin_drag, *quad_drag, *thrust_scale;
    /* per drone state: position, world velocity, world angular velocity (n*3), quaternion x y z w
     * (n*4), rotor thrusts (n*4), lagged collective (n, imposed-rate mode), rate-loop integrator,
     * filtered rate difference, previous measured rates (n*3), mixer saturation flags (n*3) */
    double *pos, *vel, *omega, *quat, *rotor, *thrust, *i_term, *d_term, *prev;
    int64_t *sat;
} wt_world;

#define MAX_COORD_VEL 100.0
#define ANGULAR_MOTION_THRESHOLD (0.25 * 3.14159265358979323846)

static double clampv(double v) {
    return v > MAX_COORD_VEL ? MAX_COORD_VEL : (v < -MAX_COORD_VEL ? -MAX_COORD_VEL : v);
}

static int sgn(double x) { return x > 0 ? 1 : (x < 0 ? -1 : 0); }

/* Bullet's btMatrix3x3::setRotation (row-major, body to world). */
static void rotation(const double *q, double R[9]) {
    double x = q[0], y = q[1], z = q[2], w = q[3];
    double s = 2.0 / (x * x + y * y + z * z + w * w);
    double xs = x * s, ys = y * s, zs = z * s;
    double wx = w * xs, wy = w * ys, wz = w * zs;
    double xx = x * xs, xy = x * ys, xz = x * zs;
    double yy = y * ys, yz = y * zs, zz = z * zs;
    R[0] = 1.0 - (yy + zz); R[1] = xy - wz; R[2] = xz + wy;
    R[3] = xy + wz; R[4] = 1.0 - (xx + zz); R[5] = yz - wx;
    R[6] = xz - wy; R[7] = yz + wx; R[8] = 1.0 - (xx + yy);
}

/* Mixer.mix: rotor thrusts for (T, tx, ty, tz), desaturated; writes the saturation flags. */
static void mix(const wt_world *w, double T, double tx, double ty, double tz, double f[4], int64_t sat[3]) {
    const double lo = w->f_lo, hi = w->f_hi;
    int ok = 1;
    for (int i = 0; i < 4; i++) {
        f[i] = T * w->bt[i] + tx * w->bx[i] + ty * w->by[i] + tz * w->bz[i];
        if (!(lo <= f[i] && f[i] <= hi)) ok = 0;
    }
    if (ok) { sat[0] = sat[1] = sat[2] = 0; return; }
    int sx = 0, sy = 0, sz = 0;
    double base[4], rp[4], yz[4];
    for (int i = 0; i < 4; i++) { base[i] = T * w->bt[i]; rp[i] = tx * w->bx[i] + ty * w->by[i]; }
    double rlo = rp[0], rhi = rp[0];
    for (int i = 1; i < 4; i++) { if (rp[i] < rlo) rlo = rp[i]; if (rp[i] > rhi) rhi = rp[i]; }
    double span = hi - lo;
    if (rhi - rlo > span) {
        sx = sgn(tx); sy = sgn(ty);
        double s = span / (rhi - rlo);
        for (int i = 0; i < 4; i++) rp[i] = s * rp[i];
    }
    double fm[4];
    double top = -INFINITY;
    for (int i = 0; i < 4; i++) { fm[i] = base[i] + rp[i]; if (fm[i] > top) top = fm[i]; }
    top -= hi;
    if (top > 0) for (int i = 0; i < 4; i++) fm[i] -= top;
    double mn = fm[0];
    for (int i = 1; i < 4; i++) if (fm[i] < mn) mn = fm[i];
    double low = lo - mn;
    if (low > 0) for (int i = 0; i < 4; i++) fm[i] += low;
    double k = 1.0;
    for (int i = 0; i < 4; i++) {
        yz[i] = tz * w->bz[i];
        if (yz[i] > 0) { double r = (hi - fm[i] > 0.0 ? hi - fm[i] : 0.0) / yz[i]; if (r < k) k = r; }
        else if (yz[i] < 0) { double r = (fm[i] - lo > 0.0 ? fm[i] - lo : 0.0) / -yz[i]; if (r < k) k = r; }
    }
    if (k < 1.0) sz = sgn(tz);
    sat[0] = sx; sat[1] = sy; sat[2] = sz;
    for (int i = 0; i < 4; i++) {
        double v = fm[i] + k * yz[i];
        v = v > lo ? v : lo;
        f[i] = v < hi ? v : hi;
    }
}

/* Drag in body axes for the world velocity v and wind wnd (R body to world). */
static void drag(const wt_world *w, int64_t i, const double R[9], const double *v, const double *wnd, double d[3]) {
    double ax = v[0] - wnd[0], ay = v[1] - wnd[1], az = v[2] - wnd[2];
    double bx = R[0] * ax + R[3] * ay + R[6] * az;
    double by = R[1] * ax + R[4] * ay + R[7] * az;
    double bz = R[2] * ax + R[5] * ay + R[8] * az;
    double sp = sqrt(bx * bx + by * by + bz * bz);
    const double *dl = w->lin_drag + 3 * i, *dq = w->quad_drag + 3 * i;
    d[0] = -(dl[0] + dq[0] * sp) * bx;
    d[1] = -(dl[1] + dq[1] * sp) * by;
    d[2] = -(dl[2] + dq[2] * sp) * bz;
}

/* One sub-step of drone i's controller side: rate PID, mixer, motor lag, drag (rate loop), or
 * the imposed body rates and lagged collective (no rate loop). Writes the body-frame force F and
 * torque Tq to apply over the sub-step and advances the controller and rotor states; in the
 * imposed-rate mode it also sets the world angular velocity to the commanded rates. */
static void controller(const wt_world *w, int64_t i, const double *cmd, const double *wnd, const double R[9],
                       double F[3], double Tq[3]) {
    const double pc = cmd[0], qc = cmd[1], rc = cmd[2], T = cmd[3];
    const double alpha = w->alpha[i], beta = w->beta[i], ts = w->thrust_scale[i];
    double *om = w->omega + 3 * i, d[3];
    if (!w->rate_loop) {
        const double *Jp = w->inertia + 3 * i;
        om[0] = R[0] * pc + R[1] * qc + R[2] * rc;
        om[1] = R[3] * pc + R[4] * qc + R[5] * rc;
        om[2] = R[6] * pc + R[7] * qc + R[8] * rc;
        Tq[0] = qc * Jp[2] * rc - rc * Jp[1] * qc;
        Tq[1] = rc * Jp[0] * pc - pc * Jp[2] * rc;
        Tq[2] = pc * Jp[1] * qc - qc * Jp[0] * pc;
        double thr = w->thrust[i];
        double mean = thr + beta * (T - thr);
        w->thrust[i] = thr + alpha * (T - thr);
        drag(w, i, R, w->vel + 3 * i, wnd, d);
        mean *= ts;
        F[0] = d[0]; F[1] = d[1]; F[2] = d[2] + mean;
        double *f = w->rotor + 4 * i;
        f[0] = f[1] = f[2] = f[3] = w->thrust[i] / 4.0;
        return;
    }
    /* measured body rates R^T omega */
    double m[3] = {R[0] * om[0] + R[3] * om[1] + R[6] * om[2],
                   R[1] * om[0] + R[4] * om[1] + R[7] * om[2],
                   R[2] * om[0] + R[5] * om[1] + R[8] * om[2]};
    double sp[3] = {pc, qc, rc}, tau[3];
    double *it = w->i_term + 3 * i, *dt = w->d_term + 3 * i, *pv = w->prev + 3 * i;
    int64_t *sat = w->sat + 3 * i;
    for (int k = 0; k < 3; k++) {
        double e = sp[k] - m[k];
        double dk = dt[k] + w->d_beta * ((m[k] - pv[k]) - dt[k]);
        dt[k] = dk;
        pv[k] = m[k];
        if (!(sat[k] && ((e > 0) == (sat[k] > 0)))) {
            double ik = it[k] + w->ki_dt[k] * e;
            const double lim = w->ilim[k];
            it[k] = ik > lim ? lim : (ik < -lim ? -lim : ik);
        }
        tau[k] = w->kp[k] * e + w->J[k] * it[k] - w->kd[k] * dk;
    }
    double c[4], g[4];
    mix(w, T, tau[0], tau[1], tau[2], c, sat);
    double *f = w->rotor + 4 * i;
    for (int r = 0; r < 4; r++) {
        g[r] = f[r] + beta * (c[r] - f[r]);   /* sub-step mean thrust (applied) */
        f[r] = f[r] + alpha * (c[r] - f[r]);  /* end-of-sub-step rotor state */
        g[r] *= ts;
    }
    drag(w, i, R, w->vel + 3 * i, wnd, d);
    const double *a = w->a_tau + 12 * i;
    F[0] = d[0]; F[1] = d[1]; F[2] = d[2] + g[0] + g[1] + g[2] + g[3];
    Tq[0] = a[0] * g[0] + a[1] * g[1] + a[2] * g[2] + a[3] * g[3];
    Tq[1] = a[4] * g[0] + a[5] * g[1] + a[6] * g[2] + a[7] * g[3];
    Tq[2] = a[8] * g[0] + a[9] * g[1] + a[10] * g[2] + a[11] * g[3];
}

/* Bullet's free-body step of drone i under body-frame force F and torque Tq (see the header). */
static void integrate(const wt_world *w, int64_t i, const double R[9], const double F[3], const double Tq[3]) {
    const double h = w->dt, m = w->mass[i];
    const double *I = w->inertia + 3 * i;
    double *p = w->pos + 3 * i, *v = w->vel + 3 * i, *om = w->omega + 3 * i, *q = w->quat + 4 * i;
    /* world force (rotor thrust, drag) plus gravity; world torque, as PyBullet's LINK_FRAME calls */
    double Fw[3] = {R[0] * F[0] + R[1] * F[1] + R[2] * F[2],
                    R[3] * F[0] + R[4] * F[1] + R[5] * F[2],
                    R[6] * F[0] + R[7] * F[1] + R[8] * F[2] + m * -w->gravity};
    double Tw[3] = {R[0] * Tq[0] + R[1] * Tq[1] + R[2] * Tq[2],
                    R[3] * Tq[0] + R[4] * Tq[1] + R[5] * Tq[2],
                    R[6] * Tq[0] + R[7] * Tq[1] + R[8] * Tq[2]};
    /* base frame: omega_b, torque_b; Euler's equations */
    double wb[3], tb[3];
    for (int k = 0; k < 3; k++) {
        wb[k] = R[k] * om[0] + R[3 + k] * om[1] + R[6 + k] * om[2];
        tb[k] = R[k] * Tw[0] + R[3 + k] * Tw[1] + R[6 + k] * Tw[2];
    }
    double Iw[3] = {I[0] * wb[0], I[1] * wb[1], I[2] * wb[2]};
    double ab[3] = {(tb[0] - (wb[1] * Iw[2] - wb[2] * Iw[1])) / I[0],
                    (tb[1] - (wb[2] * Iw[0] - wb[0] * Iw[2])) / I[1],
                    (tb[2] - (wb[0] * Iw[1] - wb[1] * Iw[0])) / I[2]};
    for (int k = 0; k < 3; k++) {
        double aw = R[3 * k] * ab[0] + R[3 * k + 1] * ab[1] + R[3 * k + 2] * ab[2];
        om[k] = clampv(om[k] + aw * h);
        v[k] = clampv(v[k] + (Fw[k] / m) * h);
    }
    for (int k = 0; k < 3; k++) p[k] += h * v[k];
    /* exponential map of the world angular velocity: q <- dq(omega h) * q */
    double ang = sqrt(om[0] * om[0] + om[1] * om[1] + om[2] * om[2]);
    if (ang * h > ANGULAR_MOTION_THRESHOLD) ang = 0.5 * (0.5 * 3.14159265358979323846) / h;
    double s;
    if (ang < 0.001) s = 0.5 * h - (h * h * h) * 0.020833333333 * ang * ang;
    else s = sin(0.5 * ang * h) / ang;
    double ax = om[0] * s, ay = om[1] * s, az = om[2] * s, aw = cos(ang * h * 0.5);
    double x = q[0], y = q[1], z = q[2], qw = q[3];
    double nx = aw * x + ax * qw + (ay * z - az * y);
    double ny = aw * y + ay * qw + (az * x - ax * z);
    double nz = aw * z + az * qw + (ax * y - ay * x);
    double nw = aw * qw - (ax * x + ay * y + az * z);
    double nrm = sqrt(nx * nx + ny * ny + nz * nz + nw * nw);
    q[0] = nx / nrm; q[1] = ny / nrm; q[2] = nz / nrm; q[3] = nw / nrm;
}

/* Advance the m drones idx[0..m) through all sub-steps of one control step, each holding its
 * command cmd[4 i..] in its wind wind[3 i..] (indexed by drone, not by position in idx). */
void wt_step(const wt_world *w, int64_t m, const int64_t *idx, const double *cmd, const double *wind) {
    double R[9], F[3], Tq[3];
    for (int64_t j = 0; j < m; j++) {
        const int64_t i = idx[j];
        for (int64_t s = 0; s < w->nsub; s++) {
            rotation(w->quat + 4 * i, R);
            controller(w, i, cmd + 4 * i, wind + 3 * i, R, F, Tq);
            integrate(w, i, R, F, Tq);
        }
    }
}

/* One sub-step of the controller side only, for drones that another integrator (PyBullet, near
 * contacts) advances: writes the body-frame force and torque of drone idx[j] to force[3 j..] and
 * torque[3 j..] (indexed by position in idx). */
void wt_wrench(const wt_world *w, int64_t m, const int64_t *idx, const double *cmd, const double *wind,
               double *force, double *torque) {
    double R[9];
    for (int64_t j = 0; j < m; j++) {
        const int64_t i = idx[j];
        rotation(w->quat + 4 * i, R);
        controller(w, i, cmd + 4 * i, wind + 3 * i, R, force + 3 * j, torque + 3 * j);
    }
}

/* Which drones may touch something during the next control step (see integration.py). For each
 * drone: reach = |v| h_c + a_max h_c^2 / 2 bounds its travel over the control step h_c, with a_max
 * from the larger of full rotor thrust and the commanded thrust, drag at its airspeed bound
 * |v| + |wind| and gravity. code[i] = 1 when its sphere plus reach plus margin reaches below the
 * ground; else 2 when the clearance free[i] left from the last turbine measurement is below the
 * reach (the caller measures again); else 0 and the reach is used up: free[i] -= reach. Returns
 * the number of drones with a non-zero code. */
int64_t wt_screen(const wt_world *w, const double *cmd, const double *wind, double h_c, double f_max,
                  int64_t has_ground, double ground_z, double need0, double *free_, double *reach,
                  int8_t *code) {
    int64_t count = 0;
    for (int64_t i = 0; i < w->n; i++) {
        const double *v = w->vel + 3 * i, *wn = wind + 3 * i;
        const double *dl = w->lin_drag + 3 * i, *dq = w->quad_drag + 3 * i;
        double speed = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
        double air = speed + sqrt(wn[0] * wn[0] + wn[1] * wn[1] + wn[2] * wn[2]);
        double dr = ((dl[0] + dl[1] + dl[2]) + (dq[0] + dq[1] + dq[2]) * air) * air;
        double thr = (f_max > cmd[4 * i + 3] ? f_max : cmd[4 * i + 3]) * w->thrust_scale[i];
        double a_max = (thr + dr) / w->mass[i] + w->gravity;
        double r = speed * h_c + 0.5 * a_max * h_c * h_c;
        reach[i] = r;
        if (has_ground && w->pos[3 * i + 2] - (r + need0) < ground_z) code[i] = 1;
        else if (free_[i] < r) code[i] = 2;
        else { code[i] = 0; free_[i] -= r; continue; }
        count++;
    }
    return count;
}

int64_t wt_abi_version(void) { return 2; }
