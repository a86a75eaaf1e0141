/* The batched box-iLQR of deapull.control.mpc.solve for m = 1, the one C definition of it:
 * included by control/native_mpc.c (f-coulomb, n = 3) and control/native_mpc_memory.c
 * (f-memory, n = 5), whose f_a steps differ but whose solvers are the same passes over a
 * state of another width. Written once so that a fix to the solver reaches both models;
 * compiled by deapull.surrogate.native.compiled, which keys its cache on this header's text
 * too (control/native.py: HEADERS).
 *
 * The including file defines, before the #include:
 *   NX              the state's width n;
 *   ILQR_EXPORT(s)  the exported name of entry point s (step, rollout, ilqr), e.g.
 *                   deapull_coin_##s: the names control/native.py's _declare binds;
 *   Model, model_of(p, K, knots, slope, intercept) and
 *   step(const Model *, const double *xi, double nu, double *out, double *A, double *Bv):
 *                   the model's parameters and one step ξ' = f(ξ, ν) with A = ∂ξ'/∂ξ (NX×NX,
 *                   row-major) and Bv = ∂ξ'/∂ν (NX) when A is not NULL.
 *
 * The passes repeat mpc.solve operation for operation (backward pass with the closed-form box
 * QP of m = 1, parallel line search over the same step sizes, the same Levenberg–Marquardt
 * schedule), one row after another; rows are independent there too.
 */
#ifndef DEAPULL_ILQR_PASSES_H
#define DEAPULL_ILQR_PASSES_H

#if !defined(NX) || !defined(ILQR_EXPORT)
#error "define NX and ILQR_EXPORT(name) (and Model, model_of, step) before including ilqr_passes.h"
#endif

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* N independent steps: xi (N, NX), nu (N) -> out (N, NX), A (N, NX, NX), Bv (N, NX) (A may be NULL) */
int ILQR_EXPORT(step)(const double *p, int K, const double *knots, const double *slope, const double *intercept,
                      int N, const double *xi, const double *nu, double *out, double *A, double *Bv)
{
    Model M = model_of(p, K, knots, slope, intercept);
    for (int i = 0; i < N; i++)
        step(&M, xi + NX * i, nu[i], out + NX * i, A ? A + NX * NX * i : NULL, A ? Bv + NX * i : NULL);
    return 0;
}

/* rollouts: x0 (B, NX), u (B, T) -> xs (B, T+1, NX) */
int ILQR_EXPORT(rollout)(const double *p, int K, const double *knots, const double *slope, const double *intercept,
                         int B, int T, const double *x0, const double *u, double *xs)
{
    Model M = model_of(p, K, knots, slope, intercept);
    for (int b = 0; b < B; b++) {
        double *x = xs + (size_t)b * (T + 1) * NX;
        memcpy(x, x0 + NX * b, NX * sizeof(double));
        for (int t = 0; t < T; t++) step(&M, x + NX * t, u[b * T + t], x + NX * (t + 1), NULL, NULL);
    }
    return 0;
}

/* ---- the solver: mpc.solve for n = NX, m = 1 ---- */

#define NT (NX + 1)

typedef struct {
    const double *C, *c, *Cf, *cf;   /* NT×NT, NT, NX×NX or NULL, NX or NULL (τ = (ξ, ν)) */
} Cost;

static double stage_cost(const Cost *Q, const double *x, double u)
{
    double tau[NT];
    for (int i = 0; i < NX; i++) tau[i] = x[i];
    tau[NX] = u;
    double quad = 0.0, lin = 0.0;
    for (int i = 0; i < NT; i++) {
        double row = 0.0;
        for (int j = 0; j < NT; j++) row += Q->C[NT * i + j] * tau[j];
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
        for (int i = 0; i < NX; i++) {
            double row = 0.0;
            for (int j = 0; j < NX; j++) row += Q->Cf[NX * i + j] * x[j];
            quad += x[i] * row;
        }
        value += 0.5 * quad;
    }
    if (Q->cf)
        for (int i = 0; i < NX; i++) value += Q->cf[i] * x[i];
    return value;
}

