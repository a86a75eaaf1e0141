/*
 * Batch-1 CPU rollouts of the surrogate models, step for step the same arithmetic as the
 * torch modules in surrogate/models/ (networks in float32, coin dynamics in double).
 * Compiled on first use by surrogate/native.py; see docs/surrogate.md ("Rollouts").
 *
 * Layouts (all row-major, as torch stores them):
 *   MLP params   for each layer l: W_l (sizes[l+1] x sizes[l]) then b_l (sizes[l+1]);
 *                ReLU after every layer but the last.
 *   LSTM params  W_ih (4H x 4), W_hh (4H x H), b_ih (4H), b_hh (4H), W_head (2 x H),
 *                b_head (2); gates in torch's order i, f, g, o.
 *   actions      n_steps x (V, dt); states (n_steps + 1) x (x, u); forces n_steps x (Fx, Fy).
 * Every function returns 0, or -1 when it cannot allocate its scratch memory.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "coin_step.h"   /* reg, coin_root: the coin's step, shared with control/native_mpc.c */

/* out = W h + b, four rows at a time so that four vectorised sums run side by side */
static inline void dense_rows(int n_out, int n_in, const float *W, const float *b, const float *h, float *out,
                              int relu)
{
    enum { R = 4 };
    int j = 0;
    for (; j + R <= n_out; j += R) {
        float acc[R] = {0.0f};
        for (int k = 0; k < n_in; k++)
            for (int q = 0; q < R; q++)
                acc[q] += W[(long)(j + q) * n_in + k] * h[k];
        for (int q = 0; q < R; q++) {
            const float v = acc[q] + b[j + q];
            out[j + q] = (relu && v < 0.0f) ? 0.0f : v;
        }
    }
    for (; j < n_out; j++) {
        const float *w = W + (long)j * n_in;
        float acc = 0.0f;
        for (int k = 0; k < n_in; k++)
            acc += w[k] * h[k];
        acc += b[j];
        out[j] = (relu && acc < 0.0f) ? 0.0f : acc;
    }
}

/* out = W h + b (ReLU if relu). The paper's width, 128, gets its own compiled copy: with
   the length known the compiler unrolls the sums into parallel vector accumulators. */
static void dense(int n_out, int n_in, const float *W, const float *b, const float *h, float *out, int relu)
{
    if (n_in == 128)
        dense_rows(n_out, 128, W, b, h, out, relu);
    else
        dense_rows(n_out, n_in, W, b, h, out, relu);
}

static int max_width(int n_layers, const int *sizes)
{
    int w = 0;
    for (int l = 0; l <= n_layers; l++)
        if (sizes[l] > w)
            w = sizes[l];
    return w;
}

/* out = MLP(in); a and b are scratch vectors of max_width floats. */
static void mlp(int n_layers, const int *sizes, const float *params, const float *in, float *out, float *a, float *b)
{
    const float *h = in;
    for (int l = 0; l < n_layers; l++) {
        int n_in = sizes[l], n_out = sizes[l + 1];
        const float *W = params, *bias = params + (long)n_out * n_in;
        float *dst = (l == n_layers - 1) ? out : ((l % 2 == 0) ? a : b);
        dense(n_out, n_in, W, bias, h, dst, l < n_layers - 1);
        params = bias + n_out;
        h = dst;
    }
}

static void normalised_inputs(const double *norm, double x, double u, double V, double dt, float *in)
{
    const double raw[4] = {x, u, V, dt};
    for (int k = 0; k < 4; k++)
        in[k] = (float)((raw[k] - norm[k]) / norm[4 + k]);
}

/*
 * f = d(m) with the paper's law (eqs. 4-6).
 * norm = in_mean[4], in_std[4], z_mean[2], z_std[2];
 * phys = mass_kg, mu_b, gravity, v_threshold, v_contact_loss.
 */
