// The MC-PILCO particle rollout (forward and backward through time) written by hand, for
// one shard of particles on one thread.  Built and called by native_rollout.py, which holds
// the symbol glossary and the maths (the same as the parts' analytic backward passes that
// direct_compile.py chains); this file only evaluates it.
//
// Layout: particles are processed in tiles of TILE = 16 (two 8-float vectors); within a
// tile every quantity is stored "structure of arrays", q[row][16].  The products with the
// GP's constant matrices are one register-blocked kernel (gemm_tile): RB = 6 rows x 16
// particles of accumulators, the constant matrix packed by blocks of RB rows, each block
// with its own range of columns (so the zeros of the triangular factors are skipped).
// The policy works on one particle at a time, vectorised over its basis functions.
//
// No torch headers: plain C++ with GCC vector extensions, called through ctypes (which
// releases the GIL, so shards run in parallel threads).

#include <cmath>
#include <cstdint>
#include <cstring>

typedef float v8 __attribute__((vector_size(32), aligned(32)));
typedef float v8u __attribute__((vector_size(32), aligned(4)));
typedef int32_t v8i __attribute__((vector_size(32), aligned(32)));
typedef uint8_t v8b __attribute__((vector_size(8), aligned(1)));

static const int TILE = 16;
#ifndef MCP_RB
#define MCP_RB 6
#endif
static const int RB = MCP_RB;  // rows per block of a packed matrix
static const float EXP_FLOOR = -87.0f;
static const float VAR_FLOOR = 1e-12f;

static inline v8 ld(const float *p) { return *(const v8u *)p; }
static inline void st(float *p, v8 v) { *(v8u *)p = v; }
static inline v8 bc(float a) { return (v8){a, a, a, a, a, a, a, a}; }

// exp(x) for x >= -87 (the callers clamp first; NaN passes through), about 1 ulp:
// x = n ln2 + r, |r| <= ln2/2, exp(r) by a degree-6 polynomial, 2^n by the exponent bits.
static inline v8 vexp(v8 x) {
    const v8 log2e = bc(1.44269504088896341f), c1 = bc(0.693359375f), c2 = bc(-2.12194440e-4f);
    const v8 magic = bc(12582912.0f);  // 1.5 2^23: (y + magic) - magic rounds y to nearest
    v8 n = (x * log2e + magic) - magic;
    v8 r = x - n * c1 - n * c2;
    v8 p = bc(1.9875691500e-4f);
    p = p * r + bc(1.3981999507e-3f);
    p = p * r + bc(8.3334519073e-3f);
    p = p * r + bc(4.1665795894e-2f);
    p = p * r + bc(1.6666665459e-1f);
    p = p * r + bc(5.0000001201e-1f);
    p = p * r * r + r + bc(1.0f);
    v8i e = __builtin_convertvector(n, v8i);
    e = (e + 127) << 23;
    v8 scale;
    std::memcpy(&scale, &e, sizeof(scale));
    return p * scale;
}

static inline float hsum(v8 v) {
    return ((v[0] + v[4]) + (v[1] + v[5])) + ((v[2] + v[6]) + (v[3] + v[7]));
}

// exp(max(x, -87)) with NaN kept (torch's clamp keeps NaN)
static inline v8 vexp_floor(v8 x) { return vexp(x < bc(EXP_FLOOR) ? bc(EXP_FLOOR) : x); }

// C[r][16] = sum_{k in [beg_b, end_b)} A[r][k] X[k][16] for the rows r of every block b
// (A packed: block b holds (end_b - beg_b) groups of its RB rows' entries, from off[b]).
static void gemm_tile(const float *A, const int *beg, const int *end, const int64_t *off,
                      int blocks, const float *X, float *C) {
    for (int b = 0; b < blocks; ++b) {
        v8 c0[RB], c1[RB];
#pragma GCC unroll 8
        for (int r = 0; r < RB; ++r) c0[r] = c1[r] = bc(0.0f);
        const float *a = A + off[b];
        for (int k = beg[b]; k < end[b]; ++k, a += RB) {
            v8 x0 = ld(X + k * TILE), x1 = ld(X + k * TILE + 8);
#pragma GCC unroll 8
            for (int r = 0; r < RB; ++r) {
                v8 ar = bc(a[r]);
                c0[r] += ar * x0;
                c1[r] += ar * x1;
            }
        }
        float *c = C + b * RB * TILE;
#pragma GCC unroll 8
        for (int r = 0; r < RB; ++r) {
            st(c + r * TILE, c0[r]);
            st(c + r * TILE + 8, c1[r]);
        }
    }
}

