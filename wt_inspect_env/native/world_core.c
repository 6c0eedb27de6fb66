/* The inspection world's per-step arithmetic for N drones: the moving inspection reference, the
 * running metrics and the default task's observation, reward and termination.
 *
 * Driven by world_core.py (ctypes). Every function loops over drones and, per drone, does the
 * scalar arithmetic in a fixed order, so a drone's numbers do not depend on how many drones are
 * stepped together. Compiled with -O2 -ffp-contract=off and no fast-math: the floating-point
 * operations are the ones written (no fused multiply-adds, no reassociation).
 */
#include <math.h>
#include <stdint.h>

int64_t wt_world_abi_version(void) { return 3; }

/* NumPy's maximum / minimum: NaN in, NaN out (C's fmax/fmin drop NaN). */
static double np_max(double a, double b) { return (isnan(a) || isnan(b)) ? NAN : (a > b ? a : b); }
static double np_min(double a, double b) { return (isnan(a) || isnan(b)) ? NAN : (a < b ? a : b); }

/* ------------------------------------------------------------------------------ reference */

typedef struct {
    int64_t n_runs;
    const int64_t *run_start;    /* first path sample of each run */
    const int64_t *run_count;    /* samples per run */
    const double *run_length;    /* tau length per run */
    const double *run_offset;    /* tau length of the runs before */
    const int64_t *run_phase;    /* phase label per run */
    const double *tau;           /* per sample */
    const double *dtau;          /* per sample (the last of a run unused) */
    const double *geom;          /* per sample: point(3) normal(3) hdir(3) s */
    const double *dp_dtau;       /* per sample, 3 */
    const double *normals;       /* per sample, 3 (unit) */
    const double *hdir;          /* per sample, 3 */
    double total_length, speed, stop, inv_band, standoff, hold_limit;   /* hold_limit NaN: none */
    int64_t closed;
    const double *reach;         /* per sample: how far short of the ideal pose the clearance stops the drone */
    double lag_threshold, stall_time;   /* stall_time NaN: no stall detection */
    int64_t stall_skip;          /* on a stall: 1 move on without the drone, 0 end the episode (the world) */
    double approach_speed;       /* speed of the approach from a far start [m/s] */
    double deadline;             /* with stall_skip: the time by which the point must reach the path's end (NaN: none) */
} RefPath;

/* A drone counts as stalled while its point advances at less than this share of the nominal speed. */
/* Vertices of an approach route at most (start, two detour via points, the first pose). */
#define APPROACH_MAX 4
#define STALL_SIGMA 0.1
/* skipping: 0 following the drone, SKIPPING moving on after a stall until the drone is back on its pose,
 * PACING at the nominal speed to the end, the point having fallen behind the schedule that meets the deadline */
#define SKIPPING 1
#define PACING 2

typedef struct {
    /* per-drone reference state */
    int64_t *run; double *tau, *time, *hold_elapsed; uint8_t *holding, *done, *release;
    /* the current sample */
    double *point, *normal, *velocity, *ideal; int64_t *phase; double *progress;
    uint8_t *s_done, *waiting, *hold_started, *phase_changed;
    double *s, *speed_factor, *lag, *s_time;
    /* stalls: seconds without progress, skipping now, stalls so far, tau skipped, first sample of a skip,
       the current sample's clearance shortfall */
    double *stalled_for; uint8_t *skipping; int64_t *stalls; double *skipped; uint8_t *s_stalled; double *deficit;
    /* the approach from a far start: its length (0: none), its route - up to APPROACH_MAX vertices
       (x, y, z) from the start pose to the path's first ideal pose - and the route's vertex count per
       drone; while the drone's tau is negative its ideal pose lies on the route, -tau from its end */
    double *approach_len, *approach_pts; int64_t *approach_nv;
} RefState;