/* roll out from x (T+1, NX)[0] under u (T), keeping Jacobians; returns the cost (inf if not finite) */
static double roll(const Model *M, const Cost *Q, int T, double *x, const double *u, double *A, double *Bv)
{
    double J = 0.0;
    for (int t = 0; t < T; t++) {
        step(M, x + NX * t, u[t], x + NX * (t + 1), A + NX * NX * t, Bv + NX * t);
        J += stage_cost(Q, x + NX * t, u[t]);
    }
    J += final_cost(Q, x + NX * T);
    return isfinite(J) ? J : INFINITY;
}

/* the backward pass of mpc.backward_pass for m = 1; returns ok */
static int backward(const Cost *Q, int T, const double *x, const double *u, const double *A, const double *Bv,
                    const double *lo, const double *hi, double mu, double *k, double *K)
{
    double Vx[NX] = {0}, Vxx[NX * NX] = {0};
    if (Q->Cf) memcpy(Vxx, Q->Cf, NX * NX * sizeof(double));
    for (int i = 0; i < NX; i++) {
        for (int j = 0; j < NX; j++) Vx[i] += Vxx[NX * i + j] * x[NX * T + j];
        if (Q->cf) Vx[i] += Q->cf[i];
    }
    int ok = 1;
    for (int t = T - 1; t >= 0; t--) {
        const double *At = A + NX * NX * t, *Bt = Bv + NX * t, *xt = x + NX * t;
        double tau[NT], grad[NT];
        for (int i = 0; i < NX; i++) tau[i] = xt[i];
        tau[NX] = u[t];
        for (int i = 0; i < NT; i++) {
            grad[i] = Q->c[i];
            for (int j = 0; j < NT; j++) grad[i] += Q->C[NT * i + j] * tau[j];
        }
        double Qx[NX], Qu = grad[NX], BV[NX], AV[NX * NX], Qxx[NX * NX], Quu, Qux[NX], BtB = 0.0, BtA[NX];
        for (int j = 0; j < NX; j++) {
            Qx[j] = grad[j];
            for (int i = 0; i < NX; i++) Qx[j] += At[NX * i + j] * Vx[i];
            Qu += Bt[j] * Vx[j];
            BtB += Bt[j] * Bt[j];
        }
        for (int j = 0; j < NX; j++) {
            BV[j] = 0.0;
            for (int i = 0; i < NX; i++) BV[j] += Bt[i] * Vxx[NX * i + j];
        }
        for (int i = 0; i < NX; i++)          /* AV = Aᵀ Vxx */
            for (int j = 0; j < NX; j++) {
                double s = 0.0;
                for (int l = 0; l < NX; l++) s += At[NX * l + i] * Vxx[NX * l + j];
                AV[NX * i + j] = s;
            }
        for (int i = 0; i < NX; i++)
            for (int j = 0; j < NX; j++) {
                double s = 0.0;
                for (int l = 0; l < NX; l++) s += AV[NX * i + l] * At[NX * l + j];
                Qxx[NX * i + j] = Q->C[NT * i + j] + s;
            }
        Quu = Q->C[NT * NX + NX];
        for (int j = 0; j < NX; j++) Quu += BV[j] * Bt[j];
        for (int j = 0; j < NX; j++) {
            double s = 0.0, s2 = 0.0;
            for (int l = 0; l < NX; l++) { s += BV[l] * At[NX * l + j]; s2 += Bt[l] * At[NX * l + j]; }
            Qux[j] = Q->C[NT * NX + j] + s;
            BtA[j] = s2;
        }
        double h = Quu + mu * BtB, Qux_r[NX];
        for (int j = 0; j < NX; j++) Qux_r[j] = Qux[j] + mu * BtA[j];
        int okt = h > 0.0;
        ok = ok && okt;
        double d = okt ? -Qu / h : 0.0, dlo = lo[t] - u[t], dhi = hi[t] - u[t];
        double kt = fmin(fmax(d, dlo), dhi);
        int free_ = d > dlo && d < dhi;
        double *Kt = K + NX * t;
        for (int j = 0; j < NX; j++) Kt[j] = (free_ && okt) ? -Qux_r[j] / h : 0.0;
        k[t] = kt;
        double a = Quu * kt + Qu;
        for (int i = 0; i < NX; i++) Vx[i] = Qx[i] + Kt[i] * a + Qux[i] * kt;
        for (int i = 0; i < NX; i++)
            for (int j = 0; j < NX; j++)
                Vxx[NX * i + j] = Qxx[NX * i + j] + Kt[i] * Quu * Kt[j] + Kt[i] * Qux[j] + Qux[i] * Kt[j];
        for (int i = 0; i < NX; i++)
            for (int j = i + 1; j < NX; j++) {
                double s = 0.5 * (Vxx[NX * i + j] + Vxx[NX * j + i]);
                Vxx[NX * i + j] = Vxx[NX * j + i] = s;
            }
    }
    return ok;
}