struct Packed {  // one packed constant matrix (see gemm_tile)
    const float *a;
    const int *beg, *end;
    const int64_t *off;
    int blocks;
};

struct Gp {  // the fused GP posterior of m outputs (models/gp/fused.py), float32
    int m, n, d, p, f;          // outputs, training points, inputs, MPK degree, MPK features
    const int *idx_a, *idx_c;   // psi_f = z[idx_a[f]] z[idx_c[f]] (p = 2)
    const float *x_mean, *x_scale;       // (d)
    const float *y_mean, *y_scale;       // (m)
    const float *inv_l2;                 // (m, d)
    const float *outputscale;            // (m)
    const float *sig_diag, *sig2;        // (p, m, d), (p, m)
    const float *noise_var;              // (m) added to the variance, or null
    const float *bound;                  // (m) clip bound of Delta, or null
    Packed w_aug[2], fwd[2], bwd[2], w_t[2];  // per output (m <= 2)
};

struct Pol {  // squashed RBF policy (policy.py), one candidate
    int nb;
    float u_max;
};

struct Cost {
    float l_x, l_theta, dt;
    int wrap;
};

static inline int pad_rows(int rows) { return (rows + RB - 1) / RB * RB; }

// per-tile record of the saved tensors of one step (floats, each block a multiple of 16)
struct Layout {
    int64_t phi, a, t, cso, sno, cs, sn, xs, R, V, active, fac, eps, sd, varon, inside, cx, cd,
        csg, cE, size;
    void init(int nb, int m, int n, int f, int p) {
        int64_t o = 0;
        phi = o; o += (int64_t)TILE * nb;
        a = o; o += 5 * TILE;
        t = o; o += TILE;
        cso = o; o += TILE;
        sno = o; o += TILE;
        cs = o; o += TILE;
        sn = o; o += TILE;
        xs = o; o += 6 * TILE;
        R = o; o += (int64_t)m * (f + n) * TILE;
        V = o; o += (int64_t)m * pad_rows(n + 1) * TILE;  // [V; mean] rows, padded
        active = o; o += m * TILE;
        fac = o; o += (int64_t)(p > 0 ? p : 1) * m * TILE;
        eps = o; o += 2 * TILE;
        sd = o; o += 2 * TILE;
        varon = o; o += 2 * TILE;
        inside = o; o += 2 * TILE;
        cx = o; o += TILE;
        cd = o; o += TILE;
        csg = o; o += TILE;
        cE = o; o += TILE;
        size = o;
    }
};

// scratch for one tile: the products' outputs (rows padded to RB)
struct Scratch {  // sizes for n <= 511, f <= 64, RB <= 8
    float E[520 * TILE];
    float dV[520 * TILE];
    float dR[584 * TILE];
    float dx[8 * TILE + RB * TILE];
};

extern "C" int64_t mcp_record_floats(int nb, int m, int n, int f, int p) {
    Layout L;
    L.init(nb, m, n, f, p);
    return L.size;
}

extern "C" int mcp_row_block() { return RB; }

extern "C" int mcp_tile() { return TILE; }