static void ref_sample(const RefPath *P, RefState *S, int64_t i, double sigma, int hold_started,
                       int phase_changed, double lag, int stalled) {
    int64_t r = S->run[i], start = P->run_start[r], cnt = P->run_count[r], k = 0;
    double t = S->tau[i], g[10], frac = 0.0;
    if (cnt == 1) {
        for (int j = 0; j < 10; ++j) g[j] = P->geom[10 * start + j];
    } else {
        /* searchsorted(tau, t, side="right") - 1, clamped to [0, cnt - 2] */
        int64_t lo = 0, hi = cnt;
        const double *tt = P->tau + start;
        while (lo < hi) {
            int64_t mid = lo + (hi - lo) / 2;
            if (tt[mid] <= t) lo = mid + 1; else hi = mid;
        }
        k = lo - 1;
        if (k < 0) k = 0;
        if (k > cnt - 2) k = cnt - 2;
        double dk = P->dtau[start + k];
        if (dk <= 0.0) frac = 0.0;
        else frac = np_min(1.0, np_max(0.0, (t - tt[k]) / dk));
        const double *g0 = P->geom + 10 * (start + k), *g1 = g0 + 10;
        for (int j = 0; j < 10; ++j) g[j] = g0[j] + frac * (g1[j] - g0[j]);
    }
    int64_t row = start + k;
    if (P->reach == 0) S->deficit[i] = 0.0;
    else if (cnt == 1) S->deficit[i] = P->reach[row];
    else S->deficit[i] = P->reach[row] + frac * (P->reach[row + 1] - P->reach[row]);
    double nn = sqrt(g[3] * g[3] + g[4] * g[4] + g[5] * g[5]);
    double *nrm = S->normal + 3 * i;
    if (nn > 1e-9) { nrm[0] = g[3] / nn; nrm[1] = g[4] / nn; nrm[2] = g[5] / nn; }
    else { for (int j = 0; j < 3; ++j) nrm[j] = P->normals[3 * row + j]; }
    double hx = g[6], hy = g[7], hn = hypot(hx, hy);
    if (hn > 1e-9) { hx = hx / hn; hy = hy / hn; }
    else { hx = P->hdir[3 * row]; hy = P->hdir[3 * row + 1]; }
    double d = P->standoff;
    double *pt = S->point + 3 * i, *id = S->ideal + 3 * i, *v = S->velocity + 3 * i;
    pt[0] = g[0]; pt[1] = g[1]; pt[2] = g[2];
    id[0] = g[0] + d * hx; id[1] = g[1] + d * hy; id[2] = g[2];
    S->phase[i] = P->run_phase[r];
    S->s[i] = g[9];
    double A = S->approach_len[i], dir[3] = {0.0, 0.0, 0.0};
    int approaching = t < 0.0 && A > 0.0;
    if (approaching) {
        /* the ideal pose -t from the end of the route (start pose -> via points -> the path's first
           ideal pose), the point carried along with it; dir: the unit direction of travel */
        const double *V = S->approach_pts + 3 * APPROACH_MAX * i;
        int64_t nv = S->approach_nv[i];
        double u = A + t, acc = 0.0, seg = 0.0;   /* u: route length flown from the start */
        int64_t j = 0;
        for (j = 0; j < nv - 1; ++j) {
            const double *v0 = V + 3 * j, *v1 = v0 + 3;
            seg = sqrt((v1[0] - v0[0]) * (v1[0] - v0[0]) + (v1[1] - v0[1]) * (v1[1] - v0[1])
                       + (v1[2] - v0[2]) * (v1[2] - v0[2]));
            if (u <= acc + seg || j == nv - 2) break;
            acc += seg;
        }
        const double *v0 = V + 3 * j, *v1 = v0 + 3;
        double w = seg > 0.0 ? np_min(1.0, np_max(0.0, (u - acc) / seg)) : 1.0;
        for (int c = 0; c < 3; ++c) {
            double target = v0[c] + w * (v1[c] - v0[c]);
            dir[c] = seg > 0.0 ? (v1[c] - v0[c]) / seg : 0.0;
            pt[c] += target - id[c];
            id[c] = target;
        }
        S->deficit[i] = 0.0;
    }
    int moving = !(S->holding[i] || S->done[i]) && (cnt > 1 || approaching);
    S->speed_factor[i] = moving ? sigma : 0.0;
    if (moving && sigma > 0.0 && approaching) {
        double f = sigma * P->approach_speed;
        for (int j = 0; j < 3; ++j) v[j] = f * dir[j];
    } else if (moving && sigma > 0.0) {
        double f = sigma * P->speed;
        for (int j = 0; j < 3; ++j) v[j] = f * P->dp_dtau[3 * row + j];
    } else {
        v[0] = v[1] = v[2] = 0.0;
    }
    double done_len = P->run_offset[r] + (t > 0.0 ? t : 0.0);
    if (P->total_length > 0) S->progress[i] = np_min(1.0, done_len / P->total_length);
    else S->progress[i] = S->done[i] ? 1.0 : 0.0;
    S->s_done[i] = S->done[i];
    S->waiting[i] = S->holding[i];
    S->hold_started[i] = (uint8_t)hold_started;
    S->phase_changed[i] = (uint8_t)phase_changed;
    S->lag[i] = lag;
    S->s_time[i] = S->time[i];
    S->s_stalled[i] = (uint8_t)stalled;
}