/* mpc.solve for B rows: x0 (B, NX), u (B, T) in: the initial guess, out: the plan; lo, hi (B, T);
 * xs (B, T+1, NX), cost (B), mu (B) in: μ0, out: final μ; history (B, iterations+1).
 * Returns the iterations run, or −1 when out of memory. */
int ILQR_EXPORT(ilqr)(const double *p, int K, const double *knots, const double *slope, const double *intercept,
                      const double *C, const double *c, const double *Cf, const double *cf, int has_Cf, int has_cf,
                      int B, int T, int iterations, int S, const double *alphas, double tol,
                      const double *x0, double *u, const double *lo, const double *hi,
                      double *xs, double *cost, double *mu, double *history)
{
    Model M = model_of(p, K, knots, slope, intercept);
    Cost Q = {C, c, has_Cf ? Cf : NULL, has_cf ? cf : NULL};
    const size_t nA = (size_t)NX * NX + NX;                          /* A and Bv of one step */
    size_t per = (size_t)T * nA + (size_t)(T + 1) * NX + T;         /* A, Bv, x, u of one trajectory */
    double *work = malloc(sizeof(double) * ((size_t)B * per + (size_t)S * per + (size_t)(NX + 1) * T + 8));
    if (!work) return -1;
    double *nomA = work, *trial = work + (size_t)B * per, *k = trial + (size_t)S * per, *Kg = k + T;
    /* nominal rollouts */
    for (int b = 0; b < B; b++) {
        double *x = xs + (size_t)b * (T + 1) * NX, *ub = u + (size_t)b * T;
        for (int t = 0; t < T; t++) ub[t] = fmin(fmax(ub[t], lo[b * T + t]), hi[b * T + t]);
        memcpy(x, x0 + NX * b, NX * sizeof(double));
        cost[b] = roll(&M, &Q, T, x, ub, nomA + (size_t)b * per, nomA + (size_t)b * per + NX * NX * T);
        history[(size_t)b * (iterations + 1)] = cost[b];
    }
    int done = 0;
    for (int it = 1; it <= iterations; it++) {
        done = it;
        int all_small = 1;
        for (int b = 0; b < B; b++) {
            double *x = xs + (size_t)b * (T + 1) * NX, *ub = u + (size_t)b * T;
            double *A = nomA + (size_t)b * per, *Bv = A + NX * NX * T;
            const double *lob = lo + (size_t)b * T, *hib = hi + (size_t)b * T;
            int ok = backward(&Q, T, x, ub, A, Bv, lob, hib, mu[b], k, Kg);
            double best = INFINITY;
            int best_s = 0;
            for (int s = 0; s < S; s++) {
                double *tA = trial + (size_t)s * per, *tB = tA + NX * NX * T, *tx = tB + NX * T, *tu = tx + NX * (T + 1);
                double J = 0.0;
                memcpy(tx, x0 + NX * b, NX * sizeof(double));
                for (int t = 0; t < T; t++) {
                    const double *xb = x + NX * t, *xc = tx + NX * t, *Kt = Kg + NX * t;
                    double fb = 0.0;
                    for (int j = 0; j < NX; j++) fb += Kt[j] * (xc[j] - xb[j]);
                    double ut = ub[t] + alphas[s] * k[t] + fb;
                    ut = fmin(fmax(ut, lob[t]), hib[t]);
                    tu[t] = ut;
                    step(&M, xc, ut, tx + NX * (t + 1), tA + NX * NX * t, tB + NX * t);
                    J += stage_cost(&Q, xc, ut);
                }
                J += final_cost(&Q, tx + NX * T);
                if (!isfinite(J)) J = INFINITY;
                if (J < best) { best = J; best_s = s; }
            }
            int better = ok && best < cost[b];
            double gain = cost[b] - best;
            if (better) {
                double *tA = trial + (size_t)best_s * per, *tx = tA + nA * T, *tu = tx + NX * (T + 1);
                memcpy(A, tA, nA * (size_t)T * sizeof(double));
                memcpy(x, tx, NX * (size_t)(T + 1) * sizeof(double));
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

#endif