// policy for one particle: u = u_max tanh(sum_i w_i D_i phi_i / u_max)
static float policy_forward(const Pol &P, const float *bT, const float *bsq, const float *w,
                            const float *inv_l, const float *obs, const uint8_t *bytes,
                            float keep_t, float keep_scale, float *phi, float *a_out,
                            float *cso, float *sno) {
    const int nb = P.nb;
    float co = std::cos(obs[2]), so = std::sin(obs[2]);
    float feat[5] = {obs[0], obs[1], obs[3], so, co};
    float a[5], asq = 0.0f;
    for (int d = 0; d < 5; ++d) {
        a[d] = feat[d] * inv_l[d];
        asq += a[d] * a[d];
    }
    *cso = co;
    *sno = so;
    for (int d = 0; d < 5; ++d) a_out[d] = a[d];
    v8 acc = bc(0.0f);
    const v8 half_asq = bc(0.5f * asq), tv = bc(keep_t), sv = bc(keep_scale);
    int i = 0;
    for (; i + 8 <= nb; i += 8) {
        v8 lp = ld(bsq + i);  // -|b_i|^2 / 2
        for (int d = 0; d < 5; ++d) lp += bc(a[d]) * ld(bT + d * nb + i);
        lp -= half_asq;
        v8 ph = vexp_floor(lp);
        v8b by = *(const v8b *)(bytes + i);
        v8 bf = __builtin_convertvector(by, v8);
        ph = ph * (bf < tv ? sv : bc(0.0f));
        st(phi + i, ph);
        acc += ph * ld(w + i);
    }
    float s = hsum(acc);
    for (; i < nb; ++i) {
        float lp = bsq[i];
        for (int d = 0; d < 5; ++d) lp += a[d] * bT[d * nb + i];
        lp -= 0.5f * asq;
        float ph = std::exp(lp < EXP_FLOOR ? EXP_FLOOR : lp);
        ph *= ((float)bytes[i] < keep_t) ? keep_scale : 0.0f;
        phi[i] = ph;
        s += ph * w[i];
    }
    return std::tanh(s / P.u_max);
}

