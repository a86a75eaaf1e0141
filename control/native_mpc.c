/* The coin task's MPC in C (deapull.control.native): f_a's step with its analytic Jacobians
 * and the batched box-iLQR of deapull.control.mpc.solve for n = 3, m = 1.
 *
 * The step is CoinDynamics (control/task.py) on the tip-contact model f-coulomb
 * (surrogate/models/tip_contact.py): the material network m evaluated as the exact
 * piecewise-affine function it is (TipContactModel.material_pieces), the coin's
 * backward-Euler step solved by the same bracketed Newton iteration as tip_coin_step (with
 * that function's stopping rule applied per row), and the Jacobians of the step from the
 * implicit-function theorem at the root, the same derivatives the torch model's
 * autograd gives. The solver repeats mpc.solve operation for operation (backward pass with
 * the closed-form box QP of m = 1, parallel line search over the same step sizes, the same
 * Levenberg–Marquardt schedule), one row after another; rows are independent there too.
 *
 * Layout of the parameter block `p` (doubles), filled by control/native.py:
 *   0 mean, 1 scale of t = (V − mean)/scale, 2 stroke_scale, 3 fy_mean, 4 fy_scale,
 *   5 m_c, 6 μ_b, 7 μ_t, 8 g, 9 ε_v, 10 Δt, 11 ΔV_max, 12 V_max, 13 iterations,
 *   14 x unit, 15 u unit, 16 V unit, 17 raw output o_0 at 0 V
 * and the pieces: knots (K+1), slope (K, 2), intercept (K, 2).
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "coin_step.h"   /* reg, coin_root: the coin's step (surrogate/coin_step.h) */

typedef struct {
    int K;
    const double *knots, *slope, *intercept;
    double mean, scale, sx, fym, fys, mass, mu_b, mu_t, grav, eps, dt, dvmax, vmax, xu, uu, vu, rest;
    int iterations;
} Model;

static Model model_of(const double *p, int K, const double *knots, const double *slope, const double *intercept)
{
    Model M;
    M.K = K; M.knots = knots; M.slope = slope; M.intercept = intercept;
    M.mean = p[0]; M.scale = p[1]; M.sx = p[2]; M.fym = p[3]; M.fys = p[4];
    M.mass = p[5]; M.mu_b = p[6]; M.mu_t = p[7]; M.grav = p[8]; M.eps = p[9];
    M.dt = p[10]; M.dvmax = p[11]; M.vmax = p[12]; M.iterations = (int)p[13];
    M.xu = p[14]; M.uu = p[15]; M.vu = p[16]; M.rest = p[17];
    return M;
}

/* X(V), dX/dV, Fy(V), dFy/dV */
static void material(const Model *M, double V, double *X, double *dX, double *Fy, double *dFy)
{
    double t = (V - M->mean) / M->scale;
    int lo = 0, hi = M->K - 1;
    while (lo < hi) {
        int mid = (lo + hi + 1) >> 1;
        if (M->knots[mid] <= t) lo = mid; else hi = mid - 1;
    }
    double s0 = M->slope[2 * lo], s1 = M->slope[2 * lo + 1];
    double o0 = s0 * t + M->intercept[2 * lo], o1 = s1 * t + M->intercept[2 * lo + 1];
    *X = M->sx * (o0 - M->rest);
    *dX = M->sx * s0 / M->scale;
    *Fy = M->fym + M->fys * o1;
    *dFy = M->fys * s1 / M->scale;
}

/* One step ξ' = f(ξ, ν) in scaled units; A (3×3, row-major) = ∂ξ'/∂ξ and Bv (3) = ∂ξ'/∂ν
 * when A is not NULL. */
