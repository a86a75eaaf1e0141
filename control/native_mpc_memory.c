/* The coin task's MPC in C on the tip-memory model f-memory (deapull.control.native,
 * NativeMemoryDynamics): f_a's step with its analytic Jacobians and the batched box-iLQR of
 * deapull.control.mpc.solve for n = 5, m = 1.
 *
 * The state is CoinDynamics' ξ = (x/x_unit, u/u_unit, V/V_unit, P/P_unit, T/T_unit): the coin,
 * the voltage now applied and the tip's memory (contact point P and friction T of the previous
 * step; control/dynamics.py). One step: V' = clip(V + ν ΔV_max, 0, V_max), m at V' (the
 * material network as the exact piecewise-affine function it is, TipFriction.material_pieces,
 * with its four outputs: X = sx (o0 − o0(0 V)), Fy0 = fym + fys o1, c = c0 softplus(o2 + 1),
 * b = tanh(o3 / 5)), then tip_memory_step (surrogate/models/memory.py): the root T' of
 *
 *   r(T) = T − μ_t max(Fy, 0) reg(s),  Fy = Fy0 + b T,  N = max(m_c g + Fy, 0),
 *   reach = T + (m_c/Δt) u,  u' = (reach − sgn(reach) μ_b N)/(m_c/Δt) if |reach| > μ_b N else 0,
 *   P' = X − c T,  s = (P' − P)/Δt − u'
 *
 * by the same bracketed Newton iteration from the previous T (stopping per row), one more
 * Newton correction, and the Jacobians of (u', P', T') from the implicit-function theorem at
 * the root (dT'/dθ = −∂r/∂θ / r'(T)): what autograd through the torch model's final correction
 * gives. The previous T only starts the solve: its derivative is 0, as in torch. The solver is
 * control/ilqr_passes.h, included below and shared with native_mpc.c.
 *
 * Layout of the parameter block `p` (doubles), filled by control/native.py:
 *   0 mean, 1 scale of t = (V − mean)/scale, 2 sx, 3 fym, 4 fys, 5 c0 (compliance scale),
 *   6 m_c, 7 μ_b, 8 μ_t, 9 g, 10 ε_v, 11 Δt, 12 ΔV_max, 13 V_max, 14 iterations,
 *   15 x unit, 16 u unit, 17 V unit, 18 P unit, 19 T unit, 20 raw output o0 at 0 V
 * and the pieces: knots (K+1), slope (K, 4), intercept (K, 4).
 */
#include <math.h>
#include <string.h>

#define NX 5
#define NO 4

typedef struct {
    int K;
    const double *knots, *slope, *intercept;
    double mean, scale, sx, fym, fys, c0, mass, mu_b, mu_t, grav, eps, dt, dvmax, vmax, xu, uu, vu, pu, tu, rest;
    int iterations;
} Model;

static Model model_of(const double *p, int K, const double *knots, const double *slope, const double *intercept)
{
    Model M;
    M.K = K; M.knots = knots; M.slope = slope; M.intercept = intercept;
    M.mean = p[0]; M.scale = p[1]; M.sx = p[2]; M.fym = p[3]; M.fys = p[4]; M.c0 = p[5];
    M.mass = p[6]; M.mu_b = p[7]; M.mu_t = p[8]; M.grav = p[9]; M.eps = p[10];
    M.dt = p[11]; M.dvmax = p[12]; M.vmax = p[13]; M.iterations = (int)p[14];
    M.xu = p[15]; M.uu = p[16]; M.vu = p[17]; M.pu = p[18]; M.tu = p[19]; M.rest = p[20];
    return M;
}

/* torch.nn.functional.softplus (β = 1, threshold 20) */
static double softplus(double v) { return v > 20.0 ? v : log1p(exp(v)); }
static double sigmoid(double v) { return v > 20.0 ? 1.0 : 1.0 / (1.0 + exp(-v)); }

/* m at V: X, Fy0, c, b and their derivatives in V */
typedef struct { double X, dX, fy0, dfy0, c, dc, b, db; } Material;