// one tile's time step: x (4 x 16, in/out), cost (16) out, record filled
static void step_forward_tile(const Gp &G, const Pol &P, const Cost &C, const float *bT,
                              const float *bsq, const float *w, const float *inv_l,
                              float *x, const float *eps, const float *nu,
                              const uint8_t *bytes, int valid, float keep_t, float keep_scale,
                              float *rec, const Layout &L, Scratch &W, float *cost) {
    const int m = G.m, n = G.n, d = G.d, F = G.f;
    float u[TILE];
    // policy, particle by particle
    for (int q = 0; q < TILE; ++q) {
        float obs[4];
        for (int j = 0; j < 4; ++j) obs[j] = x[j * TILE + q] + nu[j * TILE + q];
        float a[5];
        float t = policy_forward(P, bT, bsq, w, inv_l, obs,
                                 bytes + (int64_t)(q < valid ? q : 0) * P.nb, keep_t,
                                 keep_scale, rec + L.phi + (int64_t)q * P.nb, a,
                                 rec + L.cso + q, rec + L.sno + q);
        for (int j = 0; j < 5; ++j) rec[L.a + j * TILE + q] = a[j];
        rec[L.t + q] = t;
        u[q] = P.u_max * t;
    }
    // GP inputs [x, x_dot, theta_dot, sin theta, cos theta, u], standardised
    float *xs = rec + L.xs;
    for (int q = 0; q < TILE; ++q) {
        float th = x[2 * TILE + q];
        float sn = std::sin(th), cs = std::cos(th);
        rec[L.sn + q] = sn;
        rec[L.cs + q] = cs;
        float in[6] = {x[q], x[TILE + q], x[3 * TILE + q], sn, cs, u[q]};
        for (int j = 0; j < d; ++j) xs[j * TILE + q] = (in[j] - G.x_mean[j]) / G.x_scale[j];
    }
    float mean[2][TILE], var[2][TILE];
    for (int b = 0; b < m; ++b) {
        float *R = rec + L.R + (int64_t)b * (F + n) * TILE;
        float *V = rec + L.V + (int64_t)b * pad_rows(n + 1) * TILE;  // then the mean row
        // x_aug = [x^; 1; -||x^/l_b||^2 / 2] (8 rows) -> E = W_aug x_aug, r = exp(E)
        float xa[8 * TILE];
        for (int h = 0; h < 2; ++h) {
            v8 sq = bc(0.0f);
            for (int j = 0; j < d; ++j) {
                v8 v = ld(xs + j * TILE + 8 * h);
                st(xa + j * TILE + 8 * h, v);
                sq += bc(G.inv_l2[b * d + j]) * (v * v);
            }
            st(xa + d * TILE + 8 * h, bc(1.0f));
            st(xa + (d + 1) * TILE + 8 * h, sq * bc(-0.5f));
        }
        const Packed &Wa = G.w_aug[b];
        gemm_tile(Wa.a, Wa.beg, Wa.end, Wa.off, Wa.blocks, xa, W.E);
        for (int j = 0; j < n * TILE; j += 8) st(R + F * TILE + j, vexp_floor(ld(W.E + j)));
        // psi(z), z = [1, x^]
        if (G.p == 1) {
            for (int h = 0; h < TILE; h += 8) {
                st(R + h, bc(1.0f));
                for (int j = 0; j < d; ++j) st(R + (j + 1) * TILE + h, ld(xs + j * TILE + h));
            }
        } else if (G.p == 2) {
            for (int fi = 0; fi < F; ++fi) {
                int ia = G.idx_a[fi], ic = G.idx_c[fi];
                for (int h = 0; h < TILE; h += 8) {
                    v8 za = ia == 0 ? bc(1.0f) : ld(xs + (ia - 1) * TILE + h);
                    v8 zc = ic == 0 ? bc(1.0f) : ld(xs + (ic - 1) * TILE + h);
                    st(R + fi * TILE + h, za * zc);
                }
            }
        }
        // [V; mean] = [B; alpha_aug] R
        const Packed &Bf = G.fwd[b];
        gemm_tile(Bf.a, Bf.beg, Bf.end, Bf.off, Bf.blocks, R, V);
        for (int h = 0; h < TILE; h += 8) {
            v8 vv = bc(0.0f);
            for (int i = 0; i < n; ++i) {
                v8 s = ld(V + i * TILE + h);
                vv += s * s;
            }
            v8 prior = bc(G.outputscale[b]);
            if (G.p > 0) {
                v8 prod = bc(1.0f);
                for (int s = 0; s < G.p; ++s) {
                    v8 fac = bc(G.sig2[s * m + b]);
                    for (int j = 0; j < d; ++j) {
                        v8 v = ld(xs + j * TILE + h);
                        fac += bc(G.sig_diag[(s * m + b) * d + j]) * (v * v);
                    }
                    st(rec + L.fac + (s * m + b) * TILE + h, fac);
                    prod *= fac;
                }
                prior += prod;
            }
            v8 v = prior - vv;
            v8 on = v >= bc(0.0f) ? bc(1.0f) : bc(0.0f);
            v = v < bc(0.0f) ? bc(0.0f) : v;  // clamp_min keeps NaN
            st(rec + L.active + b * TILE + h, on);
            v8 ys = bc(G.y_scale[b]);
            st(mean[b] + h, ld(V + n * TILE + h) * ys + bc(G.y_mean[b]));
            v8 vo = v * (ys * ys);
            if (G.noise_var) vo += bc(G.noise_var[b]);
            st(var[b] + h, vo);
        }
    }
    // Delta = clip(mean + sqrt(max(var, floor)) eps), x+ = x A^T + Delta S^T, cost c(x+)
    for (int q = 0; q < TILE; ++q) {
        float delta[2];
        for (int b = 0; b < 2; ++b) {
            float vr = var[b][q];
            float on = vr >= VAR_FLOOR ? 1.0f : 0.0f;
            float sd = std::sqrt(vr < VAR_FLOOR ? VAR_FLOOR : vr);
            float e = eps[b * TILE + q];
            float dl = mean[b][q] + sd * e;
            float in = 1.0f;
            if (G.bound) {
                float bd = G.bound[b];
                in = (dl >= -bd && dl <= bd) ? 1.0f : 0.0f;
                dl = dl < -bd ? -bd : (dl > bd ? bd : dl);
            }
            rec[L.eps + b * TILE + q] = e;
            rec[L.sd + b * TILE + q] = sd;
            rec[L.varon + b * TILE + q] = on;
            rec[L.inside + b * TILE + q] = in;
            delta[b] = dl;
        }
        float dt = C.dt;
        float x0 = x[q], x1 = x[TILE + q], x2 = x[2 * TILE + q], x3 = x[3 * TILE + q];
        x[q] = x0 + dt * x1 + 0.5f * dt * delta[0];
        x[TILE + q] = x1 + delta[0];
        x[2 * TILE + q] = x2 + dt * x3 + 0.5f * dt * delta[1];
        x[3 * TILE + q] = x3 + delta[1];
        float px = x[q], th = x[2 * TILE + q];
        if (C.wrap) th = std::atan2(std::sin(th), std::cos(th));
        float dth = std::fabs(th) - (float)M_PI;
        float sg = th > 0.0f ? 1.0f : (th < 0.0f ? -1.0f : 0.0f);
        float z1 = dth / C.l_theta, z2 = px / C.l_x;
        float E = std::exp(-(z1 * z1) - z2 * z2);
        rec[L.cx + q] = px;
        rec[L.cd + q] = dth;
        rec[L.csg + q] = sg;
        rec[L.cE + q] = E;
        cost[q] = 1.0f - E;
    }
}

