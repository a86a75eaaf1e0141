/* The coin task's MPC in C (deapull.control.native): f_a's step with its analytic Jacobians
 * and the batched box-iLQR of deapull.control.mpc.solve for n = 3, m = 1.
 *
 * The step is CoinDynamics (control/task.py) on the tip-contact model f-coulomb, or f-patch
 * (surrogate/models/tip_contact.py): the material network m evaluated as the exact
 * piecewise-affine function it is (TipContactModel.material_pieces), the coin's
 * backward-Euler step solved by the same bracketed Newton iteration as tip_coin_step (with
 * that function's stopping rule applied per row), and the Jacobians of the step from the
 * implicit-function theorem at the root, the same derivatives the torch model's
 * autograd gives. The solver is control/ilqr_passes.h, included below and shared with
 * native_mpc_memory.c: mpc.solve operation for operation, over this state of width NX = 3.
 *
 * Layout of the parameter block `p` (doubles), filled by control/native.py:
 *   0 mean, 1 scale of t = (V − mean)/scale, 2 stroke_scale, 3 fy_mean, 4 fy_scale,
 *   5 m_c, 6 μ_b, 7 μ_t, 8 g, 9 ε_v, 10 Δt, 11 ΔV_max, 12 V_max, 13 iterations,
 *   14 x unit, 15 u unit, 16 V unit, 17 raw output o_0 at 0 V, 18 outputs of m (2: f-coulomb,
 *   3: f-patch, whose third is the patch's spread β = softplus(o_2 − shift)), 19 that shift
 * and the pieces: knots (K+1), slope (K, outputs), intercept (K, outputs).
 * f-patch widens the tip friction's regularisation over a step to ε = √(ε_v² + (β(V') w)²);
 * the Jacobians carry ε's dependence on w and V' (TipPatchModel).
 */
#include <math.h>
#include <stddef.h>

#include "coin_step.h"   /* reg, coin_root: the coin's step (surrogate/coin_step.h) */

#define NX 3   /* ξ = (x, u, V) */

typedef struct {
    int K;
    const double *knots, *slope, *intercept;
    double mean, scale, sx, fym, fys, mass, mu_b, mu_t, grav, eps, dt, dvmax, vmax, xu, uu, vu, rest, shift;
    int iterations, outputs;
} Model;

static Model model_of(const double *p, int K, const double *knots, const double *slope, const double *intercept)
{
    Model M;
    M.K = K; M.knots = knots; M.slope = slope; M.intercept = intercept;
    M.mean = p[0]; M.scale = p[1]; M.sx = p[2]; M.fym = p[3]; M.fys = p[4];
    M.mass = p[5]; M.mu_b = p[6]; M.mu_t = p[7]; M.grav = p[8]; M.eps = p[9];
    M.dt = p[10]; M.dvmax = p[11]; M.vmax = p[12]; M.iterations = (int)p[13];
    M.xu = p[14]; M.uu = p[15]; M.vu = p[16]; M.rest = p[17];
    M.outputs = (int)p[18]; M.shift = p[19];
    return M;
}

/* X(V), dX/dV, Fy(V), dFy/dV and, where beta is not NULL, the spread β(V), dβ/dV (0 for a
 * two-output m) */
static void material(const Model *M, double V, double *X, double *dX, double *Fy, double *dFy, double *beta,
                     double *dbeta)
{
    double t = (V - M->mean) / M->scale;
    int lo = 0, hi = M->K - 1;
    while (lo < hi) {
        int mid = (lo + hi + 1) >> 1;
        if (M->knots[mid] <= t) lo = mid; else hi = mid - 1;
    }
    const int k = M->outputs * lo;
    double s0 = M->slope[k], s1 = M->slope[k + 1];
    double o0 = s0 * t + M->intercept[k], o1 = s1 * t + M->intercept[k + 1];
    *X = M->sx * (o0 - M->rest);
    *dX = M->sx * s0 / M->scale;
    *Fy = M->fym + M->fys * o1;
    *dFy = M->fys * s1 / M->scale;
    if (!beta) return;
    *beta = *dbeta = 0.0;
    if (M->outputs < 3) return;
    /* softplus(o) = max(o, 0) + log1p(exp(−|o|)), as torch's; its slope the logistic */
    double o2 = M->slope[k + 2] * t + M->intercept[k + 2] - M->shift;
    *beta = fmax(o2, 0.0) + log1p(exp(-fabs(o2)));
    *dbeta = M->slope[k + 2] / M->scale / (1.0 + exp(-o2));
}

