// The MC-PILCO particle rollout in C++: the model it runs (task layout, policy, GP posterior,
// cost) as plain pointers into tensors held by the Python extension (native_rollout_ext.cpp),
// and the two loops over one shard of particles (native_rollout.cpp).  No torch headers here:
// the kernel file compiles in a few seconds and is the only one a change to the maths touches.
#pragma once

#include <cstdint>

namespace mcp {

constexpr int TILE = 16;  // particles per tile (two 8-float vectors)
constexpr int RB = 6;     // rows per block of a packed constant matrix (6 x 16 accumulators)

constexpr int MAX_GROUP = 8;  // most tiles per group (default_group)
constexpr int64_t FALLBACK_L2_BYTES = 256 << 10;  // L2 size assumed where none can be read

// the stages of the loops, each with its own clock (stage_seconds)
enum Stage {
    STAGE_FWD_INPUTS,  // forward: policy, GP inputs, MPK features psi
    STAGE_FWD_RBF,     // forward: E = W_aug x_aug and r = exp(E), per output
    STAGE_FWD_TRI,     // forward: [V; mean] = [B; alpha_aug] [psi; r] and the variance, per output
    STAGE_FWD_SAMPLE,  // forward: sample, clip, integrate, cost
    STAGE_BWD_SAMPLE,  // backward: cost, integration, sample
    STAGE_BWD_TRI,     // backward: dR = B^T V (-2 g_v) + alpha_aug g_m, per output
    STAGE_BWD_RBF,     // backward: W_t dE and dJ/dx^, per output
    STAGE_BWD_INPUTS,  // backward: MPK features, GP inputs, policy
    NUM_STAGES
};

// one packed constant matrix: block b holds rows RB b .. RB b + RB - 1, columns beg[b] ..
// end[b] - 1, column by column with its RB rows' entries together, from a + off[b]
struct Packed {
    const float *a;
    const int32_t *beg, *end;
    const int64_t *off;
    int blocks;
};

// Everything a rollout needs besides the policy parameters and the random numbers, float32.
// States: n coordinates; features f(x) (Fp of them) = plain coordinates, then (sin, cos) of
// each angle; GP inputs [f(x), u] (d = Fp + A); GP outputs (m): the velocity of each
// speed-integration pair, then each unpaired coordinate (its own change).
struct Model {
    int n, A, m, d, fp, n_plain, n_ang, n_pairs, n_delta, n_terms, nb;
    const int32_t *plain_idx, *angle_idx;        // (n_plain), (n_ang)
    const int32_t *position_idx, *velocity_idx;  // (n_pairs)
    const int32_t *delta_idx;                    // (n_delta)
    const float *u_mid, *u_half;                 // (A)
    const int32_t *cost_idx, *cost_mode;         // (n_terms): state index; 0 plain, 1 wrap, 2 abs
    const int32_t *cost_ref;                     // (n_terms): tracked state index, or -1
    const float *cost_target, *cost_ls, *cost_ls2;  // (n_terms): x*, l, l^2
    int n_bar;                                   // barriers c_b at state limits (cost.py)
    const int32_t *bar_idx;                      // (n_bar): state index
    const float *bar_lo, *bar_hi, *bar_inv_w;    // (n_bar): limits, 1 / width
    int n_osc;                                   // known oscillators (no GP output)
    const int32_t *osc_idx;                      // (n_osc, 2): position, velocity index
    const float *osc_coef;                       // (n_osc, 6): a_pp a_pv a_vp a_vv z_p z_v
    float dt;
    // the fused GP posterior (models/gp/fused.py): N points, MPK degree p, F MPK features
    int N, p, f;
    const int32_t *idx_a, *idx_c;  // (F): psi_f = z[idx_a[f]] z[idx_c[f]], z = [1, x^] (p = 2)
    const float *x_mean, *x_scale;  // (d)
    const float *y_mean, *y_scale;  // (m)
    const float *inv_l2;            // (m, d)
    const float *outputscale;       // (m)
    const float *sig_diag, *sig2;   // (p, m, d), (p, m); null for p = 0
    const float *noise_var;         // (m) added to the variance, or null
    const float *bound;             // (m) clip bound of Delta, or null
    const float *alpha_aug;         // (m, F + N): [alpha^T Phi, alpha^T] per output
    const Packed *w_aug, *fwd, *bwd, *w_t;  // (m) each
    int group;  // tiles that run each time step together (cache blocking, >= 1)
};

// floats of one tile's record of one time step (what its backward reads)
int64_t record_floats(const Model &M);

// Forward rollout of one shard of K candidates x per particles (rows candidate-major):
// x0 (K per, n), eps (H, K per, m), nu (H, K per, n); bytes[t] (K per, nb) uint8, the dropout
// mask 1[b < keep_t] keep_scale; policy parameters centers (K, nb, Fp), log_l (K, Fp),
// w (K, nb, A).  Writes costs (H, K per) and rec (H, K tiles, record_floats).
void forward(const Model &M, int horizon, int K, int per, const float *x0, const float *eps,
             const float *nu, const uint8_t *const *bytes, float keep_t, float keep_scale,
             const float *centers, const float *log_l, const float *w, float *costs, float *rec);

// floats per vector of the products' accumulators in this build: 16 with AVX-512, else 8
int vector_floats();

// the per-core L2 cache of this CPU in bytes (sysconf, else Linux's /sys), 0 if unknown
int64_t l2_cache_bytes();

// tiles per group for model M on a core with an L2 cache of l2_bytes (<= 0: FALLBACK_L2_BYTES):
// as many tiles as fit, with one output's constant matrices, in half of it, at most MAX_GROUP
int default_group(const Model &M, int64_t l2_bytes);

// seconds spent in each Stage since the last reset, summed over threads, into out
// (NUM_STAGES); reset: start the clocks again from zero
void stage_seconds(double *out, bool reset);

// rows of RBF kernel values (one per training point, output, tile and step) the forward loops
// took into the products since the last reset, and all of them, into out (2): a row is left
// out where every particle of the tile has its value at or below KERNEL_FLOOR (1e-30);
// reset: count again from zero
void kernel_rows(int64_t *out, bool reset);

// Backward rollout of that shard from g_costs (H, K per): adds dJ/dtheta to g_centers,
// g_log_l, g_w (shapes of the parameters).
void backward(const Model &M, int horizon, int K, int per, const float *rec,
              const float *centers, const float *log_l, const float *w, const float *g_costs,
              float *g_centers, float *g_log_l, float *g_w);

}  // namespace mcp