// one tile's backward: g (4 x 16) in: dJ/dx_{t+1}; out: dJ/dx_t.  gc (16): dJ/dc_{t+1}.
// Policy-parameter gradients accumulate into gb (5 x nb, sum_q G a), gcol (nb), gw (nb),
// gl (5, sum_q g_a o a); Gbuf (16 x nb) is scratch for the tile's G = dJ/d log phi.
static void step_backward_tile(const Gp &G, const Pol &P, const Cost &C, const float *bT,
                               const float *w, const float *inv_l, const float *rec,
                               const Layout &L, Scratch &W, float *g, const float *gc,
                               float *gb, float *gcol, float *gw, float *gl, float *Gbuf) {
    float gsq[TILE];
    const int m = G.m, n = G.n, d = G.d, F = G.f;
    float gmean[2][TILE], gvar[2][TILE], gstate[4][TILE];
    for (int q = 0; q < TILE; ++q) {
        // cost
        float E = rec[L.cE + q], gE2 = 2.0f * gc[q] * E;
        float g0 = g[q] + gE2 * rec[L.cx + q] / (C.l_x * C.l_x);
        float g1 = g[TILE + q];
        float g2 = g[2 * TILE + q] + gE2 * rec[L.cd + q] * rec[L.csg + q] / (C.l_theta * C.l_theta);
        float g3 = g[3 * TILE + q];
        // integration: g_state = g A, g_Delta = (g S) 1[inside]
        float dt = C.dt;
        gstate[0][q] = g0;
        gstate[1][q] = dt * g0 + g1;
        gstate[2][q] = g2;
        gstate[3][q] = dt * g2 + g3;
        float gd[2] = {(0.5f * dt * g0 + g1) * rec[L.inside + q],
                       (0.5f * dt * g2 + g3) * rec[L.inside + TILE + q]};
        for (int b = 0; b < 2; ++b) {
            gmean[b][q] = gd[b];
            gvar[b][q] = gd[b] * rec[L.eps + b * TILE + q] / (2.0f * rec[L.sd + b * TILE + q]) *
                         rec[L.varon + b * TILE + q];
        }
    }
    const float *xs = rec + L.xs;
    float dxs[6 * TILE];
    for (int j = 0; j < 6 * TILE; ++j) dxs[j] = 0.0f;
    float dpsi[64 * TILE];
    if (F) std::memset(dpsi, 0, sizeof(float) * F * TILE);
    float wprior[6 * TILE];  // sum_{s,b} gv_b others_{s,b} Sigma_{s,b,j}
    for (int j = 0; j < d * TILE; ++j) wprior[j] = 0.0f;
    for (int b = 0; b < m; ++b) {
        const float *R = rec + L.R + (int64_t)b * (F + n) * TILE;
        const float *V = rec + L.V + (int64_t)b * pad_rows(n + 1) * TILE;
        for (int h = 0; h < TILE; h += 8) {
            v8 ys = bc(G.y_scale[b]);
            v8 gm = ld(gmean[b] + h) * ys;
            v8 gv = ld(gvar[b] + h) * (ys * ys) * ld(rec + L.active + b * TILE + h);
            v8 m2gv = bc(-2.0f) * gv;
            for (int i = 0; i < n; ++i) st(W.dV + i * TILE + h, ld(V + i * TILE + h) * m2gv);
            st(W.dV + n * TILE + h, gm);
            if (G.p > 0) {  // prior: d/dx^ prod_s fac_s = sum_s prod_{s' != s} fac_s' 2 Sigma_s x^
                for (int s = 0; s < G.p; ++s) {
                    v8 other = G.p == 1 ? bc(1.0f)
                                        : ld(rec + L.fac + ((1 - s) * m + b) * TILE + h);
                    v8 wv = gv * other;
                    for (int j = 0; j < d; ++j) {
                        v8 acc = ld(wprior + j * TILE + h);
                        st(wprior + j * TILE + h, acc + wv * bc(G.sig_diag[(s * m + b) * d + j]));
                    }
                }
            }
        }
        // dR = [B; alpha_aug]^T [dV; g_m]
        const Packed &Bb = G.bwd[b];
        gemm_tile(Bb.a, Bb.beg, Bb.end, Bb.off, Bb.blocks, W.dV, W.dR);
        for (int j = 0; j < F * TILE; j += 8) st(dpsi + j, ld(dpsi + j) + ld(W.dR + j));
        // dE = dr o r, then [(X/l^2)^T dE; 1^T dE] = W_t dE
        for (int j = 0; j < n * TILE; j += 8)
            st(W.dR + F * TILE + j, ld(W.dR + F * TILE + j) * ld(R + F * TILE + j));
        const Packed &Wt = G.w_t[b];
        gemm_tile(Wt.a, Wt.beg, Wt.end, Wt.off, Wt.blocks, W.dR + F * TILE, W.dx);
        for (int h = 0; h < TILE; h += 8) {
            v8 sumE = ld(W.dx + d * TILE + h);
            for (int j = 0; j < d; ++j) {
                v8 acc = ld(dxs + j * TILE + h) + ld(W.dx + j * TILE + h);
                acc -= ld(xs + j * TILE + h) * (sumE * bc(G.inv_l2[b * d + j]));
                st(dxs + j * TILE + h, acc);
            }
        }
    }
    if (G.p == 1) {
        for (int j = 0; j < d * TILE; ++j) dxs[j] += dpsi[TILE + j];
    } else if (G.p == 2) {
        for (int fi = 0; fi < F; ++fi) {
            int ia = G.idx_a[fi], ic = G.idx_c[fi];
            for (int h = 0; h < TILE; h += 8) {
                v8 dp = ld(dpsi + fi * TILE + h);
                v8 za = ia == 0 ? bc(1.0f) : ld(xs + (ia - 1) * TILE + h);
                v8 zc = ic == 0 ? bc(1.0f) : ld(xs + (ic - 1) * TILE + h);
                if (ia > 0) st(dxs + (ia - 1) * TILE + h, ld(dxs + (ia - 1) * TILE + h) + dp * zc);
                if (ic > 0) st(dxs + (ic - 1) * TILE + h, ld(dxs + (ic - 1) * TILE + h) + dp * za);
            }
        }
    }
    if (G.p > 0)
        for (int j = 0; j < d * TILE; ++j) dxs[j] += 2.0f * xs[j] * wprior[j];
    // GP inputs -> state and action; policy
    for (int q = 0; q < TILE; ++q) {
        float gin[6];
        for (int j = 0; j < 6; ++j) gin[j] = dxs[j * TILE + q] / G.x_scale[j];
        float sn = rec[L.sn + q], cs = rec[L.cs + q];
        float gx0 = gstate[0][q] + gin[0];
        float gx1 = gstate[1][q] + gin[1];
        float gx2 = gstate[2][q] + gin[3] * cs - gin[4] * sn;
        float gx3 = gstate[3][q] + gin[2];
        float t = rec[L.t + q];
        float gs = gin[5] * (1.0f - t * t);  // dJ/d(phi w)
        const float *phi = rec + L.phi + (int64_t)q * P.nb;
        float *Gq = Gbuf + (int64_t)q * P.nb;
        float a[5];
        for (int j = 0; j < 5; ++j) a[j] = rec[L.a + j * TILE + q];
        gsq[q] = gs;
        v8 ga[5] = {bc(0), bc(0), bc(0), bc(0), bc(0)};
        v8 rows = bc(0.0f);
        const v8 gsv = bc(gs);
        int i = 0;
        for (; i + 8 <= P.nb; i += 8) {
            v8 Gi = gsv * ld(w + i) * ld(phi + i);  // dJ/d log phi_i
            st(Gq + i, Gi);
            rows += Gi;
            for (int j = 0; j < 5; ++j) ga[j] += Gi * ld(bT + j * P.nb + i);
        }
        float rs = hsum(rows), gaj[5];
        for (int j = 0; j < 5; ++j) gaj[j] = hsum(ga[j]);
        for (; i < P.nb; ++i) {
            float Gi = gs * w[i] * phi[i];
            Gq[i] = Gi;
            rs += Gi;
            for (int j = 0; j < 5; ++j) gaj[j] += Gi * bT[j * P.nb + i];
        }
        float gf[5];
        for (int j = 0; j < 5; ++j) {
            float g_a = gaj[j] - a[j] * rs;
            gl[j] += g_a * a[j];
            gf[j] = g_a * inv_l[j];
        }
        float co = rec[L.cso + q], so = rec[L.sno + q];
        g[q] = gx0 + gf[0];
        g[TILE + q] = gx1 + gf[1];
        g[2 * TILE + q] = gx2 + gf[3] * co - gf[4] * so;
        g[3 * TILE + q] = gx3 + gf[2];
    }
    // the tile's sums over its particles: colsum(G), phi^T gs and G^T a, one pass per column
    const float *a = rec + L.a, *phi = rec + L.phi;
    int i = 0;
    for (; i + 8 <= P.nb; i += 8) {
        v8 sc = bc(0), sw = bc(0), sb[5] = {bc(0), bc(0), bc(0), bc(0), bc(0)};
        for (int q = 0; q < TILE; ++q) {
            v8 Gi = ld(Gbuf + (int64_t)q * P.nb + i);
            sc += Gi;
            sw += ld(phi + (int64_t)q * P.nb + i) * bc(gsq[q]);
            for (int j = 0; j < 5; ++j) sb[j] += Gi * bc(a[j * TILE + q]);
        }
        st(gcol + i, ld(gcol + i) + sc);
        st(gw + i, ld(gw + i) + sw);
        for (int j = 0; j < 5; ++j) st(gb + j * P.nb + i, ld(gb + j * P.nb + i) + sb[j]);
    }
    for (; i < P.nb; ++i) {
        for (int q = 0; q < TILE; ++q) {
            float Gi = Gbuf[(int64_t)q * P.nb + i];
            gcol[i] += Gi;
            gw[i] += phi[(int64_t)q * P.nb + i] * gsq[q];
            for (int j = 0; j < 5; ++j) gb[j * P.nb + i] += Gi * a[j * TILE + q];
        }
    }
}