static Material material(const Model *M, double V)
{
    double t = (V - M->mean) / M->scale;
    int lo = 0, hi = M->K - 1;
    while (lo < hi) {
        int mid = (lo + hi + 1) >> 1;
        if (M->knots[mid] <= t) lo = mid; else hi = mid - 1;
    }
    const double *s = M->slope + NO * lo, *a = M->intercept + NO * lo;
    double o0 = s[0] * t + a[0], o1 = s[1] * t + a[1], o2 = s[2] * t + a[2], o3 = s[3] * t + a[3];
    Material m;
    m.X = M->sx * (o0 - M->rest);
    m.dX = M->sx * s[0] / M->scale;
    m.fy0 = M->fym + M->fys * o1;
    m.dfy0 = M->fys * s[1] / M->scale;
    m.c = M->c0 * softplus(o2 + 1.0);
    m.dc = M->c0 * (o2 + 1.0 > 20.0 ? 1.0 : sigmoid(o2 + 1.0)) * s[2] / M->scale;
    m.b = tanh(0.2 * o3);
    m.db = (1.0 - m.b * m.b) * 0.2 * s[3] / M->scale;
    return m;
}

static inline double reg(double v, double eps) { return v / sqrt(v * v + eps * eps); }

/* tip_memory_step's parts at T */
typedef struct { double fy, u_next, P_next, s; int slip; double sgn, pn, pf; } Parts;

static Parts parts(const Model *M, double T, double u, double P, const Material *m)
{
    const double ratio = M->mass / M->dt;
    Parts q;
    q.fy = m->fy0 + m->b * T;
    double nraw = M->mass * M->grav + q.fy;
    double normal = nraw > 0.0 ? nraw : 0.0;
    double reach = T + ratio * u, cap = M->mu_b * normal;
    q.slip = fabs(reach) > cap;
    q.sgn = reach >= 0.0 ? 1.0 : -1.0;
    q.u_next = q.slip ? (reach - q.sgn * cap) / ratio : 0.0;
    q.P_next = m->X - m->c * T;
    q.s = (q.P_next - P) / M->dt - q.u_next;
    q.pn = nraw > 0.0 ? 1.0 : 0.0;
    q.pf = q.fy > 0.0 ? 1.0 : 0.0;
    return q;
}

static double residual(const Model *M, const Parts *q, double T)
{
    return T - M->mu_t * (q->fy > 0.0 ? q->fy : 0.0) * reg(q->s, M->eps);
}

/* r'(T) as memory.py's slope() */
static double slope_of(const Model *M, const Parts *q, const Material *m)
{
    const double ratio = M->mass / M->dt, eps = M->eps;
    double du = q->slip ? (1.0 - q->sgn * M->mu_b * m->b * q->pn) / ratio : 0.0;
    double ds = -m->c / M->dt - du;
    double qq = q->s * q->s + eps * eps;
    double dreg = eps * eps / (qq * sqrt(qq));
    return 1.0 - M->mu_t * (q->pf * m->b * reg(q->s, eps) + (q->fy > 0.0 ? q->fy : 0.0) * dreg * ds);
}

/* The bracketed Newton solve of tip_memory_step from T_start (stopping per row): the root
 * before the final Newton correction, which the caller takes (its gradients are the exact
 * root's, by the implicit-function theorem) */
static double bracketed_root(const Model *M, double u, double P, double T_start, const Material *m)
{
    double bound = (M->mu_t * fabs(m->fy0) / (1.0 - M->mu_t * fabs(m->b))) * (1 + 1e-9) + 1e-15;
    double lo = -bound, hi = bound;
    double T = fmin(fmax(T_start, lo), hi);
    double change = hi - lo;
    for (int it = 0; it < M->iterations; it++) {
        Parts q = parts(M, T, u, P, m);
        double r = residual(M, &q, T);
        if (r < 0.0) lo = T; else hi = T;
        double st = r / slope_of(M, &q, m);
        int bisect = (T - st < lo) || (T - st > hi) || (2.0 * fabs(st) > fabs(change)) || !isfinite(st);
        double previous = T;
        T = bisect ? 0.5 * (lo + hi) : T - st;
        change = T - previous;
        if (fabs(change) <= 1e-14 * (fabs(T) + 1e-9)) break;
    }
    return T;
}