int deapull_rollout_physics(int n_layers, const int *sizes, const float *params, const double *norm,
                            const double *phys, int n_steps, const double *s0, const double *actions,
                            double *states, double *forces)
{
    int w = max_width(n_layers, sizes);
    float *scratch = malloc(sizeof(float) * 2 * w);
    if (!scratch)
        return -1;
    const double mass = phys[0], mu_b = phys[1], g = phys[2], vt = phys[3], vloss = phys[4];
    double x = s0[0], u = s0[1];
    float in[4], zn[2];
    states[0] = x;
    states[1] = u;
    for (int t = 0; t < n_steps; t++) {
        const double V = actions[2 * t], dt = actions[2 * t + 1];
        normalised_inputs(norm, x, u, V, dt, in);
        mlp(n_layers, sizes, params, in, zn, scratch, scratch + w);
        double fx = norm[8] + norm[10] * (double)zn[0];
        double fy = norm[9] + norm[11] * (double)zn[1];
        forces[2 * t] = fx;
        forces[2 * t + 1] = fy;
        int contact = V < vloss;
        double pull = (contact && V > 0.0) ? fmax(-fx, 0.0) : 0.0;
        double ramp = V > 0.0 ? fmin(V / vt, 1.0) : 1.0;
        double friction = mu_b * ramp * fmax((contact ? fy : 0.0) + mass * g, 0.0);
        u = -fmax(-u + dt * (pull - friction) / mass, 0.0);
        x = x + dt * u;
        states[2 * t + 2] = x;
        states[2 * t + 3] = u;
    }
    free(scratch);
    return 0;
}

/* One step of the coin under the tip (coin_step.h's coin_root); *force is the tip's friction
 * on the coin, and a coin the ground holds stays at rest. */
static double tip_coin_step(double u, double w, double cap_t, double cap_b, double c, double eps, int iterations,
                            double *force)
{
    const CoinRoot R = coin_root(c, u, w, cap_t, cap_b, eps, iterations);
    if (R.stuck) {
        *force = cap_t * reg(w, eps);
        return 0.0;
    }
    *force = cap_t * reg(w - R.v, eps);
    return R.v;
}

/* N independent coin steps (the kernel itself, for tests): u, w, cap_t, cap_b, c (N each) ->
 * u_next, force (N each). */
int deapull_coin_steps(int n, const double *u, const double *w, const double *cap_t, const double *cap_b,
                       const double *c, double eps, int iterations, double *u_next, double *force)
{
    for (int i = 0; i < n; i++)
        u_next[i] = tip_coin_step(u[i], w[i], cap_t[i], cap_b[i], c[i], eps, iterations, &force[i]);
    return 0;
}

/*
 * Tip-contact f = d(m): m maps the voltage to the tip's stroke X and pressing force Fy.
 * norm = v_mean, v_std, x_scale, fy_mean, fy_std;
 * phys = mass_kg, mu_b, mu_t, gravity, slip-rate regularisation, iterations.
 * The DEA starts at 0 V (X = 0).
 */
int deapull_rollout_tip(int n_layers, const int *sizes, const float *params, const double *norm, const double *phys,
                        int n_steps, const double *s0, const double *actions, double *states, double *forces)
{
    int w = max_width(n_layers, sizes);
    float *scratch = malloc(sizeof(float) * 2 * w);
    if (!scratch)
        return -1;
    const double mass = phys[0], mu_b = phys[1], mu_t = phys[2], g = phys[3], eps = phys[4];
    const int iterations = (int)phys[5];
    float in, out[2];
    in = (float)((0.0 - norm[0]) / norm[1]);
    mlp(n_layers, sizes, params, &in, out, scratch, scratch + w);
    const float rest = out[0];
    double x = s0[0], u = s0[1], stroke_prev = 0.0;
    states[0] = x;
    states[1] = u;
    for (int t = 0; t < n_steps; t++) {
        const double V = actions[2 * t], dt = actions[2 * t + 1];
        in = (float)((V - norm[0]) / norm[1]);
        mlp(n_layers, sizes, params, &in, out, scratch, scratch + w);
        const double stroke = (double)((float)norm[2] * (out[0] - rest));
        const double fy = (double)((float)norm[3] + (float)norm[4] * out[1]);
        const double normal = fmax(mass * g + fy, 0.0);
        double fx;
        u = tip_coin_step(u, (stroke - stroke_prev) / dt, mu_t * fmax(fy, 0.0), mu_b * normal, mass / dt, eps,
                          iterations, &fx);
        x = x + dt * u;
        stroke_prev = stroke;
        forces[2 * t] = fx;
        forces[2 * t + 1] = fy;
        states[2 * t + 2] = x;
        states[2 * t + 3] = u;
    }
    free(scratch);
    return 0;
}