struct Shard {  // one shard's rollout: rows = K candidates x per particles each
    int horizon, K, per, tiles_per;  // tiles per candidate
};

// Forward rollout of one shard.  x0 (K*per, 4), eps (H, K*per, 2), nu (H, K*per, 4) row-major;
// bytes[t] (K*per, nb) uint8; theta per candidate: centers (K, nb, 5), log_l (K, 5),
// w (K, nb).  costs (H, K*per) out; rec (H, K*tiles_per, record) out.
extern "C" int mcp_forward(const Gp *G, const Pol *P, const Cost *C, const Shard *S,
                           const float *x0, const float *eps, const float *nu,
                           const uint8_t *const *bytes, float keep_t, float keep_scale,
                           const float *centers, const float *log_l, const float *w,
                           float *costs, float *rec) {
    if (G->m > 2 || G->f > 64 || G->n + 1 > 512 || G->d != 6) return 1;
    const int nb = P->nb, rows = S->K * S->per;
    Layout L;
    L.init(nb, G->m, G->n, G->f, G->p);
    Scratch *W = new Scratch;
    float *bT = new float[5 * nb], *bsq = new float[nb];
    float x[4 * TILE], e[2 * TILE], v[4 * TILE], cost[TILE];
    for (int k = 0; k < S->K; ++k) {
        float inv_l[5];
        for (int j = 0; j < 5; ++j) inv_l[j] = std::exp(-log_l[k * 5 + j]);
        for (int i = 0; i < nb; ++i) {
            float s = 0.0f;
            for (int j = 0; j < 5; ++j) {
                float bv = centers[((int64_t)k * nb + i) * 5 + j] * inv_l[j];
                bT[j * nb + i] = bv;
                s += bv * bv;
            }
            bsq[i] = -0.5f * s;
        }
        const float *wk = w + (int64_t)k * nb;
        for (int tile = 0; tile < S->tiles_per; ++tile) {
            int first = k * S->per + tile * TILE;
            int valid = S->per - tile * TILE < TILE ? S->per - tile * TILE : TILE;
            for (int j = 0; j < 4 * TILE; ++j) x[j] = 0.0f;
            for (int q = 0; q < valid; ++q)
                for (int j = 0; j < 4; ++j) x[j * TILE + q] = x0[(int64_t)(first + q) * 4 + j];
            for (int t = 0; t < S->horizon; ++t) {
                for (int j = 0; j < 4 * TILE; ++j) v[j] = 0.0f;
                for (int j = 0; j < 2 * TILE; ++j) e[j] = 0.0f;
                for (int q = 0; q < valid; ++q) {
                    int64_t r = (int64_t)t * rows + first + q;
                    for (int j = 0; j < 4; ++j) v[j * TILE + q] = nu[r * 4 + j];
                    for (int j = 0; j < 2; ++j) e[j * TILE + q] = eps[r * 2 + j];
                }
                float *rc = rec + ((int64_t)t * S->K * S->tiles_per + k * S->tiles_per + tile) * L.size;
                step_forward_tile(*G, *P, *C, bT, bsq, wk, inv_l, x, e, v,
                                  bytes[t] + (int64_t)first * nb, valid, keep_t, keep_scale, rc, L,
                                  *W, cost);
                for (int q = 0; q < valid; ++q) costs[(int64_t)t * rows + first + q] = cost[q];
            }
        }
    }
    delete W;
    delete[] bT;
    delete[] bsq;
    return 0;
}