/* The step's friction T' at one row: the bracketed root T0, the slope there, and one more Newton
 * correction T = T0 − r(T0)/r'(T0) (whose gradients are the exact root's), with the parts at both */
typedef struct { double T0, T, sl; Parts q0, q; } Root;

static Root solve_step(const Model *M, double u, double P, double T_start, const Material *m)
{
    Root s;
    s.T0 = bracketed_root(M, u, P, T_start, m);
    s.q0 = parts(M, s.T0, u, P, m);
    s.sl = slope_of(M, &s.q0, m);
    s.T = s.T0 - residual(M, &s.q0, s.T0) / s.sl;
    s.q = parts(M, s.T, u, P, m);
    return s;
}

/* One step ξ' = f(ξ, ν) in scaled units; A (5×5, row-major) = ∂ξ'/∂ξ and Bv (5) = ∂ξ'/∂ν
 * when A is not NULL. */
static void step(const Model *M, const double *xi, double nu, double *out, double *A, double *Bv)
{
    const double dt = M->dt, eps = M->eps, ratio = M->mass / M->dt;
    double x = xi[0] * M->xu, u = xi[1] * M->uu, V = xi[2] * M->vu, P = xi[3] * M->pu, Tprev = xi[4] * M->tu;
    double Vr = V + nu * M->dvmax;
    double Vn = fmin(fmax(Vr, 0.0), M->vmax);
    double mask = (Vr >= 0.0 && Vr <= M->vmax) ? 1.0 : 0.0;
    Material m = material(M, Vn);
    Root root = solve_step(M, u, P, Tprev, &m);
    const double T0 = root.T0, sl = root.sl, T = root.T;
    const Parts q0 = root.q0, q = root.q;
    double un = q.u_next;
    out[0] = (x + dt * un) / M->xu;
    out[1] = un / M->uu;
    out[2] = Vn / M->vu;
    out[3] = q.P_next / M->pu;
    out[4] = T / M->tu;
    if (!A) return;
    /* ∂r/∂θ at T0 for θ = (u, P, X, c, fy0, b): r = T − μ_t fy⁺ reg(s) */
    double fyp0 = q0.fy > 0.0 ? q0.fy : 0.0;
    double qq = q0.s * q0.s + eps * eps, rho = reg(q0.s, eps), drho = eps * eps / (qq * sqrt(qq));
    double slip0 = q0.slip ? 1.0 : 0.0;
    /* u'(T0) partials (T fixed) */
    double du0_u = slip0, du0_fy0 = -slip0 * q0.sgn * M->mu_b * q0.pn / ratio;
    double du0_b = du0_fy0 * T0;
    /* s partials */
    double ds_u = -du0_u, ds_P = -1.0 / dt, ds_X = 1.0 / dt, ds_c = -T0 / dt, ds_fy0 = -du0_fy0, ds_b = -du0_b;
    double k = M->mu_t * fyp0 * drho;
    double dr_u = -k * ds_u, dr_P = -k * ds_P, dr_X = -k * ds_X, dr_c = -k * ds_c;
    double dr_fy0 = -M->mu_t * q0.pf * rho - k * ds_fy0;
    double dr_b = -M->mu_t * q0.pf * T0 * rho - k * ds_b;
    double dT_u = -dr_u / sl, dT_P = -dr_P / sl, dT_X = -dr_X / sl, dT_c = -dr_c / sl;
    double dT_fy0 = -dr_fy0 / sl, dT_b = -dr_b / sl;
    /* the outputs at T: u' and P' */
    double slip = q.slip ? 1.0 : 0.0;
    double du_T = slip * (1.0 - q.sgn * M->mu_b * m.b * q.pn) / ratio;
    double du_fy0p = -slip * q.sgn * M->mu_b * q.pn / ratio, du_bp = du_fy0p * T;
    double dun_u = du_T * dT_u + slip, dun_P = du_T * dT_P, dun_X = du_T * dT_X, dun_c = du_T * dT_c;
    double dun_fy0 = du_T * dT_fy0 + du_fy0p, dun_b = du_T * dT_b + du_bp;
    double dPn_u = -m.c * dT_u, dPn_P = -m.c * dT_P, dPn_X = 1.0 - m.c * dT_X, dPn_c = -T - m.c * dT_c;
    double dPn_fy0 = -m.c * dT_fy0, dPn_b = -m.c * dT_b;
    /* through V' */
    double dun_Vn = dun_X * m.dX + dun_c * m.dc + dun_fy0 * m.dfy0 + dun_b * m.db;
    double dPn_Vn = dPn_X * m.dX + dPn_c * m.dc + dPn_fy0 * m.dfy0 + dPn_b * m.db;
    double dT_Vn = dT_X * m.dX + dT_c * m.dc + dT_fy0 * m.dfy0 + dT_b * m.db;
    double dVn_V = mask * M->vu, dVn_nu = mask * M->dvmax;   /* dV'/dξ2, dV'/dν */
    double rows[3][3] = {   /* (u', P', T') by (ξ1 u, ξ3 P, V') in SI */
        {dun_u * M->uu, dun_P * M->pu, dun_Vn},
        {dPn_u * M->uu, dPn_P * M->pu, dPn_Vn},
        {dT_u * M->uu, dT_P * M->pu, dT_Vn},
    };
    double unit[3] = {M->uu, M->pu, M->tu};
    int idx[3] = {1, 3, 4};
    memset(A, 0, sizeof(double) * NX * NX);
    A[0] = 1.0;
    A[2 * NX + 2] = mask;
    for (int r = 0; r < 3; r++) {
        double *row = A + NX * idx[r];
        row[1] = rows[r][0] / unit[r];
        row[3] = rows[r][1] / unit[r];
        row[2] = rows[r][2] * dVn_V / unit[r];
        Bv[idx[r]] = rows[r][2] * dVn_nu / unit[r];
    }
    /* x' = x + Δt u' */
    A[1] = dt * rows[0][0] / M->xu;
    A[3] = dt * rows[0][1] / M->xu;
    A[2] = dt * rows[0][2] * dVn_V / M->xu;
    Bv[0] = dt * rows[0][2] * dVn_nu / M->xu;
    Bv[2] = dVn_nu / M->vu;
}