/* The samples of drones idx (after a reset): no advance, no flags, lag unknown. */
void wt_ref_sample(const RefPath *P, RefState *S, int64_t m, const int64_t *idx) {
    for (int64_t j = 0; j < m; ++j) ref_sample(P, S, idx[j], 0.0, 0, 0, NAN, 0);
}

/* One drone's step. Closed loop, the point's speed depends on the drone's distance to the ideal pose
 * less the clearance shortfall there (where the ideal pose lies closer to the structure than d_min, the
 * drone can come no nearer than that shortfall, and waiting for it would wait for ever). A drone whose
 * point makes no progress (sigma < STALL_SIGMA) for stall_time seconds stalls, and the stall is counted;
 * with stall_skip its point then moves at the nominal speed, whatever the drone does, until the drone is
 * back within lag_threshold of the ideal pose (or the run ends), the tau so skipped summed; without, the
 * world ends the episode. With stall_skip and a deadline, a drone whose point has fallen so far behind that
 * only the nominal speed from here reaches the path's end by the deadline stalls too, and its point then
 * keeps the nominal speed to the end (PACING): the mission ends by the deadline, never at the time limit
 * because the point waited. */
/* Seconds the point needs from drone i's present place to the path's end at the nominal speeds (the rest
 * of the approach, of its run and the runs after) plus the phase-change holds still to come. */
static double ref_time_to_go(const RefPath *P, const RefState *S, int64_t i) {
    double tau = S->tau[i], t = 0.0;
    int64_t run = S->run[i];
    if (tau < 0.0) { t += -tau / P->approach_speed; tau = 0.0; }
    t += (P->total_length - P->run_offset[run] - tau) / P->speed;   /* this run's rest and the runs after */
    if (!isnan(P->hold_limit)) t += P->hold_limit * (double)(P->n_runs - 1 - run);
    return t;
}

static void ref_step_one(const RefPath *P, RefState *S, int64_t i, double dt, const double *x) {
    const double *q = S->ideal + 3 * i;
    double d0 = x[0] - q[0], d1 = x[1] - q[1], d2 = x[2] - q[2];
    double lag = sqrt(d0 * d0 + d1 * d1 + d2 * d2);
    S->time[i] += dt;
    double sigma = 0.0;
    int hs = 0, pc = 0, st = 0;
    if (S->holding[i] && !S->done[i]) {
        S->hold_elapsed[i] += dt;
        int due = S->release[i] || (!isnan(P->hold_limit) && S->hold_elapsed[i] >= P->hold_limit - 1e-12);
        if (due) {
            S->holding[i] = 0;
            S->release[i] = 0;
            S->run[i] += 1;
            S->tau[i] = 0.0;
            pc = 1;
        }
    } else if (!S->holding[i] && !S->done[i]) {
        double sm = 1.0, e = 0.0;
        if (P->closed) {
            e = lag - S->deficit[i];
            if (e < 0.0) e = 0.0;
            sm = sqrt(np_min(1.0, np_max(0.0, (P->stop - e) * P->inv_band)));
            if (!isnan(P->stall_time) && (P->stall_skip || S->stalls[i] == 0)) {   /* "end": one stall ends it */
                if (S->skipping[i] == PACING) {
                    sm = 1.0;
                } else if (P->stall_skip && !isnan(P->deadline)
                           && S->time[i] + ref_time_to_go(P, S, i) >= P->deadline - 1e-12) {
                    /* so far behind that only the nominal speed from here ends the path by the deadline: a
                     * stall, and the point keeps that speed to the end whatever the drone does */
                    S->stalls[i] += 1;
                    S->stalled_for[i] = 0.0;
                    st = 1;
                    S->skipping[i] = PACING;
                    sm = 1.0;
                } else if (S->skipping[i]) {
                    if (e <= P->lag_threshold) S->skipping[i] = 0;
                    else sm = 1.0;
                } else {
                    S->stalled_for[i] = sm < STALL_SIGMA ? S->stalled_for[i] + dt : 0.0;
                    if (S->stalled_for[i] >= P->stall_time - 1e-12) {
                        S->stalls[i] += 1;
                        S->stalled_for[i] = 0.0;
                        st = 1;
                        if (P->stall_skip) { S->skipping[i] = SKIPPING; sm = 1.0; }
                    }
                }
            }
        }
        sigma = sm;
        double tau0 = S->tau[i];
        if (tau0 < 0.0) {   /* approaching: the segment at its own speed, up to the path's start */
            S->tau[i] += sm * P->approach_speed * dt;
            if (S->tau[i] > 0.0) S->tau[i] = 0.0;
        } else {
            S->tau[i] += sm * P->speed * dt;
        }
        double L = P->run_length[S->run[i]];
        if (S->tau[i] >= L) {
            S->tau[i] = L;
            if (S->run[i] == P->n_runs - 1) {
                S->done[i] = 1;
            } else {
                S->holding[i] = 1;
                S->hold_elapsed[i] = 0.0;
                hs = 1;
            }
        }
        /* path the point passes without the drone: all of a skip, the part of pacing the drone lags on */
        if (S->skipping[i] == SKIPPING || (S->skipping[i] == PACING && e > P->lag_threshold))
            S->skipped[i] += S->tau[i] - tau0;
        if (hs || S->done[i]) {
            if (S->skipping[i] != PACING || S->done[i]) S->skipping[i] = 0;   /* pacing holds to the end */
            S->stalled_for[i] = 0.0;
        }
    }
    ref_sample(P, S, i, sigma, hs, pc, lag, st);
}