// Backward rollout of one shard from g_costs (H, K*per): adds dJ/dtheta to g_centers
// (K, nb, 5), g_log_l (K, 5), g_w (K, nb).
extern "C" int mcp_backward(const Gp *G, const Pol *P, const Cost *C, const Shard *S,
                            const float *rec, const float *centers, const float *log_l,
                            const float *w, const float *g_costs, float *g_centers,
                            float *g_log_l, float *g_w) {
    const int nb = P->nb, rows = S->K * S->per;
    Layout L;
    L.init(nb, G->m, G->n, G->f, G->p);
    Scratch *W = new Scratch;
    float *bT = new float[5 * nb], *gb = new float[5 * nb], *gcol = new float[nb];
    float *gw = new float[nb], *Gbuf = new float[(int64_t)TILE * nb];
    float g[4 * TILE], gc[TILE], gl[5];
    for (int k = 0; k < S->K; ++k) {
        float inv_l[5];
        for (int j = 0; j < 5; ++j) inv_l[j] = std::exp(-log_l[k * 5 + j]);
        for (int i = 0; i < nb; ++i)
            for (int j = 0; j < 5; ++j)
                bT[j * nb + i] = centers[((int64_t)k * nb + i) * 5 + j] * inv_l[j];
        std::memset(gb, 0, sizeof(float) * 5 * nb);
        std::memset(gcol, 0, sizeof(float) * nb);
        std::memset(gw, 0, sizeof(float) * nb);
        for (int j = 0; j < 5; ++j) gl[j] = 0.0f;
        const float *wk = w + (int64_t)k * nb;
        for (int tile = 0; tile < S->tiles_per; ++tile) {
            int first = k * S->per + tile * TILE;
            int valid = S->per - tile * TILE < TILE ? S->per - tile * TILE : TILE;
            for (int j = 0; j < 4 * TILE; ++j) g[j] = 0.0f;
            for (int t = S->horizon - 1; t >= 0; --t) {
                for (int q = 0; q < TILE; ++q)
                    gc[q] = q < valid ? g_costs[(int64_t)t * rows + first + q] : 0.0f;
                const float *rc =
                    rec + ((int64_t)t * S->K * S->tiles_per + k * S->tiles_per + tile) * L.size;
                step_backward_tile(*G, *P, *C, bT, wk, inv_l, rc, L, *W, g, gc, gb, gcol, gw,
                                   gl, Gbuf);
            }
        }
        // g_b = G^T a - b o colsum(G); g_c = g_b / l; g_log_l = -(sum g_a o a + sum g_b o b)
        for (int j = 0; j < 5; ++j) {
            float sb = 0.0f;
            for (int i = 0; i < nb; ++i) {
                float bv = bT[j * nb + i];
                float g_b = gb[j * nb + i] - bv * gcol[i];
                sb += g_b * bv;
                g_centers[((int64_t)k * nb + i) * 5 + j] += g_b * inv_l[j];
            }
            g_log_l[k * 5 + j] += -(gl[j] + sb);
        }
        for (int i = 0; i < nb; ++i) g_w[(int64_t)k * nb + i] += gw[i];
    }
    delete W;
    delete[] bT;
    delete[] gb;
    delete[] gcol;
    delete[] gw;
    delete[] Gbuf;
    return 0;
}