static void step(const Model *M, const double *xi, double nu, double *out, double *A, double *Bv)
{
    const double dt = M->dt, eps = M->eps;
    double x = xi[0] * M->xu, u = xi[1] * M->uu, V = xi[2] * M->vu;
    double Vr = V + nu * M->dvmax;
    double Vn = fmin(fmax(Vr, 0.0), M->vmax);
    double mask = (Vr >= 0.0 && Vr <= M->vmax) ? 1.0 : 0.0;
    double Xp, dXp, Fp, dFp, Xn, dXn, Fy, dFy;
    material(M, V, &Xp, &dXp, &Fp, &dFp);
    material(M, Vn, &Xn, &dXn, &Fy, &dFy);
    double normal_raw = M->mass * M->grav + Fy;
    double normal = normal_raw > 0.0 ? normal_raw : 0.0, dnormal = normal_raw >= 0.0 ? dFy : 0.0;
    double fyc = Fy > 0.0 ? Fy : 0.0, dfyc = Fy >= 0.0 ? dFy : 0.0;
    double w = (Xn - Xp) / dt;
    double cap_t = M->mu_t * fyc, cap_b = M->mu_b * normal;
    /* tip_coin_step */
    double c = M->mass / dt;
    CoinRoot root = coin_root(c, u, w, cap_t, cap_b, eps, M->iterations);
    int stuck = root.stuck;
    double sign = root.sign, sl = root.slope, v = root.v;
    double y = w - root.root, q = y * y + eps * eps;
    double g = eps * eps / (q * sqrt(q));
    double regy = reg(y, eps);
    double un = stuck ? 0.0 : v;
    out[0] = (x + dt * un) / M->xu;
    out[1] = un / M->uu;
    out[2] = Vn / M->vu;
    if (!A) return;
    double du_du = 0.0, du_dV = 0.0, du_dnu = 0.0;
    if (!stuck) {
        double du_dw = cap_t * g / sl, du_dct = regy / sl, du_dcb = -sign / sl;
        double dcap = du_dct * M->mu_t * dfyc + du_dcb * M->mu_b * dnormal;   /* d u'/d V' through the caps */
        du_du = c / sl;
        du_dV = du_dw * (dXn * mask - dXp) / dt + dcap * mask;
        du_dnu = (du_dw * dXn / dt + dcap) * mask * M->dvmax;
    }
    A[0] = 1.0; A[1] = dt * du_du * M->uu / M->xu; A[2] = dt * du_dV * M->vu / M->xu;
    A[3] = 0.0; A[4] = du_du;                      A[5] = du_dV * M->vu / M->uu;
    A[6] = 0.0; A[7] = 0.0;                        A[8] = mask;
    Bv[0] = dt * du_dnu / M->xu;
    Bv[1] = du_dnu / M->uu;
    Bv[2] = mask * M->dvmax / M->vu;
}

/* N independent steps: xi (N, 3), nu (N) -> out (N, 3), A (N, 3, 3), Bv (N, 3) (A may be NULL) */
int deapull_coin_step(const double *p, int K, const double *knots, const double *slope, const double *intercept,
                      int N, const double *xi, const double *nu, double *out, double *A, double *Bv)
{
    Model M = model_of(p, K, knots, slope, intercept);
    for (int i = 0; i < N; i++)
        step(&M, xi + 3 * i, nu[i], out + 3 * i, A ? A + 9 * i : NULL, A ? Bv + 3 * i : NULL);
    return 0;
}

/* rollouts: x0 (B, 3), u (B, T) -> xs (B, T+1, 3) */
int deapull_coin_rollout(const double *p, int K, const double *knots, const double *slope, const double *intercept,
                         int B, int T, const double *x0, const double *u, double *xs)
{
    Model M = model_of(p, K, knots, slope, intercept);
    for (int b = 0; b < B; b++) {
        double *x = xs + (size_t)b * (T + 1) * 3;
        memcpy(x, x0 + 3 * b, 3 * sizeof(double));
        for (int t = 0; t < T; t++) step(&M, x + 3 * t, u[b * T + t], x + 3 * (t + 1), NULL, NULL);
    }
    return 0;
}

/* ---- the solver ---- */

typedef struct {
    const double *C, *c, *Cf, *cf;   /* 4×4, 4, 3×3 or NULL, 3 or NULL */
} Cost;

static double stage_cost(const Cost *Q, const double *x, double u)
{
    double tau[4] = {x[0], x[1], x[2], u};
    double quad = 0.0, lin = 0.0;
    for (int i = 0; i < 4; i++) {
        double row = 0.0;
        for (int j = 0; j < 4; j++) row += Q->C[4 * i + j] * tau[j];
        quad += tau[i] * row;
        lin += Q->c[i] * tau[i];
    }
    return 0.5 * quad + lin;
}

static double final_cost(const Cost *Q, const double *x)
{
    double value = 0.0;
    if (Q->Cf) {
        double quad = 0.0;
        for (int i = 0; i < 3; i++) {
            double row = 0.0;
            for (int j = 0; j < 3; j++) row += Q->Cf[3 * i + j] * x[j];
            quad += x[i] * row;
        }
        value += 0.5 * quad;
    }
    if (Q->cf)
        for (int i = 0; i < 3; i++) value += Q->cf[i] * x[i];
    return value;
}