/* One control step of every drone's reference given the drone positions (n, 3). */
void wt_ref_step(const RefPath *P, RefState *S, int64_t n, double dt, const double *pos) {
    for (int64_t i = 0; i < n; ++i) ref_step_one(P, S, i, dt, pos + 3 * i);
}

/* ------------------------------------------------------------------------------ metrics */

#define RAD2DEG (180.0 / 3.141592653589793)

typedef struct {
    double *sums;      /* (n, 9): h, hb, herr, d, err^2, inc, o, dist3, path */
    double *mins;      /* (n, 2): h, d */
    double *maxs;      /* (n, 4): herr, d, |err|, inc */
    int64_t *counts;   /* (n, 7): samples, inspecting, safe, collision events, collision samples, new, visible */
    double *t_first, *t_last, *prev;   /* prev: (n, 3) last position */
    uint8_t *prev_col;
    double safety_margin;
} Metrics;

static void metrics_add_one(Metrics *M, int64_t i, double t, const double *x, const double *q, const double *p,
                            const double *nv, int cl, int64_t n_new, int64_t n_vis, int insp, double dref) {
    {
        int64_t *c = M->counts + 7 * i;
        double *sm = M->sums + 9 * i, *mn = M->mins + 2 * i, *mx = M->maxs + 4 * i, *pv = M->prev + 3 * i;
        if (c[0] == 0) {
            M->t_first[i] = t;
        } else {
            double dx = x[0] - pv[0], dy = x[1] - pv[1], dz = x[2] - pv[2];
            sm[8] += sqrt(dx * dx + dy * dy + dz * dz);
        }
        M->t_last[i] = t;
        pv[0] = x[0]; pv[1] = x[1]; pv[2] = x[2];
        c[0] += 1;
        c[3] += cl && !M->prev_col[i];
        c[4] += cl;
        c[5] += n_new;
        c[6] += n_vis;
        M->prev_col[i] = (uint8_t)cl;
        if (!insp) return;
        double qx = q[0], qy = q[1], qz = q[2], qw = q[3];
        double qq = qx * qx + qy * qy + qz * qz + qw * qw;
        double nn = sqrt(nv[0] * nv[0] + nv[1] * nv[1] + nv[2] * nv[2]);
        double ax = p[0] - x[0], ay = p[1] - x[1], az = p[2] - x[2];
        double bx0 = 1.0 - 2.0 * (qy * qy + qz * qz) / qq;
        double bx1 = 2.0 * (qx * qy + qw * qz) / qq;
        double dot = bx0 * ax + bx1 * ay, crs = bx0 * ay - bx1 * ax;
        double d = sqrt(ax * ax + ay * ay), bxy = sqrt(bx0 * bx0 + bx1 * bx1);
        double h, hb, herr;
        if (d > 1e-9 && bxy > 1e-9) { hb = dot / d; h = hb / bxy; herr = RAD2DEG * atan2(fabs(crs), dot); }
        else { h = 0.0; hb = 0.0; herr = 90.0; }
        double u0 = nv[0] / nn, u1 = nv[1] / nn, u2 = nv[2] / nn;
        double a_n = ax * u0 + ay * u1 + az * u2;
        double dist3 = sqrt(ax * ax + ay * ay + az * az);
        double inc;
        if (dist3 > 1e-9) inc = RAD2DEG * acos(np_min(1.0, np_max(-1.0, -a_n / dist3)));
        else inc = 90.0;
        double o0 = ax - a_n * u0, o1 = ay - a_n * u1, o2 = az - a_n * u2;
        double o = sqrt(o0 * o0 + o1 * o1 + o2 * o2);
        double err = d - dref, abs_err = fabs(err);
        c[1] += 1;
        c[2] += abs_err < M->safety_margin;
        sm[0] += h; sm[1] += hb; sm[2] += herr; sm[3] += d; sm[4] += err * err; sm[5] += inc; sm[6] += o;
        sm[7] += dist3;
        mn[0] = np_min(mn[0], h); mn[1] = np_min(mn[1], d);
        mx[0] = np_max(mx[0], herr); mx[1] = np_max(mx[1], d); mx[2] = np_max(mx[2], abs_err);
        mx[3] = np_max(mx[3], inc);
    }
}