/* NN baseline: s' = s + ds_std * MLP(in). norm = in_mean[4], in_std[4], ds_std[2]. */
int deapull_rollout_nn(int n_layers, const int *sizes, const float *params, const double *norm, int n_steps,
                       const double *s0, const double *actions, double *states)
{
    int w = max_width(n_layers, sizes);
    float *scratch = malloc(sizeof(float) * 2 * w);
    if (!scratch)
        return -1;
    double x = s0[0], u = s0[1];
    float in[4], dn[2];
    states[0] = x;
    states[1] = u;
    for (int t = 0; t < n_steps; t++) {
        normalised_inputs(norm, x, u, actions[2 * t], actions[2 * t + 1], in);
        mlp(n_layers, sizes, params, in, dn, scratch, scratch + w);
        x += norm[8] * (double)dn[0];
        u += norm[9] * (double)dn[1];
        states[2 * t + 2] = x;
        states[2 * t + 3] = u;
    }
    free(scratch);
    return 0;
}

static float sigmoid(float v) { return 1.0f / (1.0f + expf(-v)); }

/*
 * LSTM baseline over a sliding window of `window` (s, a) pairs, re-read from a zero state
 * at every step. The input projection W_ih x + b_ih + b_hh of each pair is computed once
 * and kept in a ring of `window` rows. norm = in_mean[4], in_std[4], ds_std[2].
 */
int deapull_rollout_lstm(int hidden, int window, const float *params, const double *norm, int n_steps,
                         const double *s0, const double *actions, double *states)
{
    const int H = hidden, G = 4 * hidden;
    const float *W_ih = params, *W_hh = W_ih + (long)G * 4, *b_ih = W_hh + (long)G * H, *b_hh = b_ih + G;
    const float *W_head = b_hh + G, *b_head = W_head + 2 * H;
    float *ring = malloc(sizeof(float) * ((long)window * G + G + 2 * H));
    if (!ring)
        return -1;
    float *gates = ring + (long)window * G, *h = gates + G, *c = h + H;
    double x = s0[0], u = s0[1];
    float in[4];
    states[0] = x;
    states[1] = u;
    for (int t = 0; t < n_steps; t++) {
        normalised_inputs(norm, x, u, actions[2 * t], actions[2 * t + 1], in);
        float *row = ring + (long)(t % window) * G;
        dense(G, 4, W_ih, b_ih, in, row, 0);
        for (int j = 0; j < G; j++)
            row[j] += b_hh[j];
        if (t == 0)
            for (int k = 1; k < window; k++)
                memcpy(ring + (long)k * G, row, sizeof(float) * G);
        memset(h, 0, sizeof(float) * 2 * H);
        for (int k = 0; k < window; k++) {
            const float *pre = ring + (long)((t + 1 + k) % window) * G;
            if (k == 0)
                memcpy(gates, pre, sizeof(float) * G);
            else {
                dense(G, H, W_hh, pre, h, gates, 0);
            }
            for (int j = 0; j < H; j++) {
                float i_g = sigmoid(gates[j]), f_g = sigmoid(gates[H + j]);
                float g_g = tanhf(gates[2 * H + j]), o_g = sigmoid(gates[3 * H + j]);
                c[j] = f_g * c[j] + i_g * g_g;
                h[j] = o_g * tanhf(c[j]);
            }
        }
        float dn[2];
        dense(2, H, W_head, b_head, h, dn, 0);
        x += norm[8] * (double)dn[0];
        u += norm[9] * (double)dn[1];
        states[2 * t + 2] = x;
        states[2 * t + 3] = u;
    }
    free(ring);
    return 0;
}