/* roll out from x (T+1, 3)[0] under u (T), keeping Jacobians; returns the cost (inf if not finite) */
static double roll(const Model *M, const Cost *Q, int T, double *x, const double *u, double *A, double *Bv)
{
    double J = 0.0;
    for (int t = 0; t < T; t++) {
        step(M, x + 3 * t, u[t], x + 3 * (t + 1), A + 9 * t, Bv + 3 * t);
        J += stage_cost(Q, x + 3 * t, u[t]);
    }
    J += final_cost(Q, x + 3 * T);
    return isfinite(J) ? J : INFINITY;
}

/* the backward pass of mpc.backward_pass for n = 3, m = 1; returns ok */
static int backward(const Cost *Q, int T, const double *x, const double *u, const double *A, const double *Bv,
                    const double *lo, const double *hi, double mu, double *k, double *K)
{
    double Vx[3] = {0, 0, 0}, Vxx[9] = {0};
    if (Q->Cf) memcpy(Vxx, Q->Cf, 9 * sizeof(double));
    for (int i = 0; i < 3; i++) {
        for (int j = 0; j < 3; j++) Vx[i] += Vxx[3 * i + j] * x[3 * T + j];
        if (Q->cf) Vx[i] += Q->cf[i];
    }
    int ok = 1;
    for (int t = T - 1; t >= 0; t--) {
        const double *At = A + 9 * t, *Bt = Bv + 3 * t, *xt = x + 3 * t;
        double tau[4] = {xt[0], xt[1], xt[2], u[t]}, grad[4];
        for (int i = 0; i < 4; i++) {
            grad[i] = Q->c[i];
            for (int j = 0; j < 4; j++) grad[i] += Q->C[4 * i + j] * tau[j];
        }
        double Qx[3], Qu = grad[3], BV[3], AV[9], Qxx[9], Quu, Qux[3], BtB = 0.0, BtA[3];
        for (int j = 0; j < 3; j++) {
            Qx[j] = grad[j];
            for (int i = 0; i < 3; i++) Qx[j] += At[3 * i + j] * Vx[i];
            Qu += Bt[j] * Vx[j];
            BtB += Bt[j] * Bt[j];
        }
        for (int j = 0; j < 3; j++) {
            BV[j] = 0.0;
            for (int i = 0; i < 3; i++) BV[j] += Bt[i] * Vxx[3 * i + j];
        }
        for (int i = 0; i < 3; i++)          /* AV = Aᵀ Vxx */
            for (int j = 0; j < 3; j++) {
                double s = 0.0;
                for (int l = 0; l < 3; l++) s += At[3 * l + i] * Vxx[3 * l + j];
                AV[3 * i + j] = s;
            }
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++) {
                double s = 0.0;
                for (int l = 0; l < 3; l++) s += AV[3 * i + l] * At[3 * l + j];
                Qxx[3 * i + j] = Q->C[4 * i + j] + s;
            }
        Quu = Q->C[15];
        for (int j = 0; j < 3; j++) Quu += BV[j] * Bt[j];
        for (int j = 0; j < 3; j++) {
            double s = 0.0, s2 = 0.0;
            for (int l = 0; l < 3; l++) { s += BV[l] * At[3 * l + j]; s2 += Bt[l] * At[3 * l + j]; }
            Qux[j] = Q->C[12 + j] + s;
            BtA[j] = s2;
        }
        double h = Quu + mu * BtB, Qux_r[3];
        for (int j = 0; j < 3; j++) Qux_r[j] = Qux[j] + mu * BtA[j];
        int okt = h > 0.0;
        ok = ok && okt;
        double d = okt ? -Qu / h : 0.0, dlo = lo[t] - u[t], dhi = hi[t] - u[t];
        double kt = fmin(fmax(d, dlo), dhi);
        int free_ = d > dlo && d < dhi;
        double *Kt = K + 3 * t;
        for (int j = 0; j < 3; j++) Kt[j] = (free_ && okt) ? -Qux_r[j] / h : 0.0;
        k[t] = kt;
        double a = Quu * kt + Qu;
        for (int i = 0; i < 3; i++) Vx[i] = Qx[i] + Kt[i] * a + Qux[i] * kt;
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++)
                Vxx[3 * i + j] = Qxx[3 * i + j] + Kt[i] * Quu * Kt[j] + Kt[i] * Qux[j] + Qux[i] * Kt[j];
        for (int i = 0; i < 3; i++)
            for (int j = i + 1; j < 3; j++) {
                double s = 0.5 * (Vxx[3 * i + j] + Vxx[3 * j + i]);
                Vxx[3 * i + j] = Vxx[3 * j + i] = s;
            }
    }
    return ok;
}