/* Add k samples, sample j to drone idx[j] (sequentially: a drone may appear several times, in
 * time order). dref[j * dref_stride] is sample j's reference distance. */
void wt_metrics_add(Metrics *M, int64_t k, const int64_t *idx, const double *t, const double *pos,
                    const double *quat, const double *point, const double *normal, const uint8_t *col,
                    const int64_t *n_new, const int64_t *n_vis, const uint8_t *insp, const double *dref,
                    int64_t dref_stride) {
    for (int64_t j = 0; j < k; ++j)
        metrics_add_one(M, idx[j], t[j], pos + 3 * j, quat + 4 * j, point + 3 * j, normal + 3 * j, col[j] != 0,
                        n_new[j], n_vis[j], insp[j] != 0, dref[j * dref_stride]);
}

/* ------------------------------------------------------------------------------ the task */

typedef struct {
    double coverage, distance, centering, effort, crash, distance_scale, dt;
    int64_t n_triangles;
} RewardWeights;

static int finite_row(const double *x, int k) {
    for (int j = 0; j < k; ++j) if (!isfinite(x[j])) return 0;
    return 1;
}

/* Reward and its five terms (n, 5: coverage, distance, centering, effort, crash) per drone. */
void wt_rewards(const RewardWeights *W, int64_t n, const double *action, const double *hover,
                const double *state, const double *ideal, const double *point, const int64_t *n_new,
                const uint8_t *crashed, double *reward, double *terms) {
    for (int64_t i = 0; i < n; ++i) {
        const double *s = state + 10 * i, *q = ideal + 3 * i, *p = point + 3 * i, *a = action + 4 * i;
        double *tm = terms + 5 * i;
        int fin = finite_row(s, 10);
        double st[10];
        for (int j = 0; j < 10; ++j) st[j] = fin ? s[j] : 0.0;
        double d0 = st[0] - q[0], d1 = st[1] - q[1], d2 = st[2] - q[2];
        double e = sqrt(d0 * d0 + d1 * d1 + d2 * d2);
        double a0 = p[0] - st[0], a1 = p[1] - st[1];
        double axy = hypot(a0, a1);
        double qx = st[6], qy = st[7], qz = st[8], qw = st[9];
        double fwd0 = 1 - 2 * (qy * qy + qz * qz), fwd1 = 2 * (qx * qy + qw * qz);
        double h = axy > 1e-9 ? (fwd0 * a0 + fwd1 * a1) / axy : 0.0;
        double r = e / W->distance_scale;
        double gauss = exp(-0.5 * (r * r));
        double u0 = a[0] - hover[0], u1 = a[1] - hover[1], u2 = a[2] - hover[2], u3 = a[3] - hover[3];
        double effort = ((u0 * u0 + u1 * u1) + u2 * u2) + u3 * u3;
        tm[0] = fin ? W->coverage * (double)n_new[i] / (double)W->n_triangles : 0.0;
        tm[1] = fin ? W->distance * W->dt * gauss : 0.0;
        tm[2] = fin ? W->centering * W->dt * h : 0.0;
        tm[3] = fin ? -W->effort * W->dt * effort : 0.0;
        tm[4] = (crashed[i] || !fin) ? -W->crash : 0.0;
        reward[i] = (((tm[0] + tm[1]) + tm[2]) + tm[3]) + tm[4];
    }
}