/* The exported step, rollout and box-iLQR (deapull_memory_step, _rollout, _ilqr): the same
 * passes as native_mpc.c's, over this file's state of width NX = 5 */
#define ILQR_EXPORT(name) deapull_memory_##name
#include "ilqr_passes.h"

/* ---- online inference (deapull.control.inference with an f-memory f_a) -------------------
 * The inference's rows carry m at the step's voltage (X, c, Fy0, b: evaluated once, θ fixed)
 * and the tip's memory before the step (P, T), so only the step itself depends on φ.
 * phys = (m_c, μ_b, μ_t, g, ε_v, iterations). */

static Model inference_model(const double *phys, double dt)
{
    Model M;
    memset(&M, 0, sizeof M);
    M.mass = phys[0]; M.mu_b = phys[1]; M.mu_t = phys[2]; M.grav = phys[3]; M.eps = phys[4];
    M.iterations = (int)phys[5]; M.dt = dt;
    return M;
}

static Material given_material(double X, double c, double fy0, double b)
{
    Material m;
    memset(&m, 0, sizeof m);
    m.X = X; m.c = c; m.fy0 = fy0; m.b = b;
    return m;
}

/* ∂u'/∂(m_c, μ_b, μ_t) at fixed T (0 for a held step; μ_t does not enter u' directly):
 * u' = u + (T − sgn μ_b N) Δt/m_c,  N = max(m_c g + Fy, 0) */
static void slip_partials(const Model *M, const Parts *q, double T, double du[3])
{
    du[0] = du[1] = du[2] = 0.0;
    if (!q->slip) return;
    const double mass = M->mass, dt = M->dt, nraw = mass * M->grav + q->fy, normal = nraw > 0.0 ? nraw : 0.0;
    du[0] = -q->sgn * M->mu_b * q->pn * M->grav * dt / mass - (T - q->sgn * M->mu_b * normal) * dt / (mass * mass);
    du[1] = -q->sgn * normal * dt / mass;
}