/* mpc.solve for B rows: x0 (B, 3), u (B, T) in: the initial guess, out: the plan; lo, hi (B, T);
 * xs (B, T+1, 3), cost (B), mu (B) in: μ0, out: final μ; history (B, iterations+1).
 * Returns the iterations run, or −1 when out of memory. */
int deapull_coin_ilqr(const double *p, int K, const double *knots, const double *slope, const double *intercept,
                      const double *C, const double *c, const double *Cf, const double *cf, int has_Cf, int has_cf,
                      int B, int T, int iterations, int S, const double *alphas, double tol,
                      const double *x0, double *u, const double *lo, const double *hi,
                      double *xs, double *cost, double *mu, double *history)
{
    Model M = model_of(p, K, knots, slope, intercept);
    Cost Q = {C, c, has_Cf ? Cf : NULL, has_cf ? cf : NULL};
    size_t per = (size_t)T * 12 + (size_t)(T + 1) * 3 + T;       /* A, Bv, x, u of one trajectory */
    double *work = malloc(sizeof(double) * ((size_t)B * per + (size_t)S * per + 4 * (size_t)T + 8));
    if (!work) return -1;
    double *nomA = work, *trial = work + (size_t)B * per, *k = trial + (size_t)S * per, *Kg = k + T;
    int *done_rows = NULL;
    /* nominal rollouts */
    for (int b = 0; b < B; b++) {
        double *x = xs + (size_t)b * (T + 1) * 3, *ub = u + (size_t)b * T;
        for (int t = 0; t < T; t++) ub[t] = fmin(fmax(ub[t], lo[b * T + t]), hi[b * T + t]);
        memcpy(x, x0 + 3 * b, 3 * sizeof(double));
        cost[b] = roll(&M, &Q, T, x, ub, nomA + (size_t)b * per, nomA + (size_t)b * per + 9 * T);
        history[(size_t)b * (iterations + 1)] = cost[b];
    }
    (void)done_rows;
    int done = 0;
    for (int it = 1; it <= iterations; it++) {
        done = it;
        int all_small = 1;
        for (int b = 0; b < B; b++) {
            double *x = xs + (size_t)b * (T + 1) * 3, *ub = u + (size_t)b * T;
            double *A = nomA + (size_t)b * per, *Bv = A + 9 * T;
            const double *lob = lo + (size_t)b * T, *hib = hi + (size_t)b * T;
            int ok = backward(&Q, T, x, ub, A, Bv, lob, hib, mu[b], k, Kg);
            double best = INFINITY;
            int best_s = 0;
            for (int s = 0; s < S; s++) {
                double *tA = trial + (size_t)s * per, *tB = tA + 9 * T, *tx = tB + 3 * T, *tu = tx + 3 * (T + 1);
                double J = 0.0;
                memcpy(tx, x0 + 3 * b, 3 * sizeof(double));
                for (int t = 0; t < T; t++) {
                    const double *xb = x + 3 * t, *xc = tx + 3 * t, *Kt = Kg + 3 * t;
                    double ut = ub[t] + alphas[s] * k[t]
                                + (Kt[0] * (xc[0] - xb[0]) + Kt[1] * (xc[1] - xb[1]) + Kt[2] * (xc[2] - xb[2]));
                    ut = fmin(fmax(ut, lob[t]), hib[t]);
                    tu[t] = ut;
                    step(&M, xc, ut, tx + 3 * (t + 1), tA + 9 * t, tB + 3 * t);
                    J += stage_cost(&Q, xc, ut);
                }
                J += final_cost(&Q, tx + 3 * T);
                if (!isfinite(J)) J = INFINITY;
                if (J < best) { best = J; best_s = s; }
            }
            int better = ok && best < cost[b];
            double gain = cost[b] - best;
            if (better) {
                double *tA = trial + (size_t)best_s * per, *tx = tA + 12 * T, *tu = tx + 3 * (T + 1);
                memcpy(A, tA, 12 * (size_t)T * sizeof(double));
                memcpy(x, tx, 3 * (size_t)(T + 1) * sizeof(double));
                memcpy(ub, tu, (size_t)T * sizeof(double));
                cost[b] = best;
                mu[b] = mu[b] / 10.0 < 1e-6 ? 0.0 : mu[b] / 10.0;
            } else {
                mu[b] = fmin(fmax(mu[b] * 10.0, 1e-6), 1e10);
            }
            history[(size_t)b * (iterations + 1) + it] = cost[b];
            if (better && !(gain <= tol * (1.0 + fabs(cost[b])))) all_small = 0;
        }
        if (tol > 0.0 && all_small) break;
    }
    free(work);
    return done;
}