/* Termination codes (0 on, 1 non-finite, 2 collision, 3 left the working volume, 4 lost the pose);
 * limit NaN: no pose-error limit. */
void wt_terminations(int64_t n, const double *state, const uint8_t *collision, const double *lo,
                     const double *hi, const double *ideal, const uint8_t *waiting, double limit,
                     int64_t *code) {
    for (int64_t i = 0; i < n; ++i) {
        const double *s = state + 10 * i;
        if (!finite_row(s, 10)) { code[i] = 1; continue; }
        if (collision[i]) { code[i] = 2; continue; }
        int left = 0;
        for (int j = 0; j < 3; ++j) left |= (s[j] < lo[3 * i + j]) || (s[j] > hi[3 * i + j]);
        if (left) { code[i] = 3; continue; }
        code[i] = 0;
        if (!isnan(limit) && !waiting[i]) {
            const double *q = ideal + 3 * i;
            double e0 = s[0] - q[0], e1 = s[1] - q[1], e2 = s[2] - q[2];
            if (sqrt(e0 * e0 + e1 * e1 + e2 * e2) > limit) code[i] = 4;
        }
    }
}

static double safe_value(double v, int safe) {
    if (!safe) return v;
    return isfinite(v) ? v : 0.0;      /* NaN and +-inf -> 0 */
}

static float clip1(double v) { return (float)(v < -1.0 ? -1.0 : (v > 1.0 ? 1.0 : v)); }

/* The Dict observation's 24 floats per drone: position 3, velocity_body 3, quaternion 4,
 * body_rates 3, point 3, normal 3, point_velocity 3, coverage 1, progress 1. Rows flagged safe
 * (non-finite states) have NaN/inf replaced by 0. */
void wt_observations(int64_t n, const double *state, const double *rates, const double *point,
                     const double *normal, const double *pvel, const double *coverage,
                     const double *progress, const uint8_t *safe, float *out) {
    for (int64_t i = 0; i < n; ++i) {
        const double *s = state + 10 * i, *w = rates + 3 * i;
        int sf = safe[i] != 0;
        float *o = out + 24 * i;
        double st[10];
        for (int j = 0; j < 10; ++j) st[j] = safe_value(s[j], sf);
        for (int j = 0; j < 6; ++j) o[j] = (float)st[j];
        double qx = st[6], qy = st[7], qz = st[8], qw = st[9];
        double nq = sqrt(qx * qx + qy * qy + qz * qz + qw * qw);
        if (nq > 1e-9) { o[6] = clip1(qx / nq); o[7] = clip1(qy / nq); o[8] = clip1(qz / nq); o[9] = clip1(qw / nq); }
        else { o[6] = 0.0f; o[7] = 0.0f; o[8] = 0.0f; o[9] = 1.0f; }
        for (int j = 0; j < 3; ++j) {
            o[10 + j] = (float)safe_value(w[j], sf);
            o[13 + j] = (float)point[3 * i + j];
            o[16 + j] = clip1(normal[3 * i + j]);
            o[19 + j] = (float)pvel[3 * i + j];
        }
        double cv = coverage[i];
        o[22] = (float)(cv > 1.0 ? 1.0 : cv);
        double pg = progress[i];
        o[23] = (float)(pg > 1.0 ? 1.0 : (pg < 0.0 ? 0.0 : pg));
    }
}

/* ------------------------------------------------------------------------------ body frame */

/* Model state [p, v_body, q] (n, 10) and body rates (n, 3) from the world-frame flight state,
 * with the rotation Bullet's btMatrix3x3::setRotation builds from the quaternion (x, y, z, w):
 * the same operations, so the same numbers as p.getMatrixFromQuaternion. */