/* One step ξ' = f(ξ, ν) in scaled units; A (3×3, row-major) = ∂ξ'/∂ξ and Bv (3) = ∂ξ'/∂ν
 * when A is not NULL. */
static void step(const Model *M, const double *xi, double nu, double *out, double *A, double *Bv)
{
    const double dt = M->dt;
    double x = xi[0] * M->xu, u = xi[1] * M->uu, V = xi[2] * M->vu;
    double Vr = V + nu * M->dvmax;
    double Vn = fmin(fmax(Vr, 0.0), M->vmax);
    double mask = (Vr >= 0.0 && Vr <= M->vmax) ? 1.0 : 0.0;
    double Xp, dXp, Fp, dFp, Xn, dXn, Fy, dFy, beta, dbeta;
    material(M, V, &Xp, &dXp, &Fp, &dFp, NULL, NULL);
    material(M, Vn, &Xn, &dXn, &Fy, &dFy, &beta, &dbeta);
    double normal_raw = M->mass * M->grav + Fy;
    double normal = normal_raw > 0.0 ? normal_raw : 0.0, dnormal = normal_raw >= 0.0 ? dFy : 0.0;
    double fyc = Fy > 0.0 ? Fy : 0.0, dfyc = Fy >= 0.0 ? dFy : 0.0;
    double w = (Xn - Xp) / dt;
    double bw = beta * w, eps = sqrt(M->eps * M->eps + bw * bw);   /* TipContactModel.slip_eps */
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
        /* f-patch: ε = √(ε_v² + β² w²) moves with w and with β(V'); ∂r/∂ε = cap_t y ε / q^1.5 */
        double du_deps = -cap_t * y * eps / (q * sqrt(q)) / sl;
        double deps_dw = beta * bw / eps, deps_dbeta = bw * w / eps;
        du_dw += du_deps * deps_dw;
        double dspread = du_deps * deps_dbeta * dbeta;   /* d u'/d V' through β */
        du_du = c / sl;
        du_dV = du_dw * (dXn * mask - dXp) / dt + (dcap + dspread) * mask;
        du_dnu = (du_dw * dXn / dt + dcap + dspread) * mask * M->dvmax;
    }
    A[0] = 1.0; A[1] = dt * du_du * M->uu / M->xu; A[2] = dt * du_dV * M->vu / M->xu;
    A[3] = 0.0; A[4] = du_du;                      A[5] = du_dV * M->vu / M->uu;
    A[6] = 0.0; A[7] = 0.0;                        A[8] = mask;
    Bv[0] = dt * du_dnu / M->xu;
    Bv[1] = du_dnu / M->uu;
    Bv[2] = mask * M->dvmax / M->vu;
}

/* The exported step, rollout and box-iLQR (deapull_coin_step, _rollout, _ilqr): the same
 * passes as native_mpc_memory.c's, over this file's state of width NX = 3 */
#define ILQR_EXPORT(name) deapull_coin_##name
#include "ilqr_passes.h"

/* ---- online inference (control/inference.py, tip-contact model) ----
 * For n buffered transitions with the φ-free parts cached (x, u = observed velocity, Δt,
 * the tip's stroke before and after, Fy after) and one coin φ = (m_c, μ_b, μ_t): the
 * predicted next position x̂ (Predictor.predict), the stick shortfall (cap_b − |R|)⁺ Δt/m_c
 * (Predictor.stick_shortfall), and when dpred is not NULL their derivatives with respect
 * to log m_c, log μ_b, log μ_t (n, 3), from the implicit-function theorem at the root as
 * autograd through the torch model gives them. eps_rows (n) is each row's regularisation
 * (f-patch's √(ε_v² + (β w)²), which φ does not move); NULL: ε_v = phys[4] for every row. */
int deapull_coin_predict(int n, const double *x, const double *u, const double *dts, const double *stroke_prev,
                         const double *stroke, const double *fy_in, const double *eps_rows, const double *phys,
                         double *pred, double *dpred, double *shortfall, double *dshort)
{
    const double mass = phys[0], mu_b = phys[1], mu_t = phys[2], grav = phys[3];
    const int iterations = (int)phys[5];
    for (int i = 0; i < n; i++) {
        double dt = dts[i], Fy = fy_in[i], ui = u[i], eps = eps_rows ? eps_rows[i] : phys[4];
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
