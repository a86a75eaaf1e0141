/* The coin's backward-Euler step under the DEA tip, the one C definition of it: included by
 * surrogate/native_rollout.c (the surrogate's rollouts) and control/native_mpc.c (the MPC's
 * step, its Jacobians and the inference), compiled by deapull.surrogate.native.compiled with
 * this folder on the include path. The torch twin is
 * deapull.surrogate.models.tip_contact.tip_coin_step; tests/surrogate/test_coin_kernel.py
 * checks the two on the same inputs to round-off.
 *
 * The coin (velocity u, mass m_c, c = m_c / dt) is dragged by the tip moving at w through
 * rate-regularised friction (cap_t = μ_t Fy, regularisation ε_v) and held by the ground's
 * exact Coulomb friction (cap_b = μ_b (m_c g + Fy)).
 */
#ifndef DEAPULL_COIN_STEP_H
#define DEAPULL_COIN_STEP_H

#include <math.h>

static inline double reg(double v, double eps) { return v / sqrt(v * v + eps * eps); }

/* (y² + ε²)^1.5 as q√q: within an ulp of torch's pow and several times faster */
static inline double slope_den(double y, double eps)
{
    double q = y * y + eps * eps;
    return q * sqrt(q);
}

/* The coin's velocity v' at the end of a step (tip_coin_step): the root of
 *   r(v) = c (v − u) − cap_t reg(w − v) + sign cap_b
 * by Newton safeguarded with bisection in [lo, hi], then one more Newton correction.
 * Returns the corrected v'; *root is v' before the correction and *slope r'(root). */
typedef struct { double v, root, slope, sign; int stuck; } CoinRoot;

static CoinRoot coin_root(double c, double u, double w, double cap_t, double cap_b, double eps, int iterations)
{
    CoinRoot R;
    double tip_rest = cap_t * reg(w, eps);
    double ground = tip_rest + c * u;
    R.stuck = fabs(ground) <= cap_b;
    double sign = ground > 0.0 ? 1.0 : -1.0;
    double reach = (cap_t + cap_b) / c;
    double lo = (sign > 0.0 || R.stuck) ? 0.0 : fmin(u - reach, 0.0);
    double hi = (sign < 0.0 || R.stuck) ? 0.0 : fmax(u + reach, 0.0);
    double ratio = sign * cap_b / fmax(cap_t, 1e-300);
    ratio = fmin(fmax(ratio, -0.999999), 0.999999);
    double v = fmin(fmax(w - eps * ratio / sqrt(1.0 - ratio * ratio), lo), hi);
    double change = hi - lo;
#define RESIDUAL(v_) (c * ((v_) - u) - cap_t * reg(w - (v_), eps) + sign * cap_b)
#define SLOPE(v_) (c + cap_t * eps * eps / slope_den(w - (v_), eps))
    for (int it = 0; it < iterations; it++) {
        double r = RESIDUAL(v);
        if (r < 0.0) lo = v; else hi = v;
        double s = r / SLOPE(v);
        int bisect = (v - s < lo) || (v - s > hi) || (2.0 * fabs(s) > fabs(change));
        double previous = v;
        v = bisect ? 0.5 * (lo + hi) : v - s;
        change = v - previous;
        if (fabs(change) <= 1e-13 * (fabs(v) + eps)) break;
    }
    R.slope = SLOPE(v);
    R.root = v;
    R.v = v - RESIDUAL(v) / R.slope;
    R.sign = sign;
#undef RESIDUAL
#undef SLOPE
    return R;
}

#endif /* DEAPULL_COIN_STEP_H */