void wt_body_frame(int64_t n, const double *pos, const double *vel, const double *omega, const double *quat,
                   double *state, double *rates) {
    for (int64_t i = 0; i < n; ++i) {
        const double *q = quat + 4 * i, *v = vel + 3 * i, *w = omega + 3 * i, *p = pos + 3 * i;
        double x = q[0], y = q[1], z = q[2], qw = q[3];
        double s = 2.0 / (x * x + y * y + z * z + qw * qw);
        double xs = x * s, ys = y * s, zs = z * s;
        double wx = qw * xs, wy = qw * ys, wz = qw * zs;
        double xx = x * xs, xy = x * ys, xz = x * zs;
        double yy = y * ys, yz = y * zs, zz = z * zs;
        double R[9] = {1.0 - (yy + zz), xy - wz, xz + wy,
                       xy + wz, 1.0 - (xx + zz), yz - wx,
                       xz - wy, yz + wx, 1.0 - (xx + yy)};
        double *st = state + 10 * i, *r = rates + 3 * i;
        st[0] = p[0]; st[1] = p[1]; st[2] = p[2];
        st[3] = R[0] * v[0] + R[3] * v[1] + R[6] * v[2];
        st[4] = R[1] * v[0] + R[4] * v[1] + R[7] * v[2];
        st[5] = R[2] * v[0] + R[5] * v[1] + R[8] * v[2];
        st[6] = q[0]; st[7] = q[1]; st[8] = q[2]; st[9] = q[3];
        r[0] = R[0] * w[0] + R[3] * w[1] + R[6] * w[2];
        r[1] = R[1] * w[0] + R[4] * w[1] + R[7] * w[2];
        r[2] = R[2] * w[0] + R[5] * w[1] + R[8] * w[2];
    }
}

/* ------------------------------------------------------------------------------ camera */

typedef struct {
    int64_t m;                   /* triangles */
    const double *vertices;      /* (m, 3, 3) */
    const double *normals;       /* (m, 3) unit */
    const double *centroids;     /* (m, 3) */
    const double *n_dot_c;       /* (m,) n . c */
    const double *c_sq;          /* (m,) |c|^2 */
    double fov_scale[3];         /* fx/cx, fy/cy, 1 */
    double max_range, cos_max_incidence;
    int64_t incidence_from_axis, range_from_vertices;
} Visibility;

/* Per camera j (origins (k, 3), R_world_from_cam (k, 3, 3)): the sorted indices of the triangles
 * that pass every test but occlusion (the coverage rule of coverage.py), written to
 * out[start[j] .. start[j + 1]) (start has k + 1 entries; out must hold k * m). */
void wt_in_view(const Visibility *V, int64_t k, const double *origins, const double *Rs, int64_t *start,
                int64_t *out) {
    int64_t w = 0, m = V->m;
    double r2max = V->max_range * V->max_range, cos2 = V->cos_max_incidence * V->cos_max_incidence;
    for (int64_t j = 0; j < k; ++j) {
        start[j] = w;
        const double *o = origins + 3 * j, *R = Rs + 9 * j;
        double ox = o[0], oy = o[1], oz = o[2], oo = ox * ox + oy * oy + oz * oz;
        double S[9];
        for (int a = 0; a < 3; ++a)
            for (int b = 0; b < 3; ++b) S[3 * a + b] = R[3 * a + b] * V->fov_scale[b];
        for (int64_t t = 0; t < m; ++t) {
            const double *nr = V->normals + 3 * t, *c = V->centroids + 3 * t;
            double n_dot_v = (nr[0] * ox + nr[1] * oy + nr[2] * oz) - V->n_dot_c[t];
            double c_dot_o = c[0] * ox + c[1] * oy + c[2] * oz;
            double dist_sq = (V->c_sq[t] - 2.0 * c_dot_o) + oo;
            if (!(n_dot_v > 0.0 && dist_sq <= r2max)) continue;
            if (V->incidence_from_axis) {
                double cos_inc = -(nr[0] * R[2] + nr[1] * R[5] + nr[2] * R[8]);
                if (!(cos_inc > V->cos_max_incidence)) continue;
            } else if (!(n_dot_v * n_dot_v > cos2 * dist_sq)) {
                continue;
            }
            const double *vx = V->vertices + 9 * t;
            int keep = 1;
            for (int q = 0; q < 3 && keep; ++q) {
                double r0 = vx[3 * q] - ox, r1 = vx[3 * q + 1] - oy, r2 = vx[3 * q + 2] - oz;
                double p0 = r0 * S[0] + r1 * S[3] + r2 * S[6];
                double p1 = r0 * S[1] + r1 * S[4] + r2 * S[7];
                double p2 = r0 * S[2] + r1 * S[5] + r2 * S[8];
                double a0 = fabs(p0), a1 = fabs(p1);
                double big = a0 > a1 ? a0 : a1;
                int inside = big <= p2 && p2 > 0.0;
                if (V->range_from_vertices) inside = inside && (r0 * r0 + r1 * r1 + r2 * r2) <= r2max;
                keep = inside;
            }
            if (keep) out[w++] = t;
        }
    }
    start[k] = w;
}