/* x̂' of n rows (coin position x, velocity u, step Δt, memory P, T, and m at V': X, c, Fy0, b)
 * and the stick shortfall (μ_b N − |T' + m_c u/Δt|)⁺ Δt/m_c where the step holds the coin
 * (0 elsewhere), as TipMemoryModel.predict_with_shortfall; with dpred and dshort not NULL
 * their derivatives in log m_c, log μ_b, log μ_t (n × 3, row-major), as autograd gives them
 * through the final Newton correction (T0 fixed, the slope at T0 a constant). */
int deapull_memory_predict(int n, const double *x, const double *u, const double *dts, const double *P,
                           const double *Tprev, const double *X, const double *c, const double *fy0,
                           const double *b, const double *phys, double *pred, double *dpred, double *shortfall,
                           double *dshort)
{
    for (int i = 0; i < n; i++) {
        const double dt = dts[i];
        Model M = inference_model(phys, dt);
        Material m = given_material(X[i], c[i], fy0[i], b[i]);
        const double mass = M.mass, mu_b = M.mu_b, mu_t = M.mu_t, ratio = mass / dt, eps = M.eps;
        Root root = solve_step(&M, u[i], P[i], Tprev[i], &m);
        const double T = root.T, sl = root.sl;
        const Parts q0 = root.q0, q = root.q;
        pred[i] = x[i] + dt * q.u_next;
        double nraw = mass * M.grav + q.fy, normal = nraw > 0.0 ? nraw : 0.0;
        double R = T + ratio * u[i], D = mu_b * normal - fabs(R);
        int stuck = q.u_next == 0.0;
        shortfall[i] = stuck && D > 0.0 ? D * dt / mass : 0.0;
        if (!dpred) continue;
        /* ∂u'/∂φ at fixed T, at T0 (for ∂r) and at T (the output) */
        double du0[3], du[3];
        slip_partials(&M, &q0, root.T0, du0);
        slip_partials(&M, &q, T, du);
        /* r = T − μ_t Fy⁺ reg(s), s = (P' − P)/Δt − u': ∂r/∂φ = k ∂u'/∂φ − [μ_t] Fy⁺ reg(s) */
        double fyp0 = q0.fy > 0.0 ? q0.fy : 0.0, qq = q0.s * q0.s + eps * eps;
        double k = mu_t * fyp0 * eps * eps / (qq * sqrt(qq));
        double dr[3] = {k * du0[0], k * du0[1], -fyp0 * reg(q0.s, eps)};
        double du_T = q.slip ? (1.0 - q.sgn * mu_b * m.b * q.pn) / ratio : 0.0;
        double phi[3] = {mass, mu_b, mu_t};
        for (int j = 0; j < 3; j++) {
            double dT = -dr[j] / sl;
            dpred[3 * i + j] = dt * (du_T * dT + du[j]) * phi[j];
            double dsh = 0.0;
            if (stuck && D > 0.0) {
                double sR = R > 0.0 ? 1.0 : (R < 0.0 ? -1.0 : 0.0);
                double dcap = mu_b * q.pn * ((j == 0 ? M.grav : 0.0) + m.b * dT) + (j == 1 ? normal : 0.0);
                double dR = dT + (j == 0 ? u[i] / dt : 0.0);
                dsh = (dcap - sR * dR) * dt / mass - (j == 0 ? D * dt / (mass * mass) : 0.0);
            }
            dshort[3 * i + j] = dsh * phi[j];
        }
    }
    return 0;
}

/* The memory along n consecutive rows: row 0 starts from (P0, T0); P_out[i], T_out[i] is the
 * memory after row i's step, which row i + 1 starts from (TipMemoryModel.memory_along's scan) */
int deapull_memory_scan(int n, const double *u, const double *dts, const double *X, const double *c,
                        const double *fy0, const double *b, const double *phys, double P0, double T0,
                        double *P_out, double *T_out)
{
    double P = P0, T = T0;
    for (int i = 0; i < n; i++) {
        Model M = inference_model(phys, dts[i]);
        Material m = given_material(X[i], c[i], fy0[i], b[i]);
        Root root = solve_step(&M, u[i], P, T, &m);
        T = root.T;
        P = root.q.P_next;
        P_out[i] = P; T_out[i] = T;
    }
    return 0;
}