/* ---- online inference (control/inference.py, tip-contact model) ----
 * For n buffered transitions with the φ-free parts cached (x, u = observed velocity, Δt,
 * the tip's stroke before and after, Fy after) and one coin φ = (m_c, μ_b, μ_t): the
 * predicted next position x̂ (Predictor.predict), the stick shortfall (cap_b − |R|)⁺ Δt/m_c
 * (Predictor.stick_shortfall), and when dpred is not NULL their derivatives with respect
 * to log m_c, log μ_b, log μ_t (n, 3), from the implicit-function theorem at the root as
 * autograd through the torch model gives them. */
int deapull_coin_predict(int n, const double *x, const double *u, const double *dts, const double *stroke_prev,
                         const double *stroke, const double *fy_in, const double *phys,
                         double *pred, double *dpred, double *shortfall, double *dshort)
{
    const double mass = phys[0], mu_b = phys[1], mu_t = phys[2], grav = phys[3], eps = phys[4];
    const int iterations = (int)phys[5];
    for (int i = 0; i < n; i++) {
        double dt = dts[i], Fy = fy_in[i], ui = u[i];
        double normal_raw = mass * grav + Fy;
        double normal = normal_raw > 0.0 ? normal_raw : 0.0, dnormal_dm = normal_raw >= 0.0 ? grav : 0.0;
        double fyc = Fy > 0.0 ? Fy : 0.0;
        double w = (stroke[i] - stroke_prev[i]) / dt;
        double cap_t = mu_t * fyc, cap_b = mu_b * normal;
        double c = mass / dt;
        double tip_rest = cap_t * reg(w, eps);
        CoinRoot root = coin_root(c, ui, w, cap_t, cap_b, eps, iterations);
        int stuck = root.stuck;
        double sign = root.sign, sl = root.slope, v0 = root.root, v = root.v, regy = reg(w - v0, eps);
        double un = stuck ? 0.0 : v;
        pred[i] = x[i] + dt * un;
        /* the stick shortfall */
        double R = tip_rest + c * ui, D = cap_b - fabs(R);
        shortfall[i] = (D > 0.0 ? D : 0.0) * dt / mass;
        if (!dpred) continue;
        if (stuck) {
            dpred[3 * i] = dpred[3 * i + 1] = dpred[3 * i + 2] = 0.0;
        } else {
            /* dv/dθ = −(∂r/∂θ)/slope at the root, ×θ for log θ */
            double dr_dm = (v0 - ui) / dt + sign * mu_b * dnormal_dm;
            double dr_dmub = sign * normal, dr_dmut = -fyc * regy;
            dpred[3 * i] = -dt * dr_dm / sl * mass;
            dpred[3 * i + 1] = -dt * dr_dmub / sl * mu_b;
            dpred[3 * i + 2] = -dt * dr_dmut / sl * mu_t;
        }
        if (D > 0.0) {
            double sR = R > 0.0 ? 1.0 : (R < 0.0 ? -1.0 : 0.0);
            double dD_dm = mu_b * dnormal_dm - sR * ui / dt;
            dshort[3 * i] = (dD_dm * dt / mass - D * dt / (mass * mass)) * mass;
            dshort[3 * i + 1] = normal * dt / mass * mu_b;
            dshort[3 * i + 2] = -sR * fyc * reg(w, eps) * dt / mass * mu_t;
        } else {
            dshort[3 * i] = dshort[3 * i + 1] = dshort[3 * i + 2] = 0.0;
        }
    }
    return 0;
}