/* Wind speeds of k gust fields at their times: mean + amplitude sin(2 pi t / period + phase). */
void wt_gust_speeds(int64_t k, const double *mean, const double *amplitude, const double *period,
                    const double *phase, const double *t, double *out) {
    for (int64_t j = 0; j < k; ++j)
        out[j] = mean[j] + amplitude[j] * sin(2 * 3.141592653589793 * t[j] / period[j] + phase[j]);
}

/* ------------------------------------------------------------------------------ the world step */

typedef struct {
    int64_t n;
    const RefPath *path; RefState *ref; Metrics *metrics; const RewardWeights *weights;
    const double *state, *rates;        /* the body frame after the flight step, (n, 10), (n, 3) */
    const int64_t *steps; double dt;    /* episode steps per drone; control period */
    uint8_t *finite;                    /* out of wt_world_advance */
    const uint8_t *collision;           /* touched the ground or the turbine during the step */
    const int64_t *n_new, *n_vis;       /* this step's camera frame per drone (0 without one) */
    const double *actions, *hover;      /* normalised actions (n, 4), hover action (4) */
    const double *lo, *hi; double pose_limit;      /* working volume (n, 3) each; NaN: no pose limit */
    double *done_time; double end_hold, time_limit;
    const int64_t *n_seen; double d_ref;
    int64_t *code; double *reward, *terms; uint8_t *terminated, *truncated, *complete; float *obs;
} WorldStep;

/* After the flight step: which drones are finite, and every drone's reference advanced (a
 * non-finite drone as if at its ideal pose). */
void wt_world_advance(WorldStep *W) {
    for (int64_t i = 0; i < W->n; ++i) {
        const double *s = W->state + 10 * i;
        int fin = finite_row(s, 10);
        W->finite[i] = (uint8_t)fin;
        double x[3];
        for (int j = 0; j < 3; ++j) x[j] = fin ? s[j] : W->ref->ideal[3 * i + j];
        ref_step_one(W->path, W->ref, i, W->dt, x);
    }
}

/* After the camera frames: metrics, termination, reward, completion and observation per drone. */
void wt_world_finish(WorldStep *W) {
    RefState *R = W->ref;
    for (int64_t i = 0; i < W->n; ++i) {
        const double *s = W->state + 10 * i;
        double t = (double)W->steps[i] * W->dt;
        int fin = W->finite[i];
        if (fin)
            metrics_add_one(W->metrics, i, t, s, s + 6, R->point + 3 * i, R->normal + 3 * i, W->collision[i] != 0,
                            W->n_new[i], W->n_vis[i], !R->waiting[i], W->d_ref);
        wt_terminations(1, s, W->collision + i, W->lo + 3 * i, W->hi + 3 * i, R->ideal + 3 * i, R->waiting + i,
                        W->pose_limit, W->code + i);
        W->terminated[i] = W->code[i] > 0;
        wt_rewards(W->weights, 1, W->actions + 4 * i, W->hover, s, R->ideal + 3 * i, R->point + 3 * i, W->n_new + i,
                   W->terminated + i, W->reward + i, W->terms + 5 * i);
        if (R->s_done[i] && isnan(W->done_time[i])) W->done_time[i] = t;
        int complete = !isnan(W->done_time[i]) && t >= W->done_time[i] + W->end_hold - 1e-9;
        W->complete[i] = (uint8_t)complete;
        int stalled = R->stalls[i] > 0 && !W->path->stall_skip;
        W->truncated[i] = !W->terminated[i] && (complete || t >= W->time_limit - 1e-9 || stalled);
        double cov = (double)W->n_seen[i] / (double)W->weights->n_triangles;
        uint8_t safe = !fin;
        wt_observations(1, s, W->rates + 3 * i, R->point + 3 * i, R->normal + 3 * i, R->velocity + 3 * i, &cov,
                        R->progress + i, &safe, W->obs + 24 * i);
    }
}
