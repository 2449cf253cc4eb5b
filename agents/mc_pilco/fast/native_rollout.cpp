// The MC-PILCO particle rollout (forward and backward through time) written by hand, for
// one shard of particles on one thread, for any task layout.  native_rollout.py holds the
// symbol glossary and the maths (the same as the parts' analytic backward passes that
// backends.py chains in PyTorch ops); this file only evaluates it.
//
// Layout: particles are processed in tiles of TILE = 16 (two 8-float vectors); within a
// tile every quantity is stored "structure of arrays", q[row][16].  The products with the
// GP's constant matrices are one register-blocked kernel (gemm_tile): RB = 6 rows x 16
// particles of accumulators, the constant matrix packed by blocks of RB rows, each block
// with its own range of columns (so the zeros of the triangular factors are skipped).
// The policy works on one particle at a time, vectorised over its basis functions.
//
// No torch headers: plain C++ with GCC vector extensions; native_rollout_ext.cpp binds it.

#include "native_rollout.h"

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <string>
#include <vector>

#if defined(__SSE__)
#include <xmmintrin.h>
#endif

namespace mcp {
namespace {

typedef float v8 __attribute__((vector_size(32), aligned(32)));
typedef float v8u __attribute__((vector_size(32), aligned(4)));
typedef int32_t v8i __attribute__((vector_size(32), aligned(32)));
typedef uint8_t v8b __attribute__((vector_size(8), aligned(1)));

// The products' accumulators: with AVX-512 one 16-float vector per row of a tile (the 16
// particles), else two 8-float vectors.  Per lane the same multiply-adds in the same order,
// so both give the same bits; the wide one issues half the instructions (the difference on
// cores with two 512-bit multiply-add units, e.g. Intel's server cores; Zen 4 splits a
// 512-bit operation into two 256-bit halves and runs both at the same rate).
#if defined(__AVX512F__)
#define MCP_WIDE 1
typedef float v16 __attribute__((vector_size(64), aligned(64)));
typedef float v16u __attribute__((vector_size(64), aligned(4)));
#else
#define MCP_WIDE 0
#endif

constexpr int POLICY_CHAINS = 4;  // independent sums the policy's loops keep (FMA latency)
static_assert(POLICY_CHAINS == 4, "the policy loops add their 4 sums by hand");
constexpr float EXP_FLOOR = -87.0f;  // exp's argument floor (models/numerics.py)
constexpr float VAR_FLOOR = 1e-12f;  // variance floor of the sample (dynamics.py)
// RBF kernel values at or below this are left out of the products where every particle of a
// tile has them (active_row): exp(-69); times the GP's constants they are below 1e-20, far
// under the float32 rounding of the posterior they would add to
constexpr float KERNEL_FLOOR = 1e-30f;
constexpr float PI_F = 3.14159265358979323846f;  // pi rounded to float, as torch rounds it
constexpr float TWO_PI_F = 6.28318530717958647692f;  // 2 pi rounded to float

inline v8 ld(const float *p) { return *(const v8u *)p; }
inline void st(float *p, v8 v) { *(v8u *)p = v; }
inline v8 bc(float a) { return (v8){a, a, a, a, a, a, a, a}; }
#if MCP_WIDE
inline v16 ld16(const float *p) { return *(const v16u *)p; }
inline v16 bc16(float a) { return (v16){a, a, a, a, a, a, a, a, a, a, a, a, a, a, a, a}; }
inline v8 lo8(v16 v) { return __builtin_shufflevector(v, v, 0, 1, 2, 3, 4, 5, 6, 7); }
inline v8 hi8(v16 v) { return __builtin_shufflevector(v, v, 8, 9, 10, 11, 12, 13, 14, 15); }
#endif

// exp(x) for x >= -87 (the callers clamp first; NaN passes through), about 1 ulp:
// x = n ln2 + r, |r| <= ln2/2, exp(r) by a degree-6 polynomial, 2^n by the exponent bits.
inline v8 vexp(v8 x) {
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

inline float hsum(v8 v) {
    return ((v[0] + v[4]) + (v[1] + v[5])) + ((v[2] + v[6]) + (v[3] + v[7]));
}

// exp(max(x, -87)) with NaN kept (torch's clamp keeps NaN)
inline v8 vexp_floor(v8 x) { return vexp(x < bc(EXP_FLOOR) ? bc(EXP_FLOOR) : x); }

inline float exp_floor(float x) { return std::exp(x < EXP_FLOOR ? EXP_FLOOR : x); }

inline int pad_rows(int rows) { return (rows + RB - 1) / RB * RB; }

// whether a row of kernel values of a tile (r0: particles 0-7, r1: 8-15) takes part in the
// products: some particle's value is above KERNEL_FLOOR, or NaN (which must propagate)
inline bool active_row(v8 r0, v8 r1) {
    const v8i low = (r0 <= bc(KERNEL_FLOOR)) & (r1 <= bc(KERNEL_FLOOR));
    uint64_t u[4];
    std::memcpy(u, &low, sizeof(u));
    return (u[0] & u[1] & u[2] & u[3]) != ~uint64_t(0);
}

// whether every exponent of a row of a tile (x0: particles 0-7, x1: 8-15) is below EXP_FLOOR
// (false where one is NaN), so that its kernel values are all exp(EXP_FLOOR)
inline bool below_exp_floor(v8 x0, v8 x1) {
    const v8i low = (x0 < bc(EXP_FLOOR)) & (x1 < bc(EXP_FLOOR));
    uint64_t u[4];
    std::memcpy(u, &low, sizeof(u));
    return (u[0] & u[1] & u[2] & u[3]) == ~uint64_t(0);
}

// The columns of a tile's X2 (below) that a product uses: those listed in idx[0 .. n - 1]
// (ascending); idx null: all of them.
struct Cols {
    const int32_t *idx = nullptr;
    int n = 0;
};

// C_r[16] = sum_{k in [beg_b, end_b)} A[r][k] X(k)[16] for the rows r of every block b of
// the packed matrix P, where X(k) = X1 + 16 k for k < split, X2 + 16 (k - split) after;
// each block's RB x 16 results go, still in registers, to epi(first row, c0, c1) (c0[r],
// c1[r]: particles 0-7 and 8-15 of row first + r), which stores or consumes them.
// LIST: only the columns k >= split listed in cols are taken (the others are zero for every
// particle of the tile); skip (one byte per block, or null): blocks whose rows are not
// needed, left out without a call of epi.  (Each instantiation has one loop over X2: with
// both, GCC keeps the accumulators in memory.)
template <bool LIST, class Epi>
inline void gemm_tile_t(const Packed &P, const float *X1, int split, const float *X2, Epi &&epi,
                        Cols cols, const uint8_t *skip) {
    for (int b = 0; b < P.blocks; ++b) {
        if (skip && skip[b]) continue;
        v8 c0[RB], c1[RB];
#pragma GCC unroll 8
        for (int r = 0; r < RB; ++r) c0[r] = c1[r] = bc(0.0f);
        const float *a = P.a + P.off[b];
        int k = P.beg[b];
        const int e = P.end[b], e1 = e < split ? e : split;
        for (; k < e1; ++k, a += RB) {
            v8 x0 = ld(X1 + k * TILE), x1 = ld(X1 + k * TILE + 8);
#pragma GCC unroll 8
            for (int r = 0; r < RB; ++r) {
                v8 ar = bc(a[r]);
                c0[r] += ar * x0;
                c1[r] += ar * x1;
            }
        }
        if constexpr (LIST) {  // the listed columns of X2 in [k, e), column j at a0 + RB j
            const float *a0 = a - (int64_t)(k - split) * RB;
            const int32_t *q = std::lower_bound(cols.idx, cols.idx + cols.n, k - split);
            for (const int32_t *qe = cols.idx + cols.n; q < qe && *q < e - split; ++q) {
                const float *x = X2 + (int64_t)*q * TILE, *aj = a0 + (int64_t)*q * RB;
                v8 x0 = ld(x), x1 = ld(x + 8);
#pragma GCC unroll 8
                for (int r = 0; r < RB; ++r) {
                    v8 ar = bc(aj[r]);
                    c0[r] += ar * x0;
                    c1[r] += ar * x1;
                }
            }
        } else if (k < e) {
            const float *x = X2 + (int64_t)(k - split) * TILE;
            for (; k < e; ++k, a += RB, x += TILE) {
                v8 x0 = ld(x), x1 = ld(x + 8);
#pragma GCC unroll 8
                for (int r = 0; r < RB; ++r) {
                    v8 ar = bc(a[r]);
                    c0[r] += ar * x0;
                    c1[r] += ar * x1;
                }
            }
        }
        v8 o0[RB], o1[RB];  // copies: the accumulators' addresses are never taken
#pragma GCC unroll 8
        for (int r = 0; r < RB; ++r) o0[r] = c0[r], o1[r] = c1[r];
        epi(b * RB, o0, o1);
    }
}

#if MCP_WIDE
// gemm_tile_t with one 16-float accumulator per row: the same sums, lane by lane
template <bool LIST, class Epi>
inline void gemm_tile_w(const Packed &P, const float *X1, int split, const float *X2, Epi &&epi,
                        Cols cols, const uint8_t *skip) {
    for (int b = 0; b < P.blocks; ++b) {
        if (skip && skip[b]) continue;
        v16 c[RB];
#pragma GCC unroll 8
        for (int r = 0; r < RB; ++r) c[r] = v16{};
        const float *a = P.a + P.off[b];
        int k = P.beg[b];
        const int e = P.end[b], e1 = e < split ? e : split;
        for (; k < e1; ++k, a += RB) {
            const v16 x = ld16(X1 + k * TILE);
#pragma GCC unroll 8
            for (int r = 0; r < RB; ++r) c[r] += bc16(a[r]) * x;
        }
        if constexpr (LIST) {
            const float *a0 = a - (int64_t)(k - split) * RB;
            const int32_t *q = std::lower_bound(cols.idx, cols.idx + cols.n, k - split);
            for (const int32_t *qe = cols.idx + cols.n; q < qe && *q < e - split; ++q) {
                const v16 x = ld16(X2 + (int64_t)*q * TILE);
                const float *aj = a0 + (int64_t)*q * RB;
#pragma GCC unroll 8
                for (int r = 0; r < RB; ++r) c[r] += bc16(aj[r]) * x;
            }
        } else if (k < e) {
            const float *x = X2 + (int64_t)(k - split) * TILE;
            for (; k < e; ++k, a += RB, x += TILE) {
                const v16 xv = ld16(x);
#pragma GCC unroll 8
                for (int r = 0; r < RB; ++r) c[r] += bc16(a[r]) * xv;
            }
        }
        v8 o0[RB], o1[RB];
#pragma GCC unroll 8
        for (int r = 0; r < RB; ++r) o0[r] = lo8(c[r]), o1[r] = hi8(c[r]);
        epi(b * RB, o0, o1);
    }
}
#endif

// gemm_tile_t over the columns cols lists (idx null: all of them)
template <class Epi>
inline void gemm_tile(const Packed &P, const float *X1, int split, const float *X2, Epi &&epi,
                      Cols cols = {}, const uint8_t *skip = nullptr) {
#if MCP_WIDE
    if (cols.idx)
        gemm_tile_w<true>(P, X1, split, X2, epi, cols, skip);
    else
        gemm_tile_w<false>(P, X1, split, X2, epi, cols, skip);
#else
    if (cols.idx)
        gemm_tile_t<true>(P, X1, split, X2, epi, cols, skip);
    else
        gemm_tile_t<false>(P, X1, split, X2, epi, cols, skip);
#endif
}

// gemm_tile storing every row it computes (the padding rows too) in C (rows x 16)
inline void gemm_tile_store(const Packed &P, const float *X1, int split, const float *X2,
                            float *C, Cols cols = {}) {
    gemm_tile(
        P, X1, split, X2,
        [C](int first, const v8 *c0, const v8 *c1) {
            float *c = C + (int64_t)first * TILE;
#pragma GCC unroll 8
            for (int r = 0; r < RB; ++r) {
                st(c + r * TILE, c0[r]);
                st(c + r * TILE + 8, c1[r]);
            }
        },
        cols);
}

constexpr int NO_SPLIT = 1 << 30;  // split of a gemm_tile whose X is one block of rows

constexpr int PREFETCH_LINES = 16;  // cache lines of the next record requested per call of next()

// Requests the records the backward loop reads next (written long before and since evicted to
// memory: one per tile of a group) into the caches a few lines at a time, between the kernel's
// blocks, so that their loads overlap the arithmetic instead of waiting at the start of a step.
struct Prefetch {
    std::vector<const char *> p, end;
    size_t at = 0;
    void start(const std::vector<const float *> &recs, int64_t floats) {
        p.clear();
        end.clear();
        at = 0;
        for (const float *rec : recs) {
            if (!rec) continue;
            p.push_back((const char *)rec);
            end.push_back((const char *)rec + floats * (int64_t)sizeof(float));
        }
    }
    void next() {
        for (int i = 0; i < PREFETCH_LINES && at < p.size(); ++i) {
            __builtin_prefetch(p[at], 0, 3);
            p[at] += 64;
            if (p[at] >= end[at]) ++at;
        }
    }
};

// Stage clocks: nanoseconds spent in each stage of the loops, summed over every thread and
// call since the last reset (stage_names() in native_rollout.h names them).
std::atomic<int64_t> STAGE_NS[NUM_STAGES];
// rows of RBF kernel values of the forward loops' tiles (per output and step): taken, all
std::atomic<int64_t> KERNEL_ROWS[2];

inline int64_t now_ns() {
    return std::chrono::duration_cast<std::chrono::nanoseconds>(
               std::chrono::steady_clock::now().time_since_epoch())
        .count();
}

// a loop's own stage clocks, added to STAGE_NS once when it ends
struct StageClock {
    int64_t ns[NUM_STAGES] = {};
    int64_t rows[2] = {};  // kernel rows taken, all (KERNEL_ROWS)
    int64_t last = now_ns();
    void lap(int stage) {  // the time since the last lap goes to `stage`
        const int64_t t = now_ns();
        ns[stage] += t - last;
        last = t;
    }
    ~StageClock() {
        for (int i = 0; i < NUM_STAGES; ++i) STAGE_NS[i].fetch_add(ns[i]);
        for (int i = 0; i < 2; ++i) KERNEL_ROWS[i].fetch_add(rows[i]);
    }
};

// Denormal floats flushed to zero (FTZ) and read as zero (DAZ) while a loop runs, the
// caller's floating-point control restored after.  The kernel values at the exponential's
// floor (exp(-87) ~ 1.6e-38) times the GP's constants are denormal; on CPUs that handle
// denormals by microcode assists (most Intel cores) every such product costs about a hundred
// cycles.  The values lost are below 1.2e-38, far under the float32 rounding of the results.
struct FlushDenormals {
#if defined(__SSE__)
    unsigned saved = _mm_getcsr();
    FlushDenormals() { _mm_setcsr(saved | 0x8040u); }  // FTZ (bit 15) | DAZ (bit 6)
    ~FlushDenormals() { _mm_setcsr(saved); }
#endif
};

// offsets (floats) of a tile's record of one step, each block a multiple of 16
struct Lay {
    int64_t phi, a, t, so, co, sn, cs, xs, psi, r, V, active, fac, eps, sd, varon, inside, cd,
        cE, cb, size;
    int vrows;  // rows of one output's [V; mean], padded to RB
    explicit Lay(const Model &M) {
        const int64_t T = TILE;
        vrows = pad_rows(M.N + 1);
        int64_t o = 0;
        auto take = [&o](int64_t floats) {
            int64_t at = o;
            o += floats;
            return at;
        };
        phi = take(T * M.nb);
        a = take(T * M.fp);
        t = take(T * M.A);
        so = take(T * M.n_ang);
        co = take(T * M.n_ang);
        sn = take(T * M.n_ang);
        cs = take(T * M.n_ang);
        xs = take(T * M.d);
        psi = take(T * M.f);
        r = take(T * M.m * M.N);
        V = take(T * M.m * vrows);
        active = take(T * M.m);
        fac = take(T * M.m * (M.p > 0 ? M.p : 1));
        eps = take(T * M.m);
        sd = take(T * M.m);
        varon = take(T * M.m);
        inside = take(T * M.m);
        cd = take(T * M.n_terms);
        cE = take(T);
        cb = take(T * M.n_bar);
        size = o;
    }
};

// one candidate's policy constants: b = c / l transposed (Fp, nb), -|b_i|^2 / 2, w^T (A, nb)
struct Pol {
    std::vector<float> bT, bsq, wT, inv_l;
    Pol(const Model &M) : bT(M.fp * M.nb), bsq(M.nb), wT(M.A * M.nb), inv_l(M.fp) {}
    void load(const Model &M, const float *centers, const float *log_l, const float *w) {
        const int nb = M.nb, fp = M.fp;
        for (int j = 0; j < fp; ++j) inv_l[j] = std::exp(-log_l[j]);
        for (int i = 0; i < nb; ++i) {
            float s = 0.0f;
            for (int j = 0; j < fp; ++j) {
                float bv = centers[(int64_t)i * fp + j] * inv_l[j];
                bT[j * nb + i] = bv;
                s += bv * bv;
            }
            bsq[i] = -0.5f * s;
            for (int a = 0; a < M.A; ++a) wT[a * nb + i] = w[(int64_t)i * M.A + a];
        }
    }
};

// scratch of one thread, sized for the model
struct Work {
    std::vector<float> xa, mean, var, u, usum, feat, dR, dx, dxs, dpsi, wprior, gmean, gvar,
        gstate, G, gs, gin, gf, ga, gx, csum, delta;
    std::vector<int32_t> act;   // the active rows of r (active_row) of the output in hand
    std::vector<uint8_t> skip;  // blocks of B^T whose rows are all inactive kernel rows
    explicit Work(const Model &M)
        : xa((M.d + 2) * TILE), mean(M.m * TILE), var(M.m * TILE),
          u(M.A * TILE), usum(M.A), feat(M.fp),
          dR((int64_t)pad_rows(M.f + M.N) * TILE), dx(pad_rows(M.d + 1) * TILE),
          dxs(M.d * TILE), dpsi((M.f > 0 ? M.f : 1) * TILE), wprior(M.d * TILE),
          gmean(M.m * TILE), gvar(M.m * TILE), gstate(M.n * TILE), G((int64_t)TILE * M.nb),
          gs(M.A * TILE), gin(M.d * TILE), gf(M.fp * TILE), ga(M.fp), gx(M.n * TILE),
          csum(TILE), delta(M.m * TILE), act(M.N), skip(pad_rows(M.f + M.N) / RB) {}
};

// One particle's policy activations phi_i = exp(-1/2 |a - b_i|^2) D_i (i < nb) from
// a = x~ / l (fp entries, |a|^2 = asq), b = c / l transposed (fp, nb), -|b_i|^2 / 2 and the
// dropout bytes (D_i = 1[byte < keep_t] keep_scale); returns sum_i phi_i w0_i (the first
// action's weights, summed in the same pass).  FPT: fp as a compile-time constant
// (the loops over the features unrolled, their broadcasts kept in registers), 0: at run time.
template <int FPT>
float phi_row_t(int fp_rt, int nb, const float *a, float asq, const float *bT, const float *bsq,
                const uint8_t *by, float keep_t, float keep_scale, const float *w0, float *phi) {
    const int fp = FPT ? FPT : fp_rt;
    v8 av[FPT ? FPT : 1];
    if (FPT)
        for (int j = 0; j < FPT; ++j) av[j] = bc(a[j]);
    const v8 half_asq = bc(0.5f * asq), tv = bc(keep_t), sv = bc(keep_scale);
    v8 acc = bc(0.0f);
    auto finish = [&](int i0, v8 lp) {  // phi = exp(lp - |a|^2 / 2) D of basis i0 .. i0 + 7
        v8 ph = vexp_floor(lp - half_asq);
        v8 bf = __builtin_convertvector(*(const v8b *)(by + i0), v8);
        ph = ph * (bf < tv ? sv : bc(0.0f));
        st(phi + i0, ph);
        acc += ph * ld(w0 + i0);
    };
    int i = 0;
    // POLICY_CHAINS blocks of 8 basis functions at a time: as many independent sums over the
    // features, so that the multiply-adds do not wait on each other
    for (; i + 8 * POLICY_CHAINS <= nb; i += 8 * POLICY_CHAINS) {
        v8 lp[POLICY_CHAINS];
#pragma GCC unroll 4
        for (int u = 0; u < POLICY_CHAINS; ++u) lp[u] = ld(bsq + i + 8 * u);  // -|b_i|^2 / 2
        if (FPT) {
#pragma GCC unroll 32
            for (int j = 0; j < FPT; ++j)
#pragma GCC unroll 4
                for (int u = 0; u < POLICY_CHAINS; ++u)
                    lp[u] += av[j] * ld(bT + j * nb + i + 8 * u);
        } else {
            for (int j = 0; j < fp; ++j) {
                const v8 aj = bc(a[j]);
#pragma GCC unroll 4
                for (int u = 0; u < POLICY_CHAINS; ++u) lp[u] += aj * ld(bT + j * nb + i + 8 * u);
            }
        }
#pragma GCC unroll 4
        for (int u = 0; u < POLICY_CHAINS; ++u) finish(i + 8 * u, lp[u]);
    }
    for (; i + 8 <= nb; i += 8) {
        v8 lp = ld(bsq + i);  // -|b_i|^2 / 2
        if (FPT) {
#pragma GCC unroll 32
            for (int j = 0; j < FPT; ++j) lp += av[j] * ld(bT + j * nb + i);
        } else {
            for (int j = 0; j < fp; ++j) lp += bc(a[j]) * ld(bT + j * nb + i);
        }
        finish(i, lp);
    }
    float s = hsum(acc);
    for (; i < nb; ++i) {
        float lp = bsq[i];
        for (int j = 0; j < fp; ++j) lp += a[j] * bT[j * nb + i];
        lp -= 0.5f * asq;
        phi[i] = exp_floor(lp) * (((float)by[i] < keep_t) ? keep_scale : 0.0f);
        s += phi[i] * w0[i];
    }
    return s;
}

// One particle's G_i = (sum_a gs_a w_ia) phi_i = dJ/d log phi_i (i < nb, stored in G), its
// row sum (returned) and ga_j = sum_i G_i b_ji (j < fp), in one pass over i; w^T (A, nb),
// gs (A entries, stride TILE); FPT as in phi_row_t.
template <int FPT>
float g_row_t(int fp_rt, int A, int nb, const float *phi, const float *gs, const float *wT,
              const float *bT, float *G, float *ga) {
    const int fp = FPT ? FPT : fp_rt;
    constexpr int NACC = FPT ? FPT : 1;
    v8 acc[NACC];
    for (int j = 0; j < NACC; ++j) acc[j] = bc(0.0f);
    v8 rows = bc(0.0f);
    int i = 0;
    for (; i + 8 <= nb; i += 8) {
        v8 gw = bc(gs[0]) * ld(wT + i);
        for (int a = 1; a < A; ++a) gw += bc(gs[a * TILE]) * ld(wT + a * nb + i);
        const v8 Gi = gw * ld(phi + i);
        st(G + i, Gi);
        rows += Gi;
        if (FPT) {
#pragma GCC unroll 32
            for (int j = 0; j < NACC; ++j) acc[j] += Gi * ld(bT + j * nb + i);
        }
    }
    float rs = hsum(rows);
    const int vec_end = i;
    for (; i < nb; ++i) {
        float gw = 0.0f;
        for (int a = 0; a < A; ++a) gw += gs[a * TILE] * wT[a * nb + i];
        G[i] = gw * phi[i];
        rs += G[i];
    }
    for (int j = 0; j < fp; ++j) {
        const float *bj = bT + j * nb;
        float s = 0.0f;
        int k = 0;
        if (FPT) {
            s = hsum(acc[j < NACC ? j : 0]);
            k = vec_end;
        } else {
            v8 v[POLICY_CHAINS] = {};
            for (; k + 8 * POLICY_CHAINS <= nb; k += 8 * POLICY_CHAINS)
#pragma GCC unroll 4
                for (int u = 0; u < POLICY_CHAINS; ++u)
                    v[u] += ld(G + k + 8 * u) * ld(bj + k + 8 * u);
            for (; k + 8 <= nb; k += 8) v[0] += ld(G + k) * ld(bj + k);
            for (int u = 1; u < POLICY_CHAINS; ++u) v[0] += v[u];
            s = hsum(v[0]);
        }
        for (; k < nb; ++k) s += G[k] * bj[k];
        ga[j] = s;
    }
    return rs;
}

// The tile's sums over its 16 particles, added to the candidate's running sums:
// colsum(G) (nb), phi^T gs (A, nb) and G^T a (fp, nb), 8 columns at a time with the
// accumulators in registers; FPT as in phi_row_t.
template <int FPT>
void tile_sums_t(int fp_rt, int A, int nb, const float *Gb, const float *phi, const float *gs,
                 const float *a_rec, float *gcol, float *gw, float *gb) {
    const int fp = FPT ? FPT : fp_rt;
    int i = 0;
    for (; i + 8 <= nb; i += 8) {
        v8 sc = ld(gcol + i);
        if (FPT) {
            v8 sb[FPT ? FPT : 1];
            for (int j = 0; j < FPT; ++j) sb[j] = ld(gb + (int64_t)j * nb + i);
            for (int q = 0; q < TILE; ++q) {
                const v8 G = ld(Gb + (int64_t)q * nb + i);
                sc += G;
#pragma GCC unroll 32
                for (int j = 0; j < FPT; ++j) sb[j] += G * bc(a_rec[j * TILE + q]);
            }
            for (int j = 0; j < FPT; ++j) st(gb + (int64_t)j * nb + i, sb[j]);
        } else {  // each sum over the 16 particles in POLICY_CHAINS independent parts
            for (int q = 0; q < TILE; ++q) sc += ld(Gb + (int64_t)q * nb + i);
            for (int j = 0; j < fp; ++j) {
                v8 sb[POLICY_CHAINS] = {};
                for (int q = 0; q < TILE; q += POLICY_CHAINS)
#pragma GCC unroll 4
                    for (int u = 0; u < POLICY_CHAINS; ++u)
                        sb[u] += ld(Gb + (int64_t)(q + u) * nb + i) * bc(a_rec[j * TILE + q + u]);
                st(gb + (int64_t)j * nb + i,
                   ld(gb + (int64_t)j * nb + i) + ((sb[0] + sb[1]) + (sb[2] + sb[3])));
            }
        }
        st(gcol + i, sc);
        for (int a = 0; a < A; ++a) {
            v8 sw[POLICY_CHAINS] = {};
            for (int q = 0; q < TILE; q += POLICY_CHAINS)
#pragma GCC unroll 4
                for (int u = 0; u < POLICY_CHAINS; ++u)
                    sw[u] += ld(phi + (int64_t)(q + u) * nb + i) * bc(gs[a * TILE + q + u]);
            st(gw + (int64_t)a * nb + i,
               ld(gw + (int64_t)a * nb + i) + ((sw[0] + sw[1]) + (sw[2] + sw[3])));
        }
    }
    for (; i < nb; ++i) {
        for (int q = 0; q < TILE; ++q) {
            const float Gi = Gb[(int64_t)q * nb + i];
            gcol[i] += Gi;
            for (int a = 0; a < A; ++a)
                gw[(int64_t)a * nb + i] += phi[(int64_t)q * nb + i] * gs[a * TILE + q];
            for (int j = 0; j < fp; ++j) gb[(int64_t)j * nb + i] += Gi * a_rec[j * TILE + q];
        }
    }
}

typedef float (*PhiRow)(int, int, const float *, float, const float *, const float *,
                        const uint8_t *, float, float, const float *, float *);
typedef float (*GRow)(int, int, int, const float *, const float *, const float *,
                      const float *, float *, float *);
typedef void (*TileSums)(int, int, int, const float *, const float *, const float *,
                         const float *, float *, float *, float *);

constexpr int MAX_UNROLLED_FEATURES = 16;  // policy feature counts with their own unrolled code

template <int K>
struct Pick {  // the K-feature instantiation for fp = K, else the next K
    static PhiRow phi(int fp) { return fp == K ? phi_row_t<K> : Pick<K + 1>::phi(fp); }
    static GRow g(int fp) { return fp == K ? g_row_t<K> : Pick<K + 1>::g(fp); }
    static TileSums sums(int fp) { return fp == K ? tile_sums_t<K> : Pick<K + 1>::sums(fp); }
};
template <>
struct Pick<MAX_UNROLLED_FEATURES + 1> {
    static PhiRow phi(int) { return phi_row_t<0>; }
    static GRow g(int) { return g_row_t<0>; }
    static TileSums sums(int) { return tile_sums_t<0>; }
};

inline PhiRow pick_phi_row(int fp) { return Pick<1>::phi(fp); }
inline GRow pick_g_row(int fp) { return Pick<1>::g(fp); }
inline TileSums pick_tile_sums(int fp) { return Pick<1>::sums(fp); }

// u = u_mid + u_half tanh((D o phi) w / u_half) for the tile's particles (u: A x 16)
void policy_forward(const Model &M, const Lay &L, const Pol &P, const float *x, const float *nu,
                    const uint8_t *bytes, int valid, float keep_t, float keep_scale, float *rec,
                    Work &W) {
    const int nb = M.nb, fp = M.fp, np = M.n_plain;
    const PhiRow phi_row = pick_phi_row(fp);
    float *feat = W.feat.data();
    for (int q = 0; q < TILE; ++q) {
        for (int k = 0; k < np; ++k) {
            int j = M.plain_idx[k];
            feat[k] = x[j * TILE + q] + nu[j * TILE + q];
        }
        for (int k = 0; k < M.n_ang; ++k) {
            int j = M.angle_idx[k];
            float th = x[j * TILE + q] + nu[j * TILE + q];
            float s = std::sin(th), c = std::cos(th);
            feat[np + 2 * k] = s;
            feat[np + 2 * k + 1] = c;
            rec[L.so + k * TILE + q] = s;
            rec[L.co + k * TILE + q] = c;
        }
        float asq = 0.0f;
        for (int j = 0; j < fp; ++j) {
            float a = feat[j] * P.inv_l[j];
            feat[j] = a;
            asq += a * a;
            rec[L.a + j * TILE + q] = a;
        }
        float *phi = rec + L.phi + (int64_t)q * nb;
        const uint8_t *by = bytes + (int64_t)(q < valid ? q : 0) * nb;
        const float s0 = phi_row(fp, nb, feat, asq, P.bT.data(), P.bsq.data(), by, keep_t,
                                 keep_scale, P.wT.data(), phi);
        float *sums = W.usum.data();  // (D o phi) w of every action; the first's from phi_row
        sums[0] = s0;
        for (int a0 = 1; a0 < M.A; a0 += POLICY_CHAINS) {  // POLICY_CHAINS actions per pass
            const int na = M.A - a0 < POLICY_CHAINS ? M.A - a0 : POLICY_CHAINS;
            v8 acc[POLICY_CHAINS] = {};
            int i = 0;
            for (; i + 8 <= nb; i += 8) {
                const v8 ph = ld(phi + i);
                for (int u = 0; u < na; ++u) acc[u] += ph * ld(P.wT.data() + (int64_t)(a0 + u) * nb + i);
            }
            for (int u = 0; u < na; ++u) {
                const float *wa = P.wT.data() + (int64_t)(a0 + u) * nb;
                float s = hsum(acc[u]);
                for (int k = i; k < nb; ++k) s += phi[k] * wa[k];
                sums[a0 + u] = s;
            }
        }
        for (int a = 0; a < M.A; ++a) {
            const float s = sums[a];
            float t = std::tanh(s / M.u_half[a]);
            rec[L.t + a * TILE + q] = t;
            W.u[a * TILE + q] = M.u_mid[a] + M.u_half[a] * t;
        }
    }
}

// one tile's time step: x (n x 16, in/out), cost (16) out, record filled
// one tile's policy and GP inputs: u, x^ = [f(x), u] standardised and psi(z) to the record
void inputs_forward_tile(const Model &M, const Lay &L, const Pol &P, const float *x,
                         const float *nu, const uint8_t *bytes, int valid, float keep_t,
                         float keep_scale, float *rec, Work &W) {
    const int d = M.d, F = M.f, np = M.n_plain, fp = M.fp;
    policy_forward(M, L, P, x, nu, bytes, valid, keep_t, keep_scale, rec, W);
    // GP inputs [f(x), u], standardised
    float *xs = rec + L.xs;
    for (int q = 0; q < TILE; ++q) {
        for (int k = 0; k < np; ++k) {
            int j = M.plain_idx[k];
            xs[k * TILE + q] = (x[j * TILE + q] - M.x_mean[k]) / M.x_scale[k];
        }
        for (int k = 0; k < M.n_ang; ++k) {
            float th = x[M.angle_idx[k] * TILE + q];
            float s = std::sin(th), c = std::cos(th);
            rec[L.sn + k * TILE + q] = s;
            rec[L.cs + k * TILE + q] = c;
            int j = np + 2 * k;
            xs[j * TILE + q] = (s - M.x_mean[j]) / M.x_scale[j];
            xs[(j + 1) * TILE + q] = (c - M.x_mean[j + 1]) / M.x_scale[j + 1];
        }
        for (int a = 0; a < M.A; ++a) {
            int j = fp + a;
            xs[j * TILE + q] = (W.u[a * TILE + q] - M.x_mean[j]) / M.x_scale[j];
        }
    }
    // psi(z), z = [1, x^] (shared by the outputs)
    float *psi = rec + L.psi;
    if (M.p == 2) {
        for (int fi = 0; fi < F; ++fi) {
            int ia = M.idx_a[fi], ic = M.idx_c[fi];
            for (int h = 0; h < TILE; h += 8) {
                v8 za = ia == 0 ? bc(1.0f) : ld(xs + (ia - 1) * TILE + h);
                v8 zc = ic == 0 ? bc(1.0f) : ld(xs + (ic - 1) * TILE + h);
                st(psi + fi * TILE + h, za * zc);
            }
        }
    } else if (M.p == 1) {  // psi = z = [1, x^]
        for (int h = 0; h < TILE; h += 8) st(psi + h, bc(1.0f));
        std::memcpy(psi + TILE, xs, sizeof(float) * d * TILE);
    }
}

// one tile's GP posterior of output b: r = exp(E) and [V; mean] to the record, the mean and
// the variance of Delta_b to W
void gp_forward_tile(const Model &M, const Lay &L, int b, float *rec, Work &W,
                     StageClock &clock) {
    const int m = M.m, N = M.N, d = M.d, F = M.f;
    const float *xs = rec + L.xs, *psi = rec + L.psi;
    float *xa = W.xa.data();
    {
        float *r = rec + L.r + (int64_t)b * N * TILE;
        float *V = rec + L.V + (int64_t)b * L.vrows * TILE;  // then the mean row
        // x_aug = [x^; 1; -||x^/l_b||^2 / 2] -> E = W_aug x_aug, r = exp(E)
        for (int h = 0; h < TILE; h += 8) {
            v8 sq = bc(0.0f);
            for (int j = 0; j < d; ++j) {
                v8 v = ld(xs + j * TILE + h);
                st(xa + j * TILE + h, v);
                sq += bc(M.inv_l2[b * d + j]) * (v * v);
            }
            st(xa + d * TILE + h, bc(1.0f));
            st(xa + (d + 1) * TILE + h, sq * bc(-0.5f));
        }
        // (and the list of active rows, active_row); a row whose exponents are all below
        // EXP_FLOOR gets exp(EXP_FLOOR) without evaluating it (the same bits; not active)
        int32_t *act = W.act.data();
        int n_act = 0;
        const v8 at_floor = vexp(bc(EXP_FLOOR));
        gemm_tile(M.w_aug[b], xa, NO_SPLIT, xa,
                  [r, N, act, &n_act, at_floor](int first, const v8 *c0, const v8 *c1) {
                      const int rows = N - first < RB ? N - first : RB;  // padding rows dropped
                      for (int q = 0; q < rows; ++q) {
                          if (below_exp_floor(c0[q], c1[q])) {
                              st(r + (first + q) * TILE, at_floor);
                              st(r + (first + q) * TILE + 8, at_floor);
                              continue;
                          }
                          const v8 e0 = vexp_floor(c0[q]), e1 = vexp_floor(c1[q]);
                          st(r + (first + q) * TILE, e0);
                          st(r + (first + q) * TILE + 8, e1);
                          if (active_row(e0, e1)) act[n_act++] = first + q;
                      }
                  });
        clock.lap(STAGE_FWD_RBF);
        clock.rows[0] += n_act;
        clock.rows[1] += N;
        // [V; mean] = [B; alpha_aug] [psi; r] over the active rows of r, and ||V||^2 summed
        // over the rows in order
        const Cols cols = n_act < N ? Cols{act, n_act} : Cols{};
        v8 vv2[2] = {bc(0.0f), bc(0.0f)};
        gemm_tile(M.fwd[b], psi, F, r, [V, N, &vv2](int first, const v8 *c0, const v8 *c1) {
            float *c = V + (int64_t)first * TILE;
            const int rows = N - first < RB ? N - first : RB;
#pragma GCC unroll 8
            for (int q = 0; q < RB; ++q) {
                st(c + q * TILE, c0[q]);
                st(c + q * TILE + 8, c1[q]);
                if (q < rows) {
                    vv2[0] += c0[q] * c0[q];
                    vv2[1] += c1[q] * c1[q];
                }
            }
        }, cols);
        for (int h = 0; h < TILE; h += 8) {
            const v8 vv = vv2[h / 8];
            v8 prior = bc(M.outputscale[b]);
            if (M.p > 0) {
                v8 prod = bc(1.0f);
                for (int s = 0; s < M.p; ++s) {
                    v8 fac = bc(M.sig2[s * m + b]);
                    for (int j = 0; j < d; ++j) {
                        v8 v = ld(xs + j * TILE + h);
                        fac += bc(M.sig_diag[(s * m + b) * d + j]) * (v * v);
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
            v8 ys = bc(M.y_scale[b]);
            st(W.mean.data() + b * TILE + h, ld(V + N * TILE + h) * ys + bc(M.y_mean[b]));
            v8 vo = v * (ys * ys);
            if (M.noise_var) vo += bc(M.noise_var[b]);
            st(W.var.data() + b * TILE + h, vo);
        }
    }
    clock.lap(STAGE_FWD_TRI);
}

// one tile's sample, clip, integration and cost: x (n x 16, in/out), cost (16) out
void sample_forward_tile(const Model &M, const Lay &L, float *x, const float *eps, float *rec,
                         Work &W, float *cost) {
    const int m = M.m;
    // Delta = clip(mean + sqrt(max(var, floor)) eps), x+ = x A^T + Delta S^T, cost c(x+);
    // loops over the tile's 16 particles (the compiler vectorises them)
    float *delta = W.delta.data();
    for (int b = 0; b < m; ++b) {
        const float *mn = W.mean.data() + b * TILE, *vr = W.var.data() + b * TILE;
        const float *e = eps + b * TILE;
        float *dl = delta + b * TILE, *re = rec + L.eps + b * TILE, *rs = rec + L.sd + b * TILE;
        float *ro = rec + L.varon + b * TILE, *ri = rec + L.inside + b * TILE;
        for (int q = 0; q < TILE; ++q) {
            const float v = vr[q];
            const float sd = std::sqrt(v < VAR_FLOOR ? VAR_FLOOR : v);
            ro[q] = v >= VAR_FLOOR ? 1.0f : 0.0f;
            rs[q] = sd;
            re[q] = e[q];
            dl[q] = mn[q] + sd * e[q];
        }
        if (M.bound) {
            const float bd = M.bound[b];
            for (int q = 0; q < TILE; ++q) {
                const float v = dl[q];
                ri[q] = (v >= -bd && v <= bd) ? 1.0f : 0.0f;
                dl[q] = v < -bd ? -bd : (v > bd ? bd : v);  // NaN kept, as torch.clamp
            }
        } else {
            for (int q = 0; q < TILE; ++q) ri[q] = 1.0f;
        }
    }
    const float dt = M.dt, half_dt = 0.5f * dt;
    for (int k = 0; k < M.n_pairs; ++k) {
        float *xp = x + M.position_idx[k] * TILE, *xv = x + M.velocity_idx[k] * TILE;
        const float *dk = delta + k * TILE;
        for (int q = 0; q < TILE; ++q) {
            const float p0 = xp[q], v0 = xv[q];
            xp[q] = p0 + dt * v0 + half_dt * dk[q];
            xv[q] = v0 + dk[q];
        }
    }
    for (int k = 0; k < M.n_delta; ++k) {
        float *xo = x + M.delta_idx[k] * TILE;
        const float *dk = delta + (M.n_pairs + k) * TILE;
        for (int q = 0; q < TILE; ++q) xo[q] += dk[q];
    }
    // known oscillators: [r, rd]+ = [[a_pp, a_pv], [a_vp, a_vv]] [r, rd] + [z_p, z_v]
    for (int k = 0; k < M.n_osc; ++k) {
        float *xp = x + M.osc_idx[2 * k] * TILE, *xv = x + M.osc_idx[2 * k + 1] * TILE;
        const float *a = M.osc_coef + 6 * k;
        for (int q = 0; q < TILE; ++q) {
            const float p0 = xp[q], v0 = xv[q];
            xp[q] = a[0] * p0 + a[1] * v0 + a[4];
            xv[q] = a[2] * p0 + a[3] * v0 + a[5];
        }
    }
    // c = 1 - exp(-sum_j (d_j / l_j)^2), d_j of x_i (or x_i - x_r) by the term's mode (cost.py)
    float *sum = W.csum.data();
    for (int q = 0; q < TILE; ++q) sum[q] = 0.0f;
    float tracked[TILE];  // x_i - x_r of a term that tracks the state x_r
    for (int j = 0; j < M.n_terms; ++j) {
        const float *xv = x + M.cost_idx[j] * TILE;
        if (M.cost_ref[j] >= 0) {
            const float *xr = x + M.cost_ref[j] * TILE;
            for (int q = 0; q < TILE; ++q) tracked[q] = xv[q] - xr[q];
            xv = tracked;
        }
        const float tg = M.cost_target[j], ls = M.cost_ls[j];
        float *cd = rec + L.cd + j * TILE;  // d_j d'_j
        if (M.cost_mode[j] == 0) {
            for (int q = 0; q < TILE; ++q) {
                const float dj = xv[q] - tg, z = dj / ls;
                sum[q] += z * z;
                cd[q] = dj;
            }
        } else if (M.cost_mode[j] == 1) {  // torch.remainder(v - t + pi, 2 pi) - pi
            for (int q = 0; q < TILE; ++q) {
                float mod = std::fmod((xv[q] - tg) + PI_F, TWO_PI_F);
                if (mod != 0.0f && mod < 0.0f) mod += TWO_PI_F;
                const float dj = mod - PI_F, z = dj / ls;
                sum[q] += z * z;
                cd[q] = dj;
            }
        } else {  // |v| - |t|, slope sign(v)
            const float at = std::fabs(tg);
            for (int q = 0; q < TILE; ++q) {
                const float v = xv[q], dj = std::fabs(v) - at, z = dj / ls;
                const float slope = v > 0.0f ? 1.0f : (v < 0.0f ? -1.0f : 0.0f);
                sum[q] += z * z;
                cd[q] = dj * slope;
            }
        }
    }
    for (int h = 0; h < TILE; h += 8) {
        const v8 E = vexp_floor(-ld(sum + h));
        st(rec + L.cE + h, E);
        st(cost + h, bc(1.0f) - E);
    }
    // c_b = sigma((x - hi) / s) + sigma((lo - x) / s) per barrier; dc_b/dx to the record
    for (int k = 0; k < M.n_bar; ++k) {
        const float *xv = x + M.bar_idx[k] * TILE;
        const float lo = M.bar_lo[k], hi = M.bar_hi[k], iw = M.bar_inv_w[k];
        float *db = rec + L.cb + k * TILE;
        for (int q = 0; q < TILE; ++q) {
            const float a = 1.0f / (1.0f + std::exp(-(xv[q] - hi) * iw));
            const float b = 1.0f / (1.0f + std::exp(-(lo - xv[q]) * iw));
            cost[q] += a + b;
            db[q] = (a * (1.0f - a) - b * (1.0f - b)) * iw;
        }
    }
}

// The tile's running sums of the policy-parameter gradients of one candidate.
struct PolGrad {
    std::vector<float> gb, gcol, gw, gl;  // (Fp, nb) sum G a; (nb) colsum G; (A, nb); (Fp)
    explicit PolGrad(const Model &M) : gb(M.fp * M.nb), gcol(M.nb), gw(M.A * M.nb), gl(M.fp) {}
    void zero() {
        std::fill(gb.begin(), gb.end(), 0.0f);
        std::fill(gcol.begin(), gcol.end(), 0.0f);
        std::fill(gw.begin(), gw.end(), 0.0f);
        std::fill(gl.begin(), gl.end(), 0.0f);
    }
};

// one tile's backward through the cost, the integration and the sample: g (n x 16) in,
// dJ/dx_{t+1}; gc (16): dJ/dc_{t+1}; out: W.gstate (g A), W.gmean, W.gvar (dJ/d mean and
// variance of each output), the GP input gradients zeroed
void sample_backward_tile(const Model &M, const Lay &L, const float *rec, Work &W,
                          const float *g, const float *gc) {
    const int m = M.m, d = M.d;
    float *gstate = W.gstate.data(), *gmean = W.gmean.data(), *gvar = W.gvar.data();
    // cost: dc/dx_j = 2 E d_j d'_j / l_j^2; loops over the tile's 16 particles
    float *gx = W.gx.data(), *gE2 = W.csum.data();
    std::memcpy(gx, g, sizeof(float) * M.n * TILE);
    for (int q = 0; q < TILE; ++q) gE2[q] = 2.0f * gc[q] * rec[L.cE + q];
    for (int j = 0; j < M.n_terms; ++j) {
        float *gj = gx + M.cost_idx[j] * TILE;
        const float *cd = rec + L.cd + j * TILE;
        const float ls2 = M.cost_ls2[j];
        for (int q = 0; q < TILE; ++q) gj[q] += gE2[q] * cd[q] / ls2;
        if (M.cost_ref[j] >= 0) {  // the tracked state: the same with the opposite sign
            float *gr = gx + M.cost_ref[j] * TILE;
            for (int q = 0; q < TILE; ++q) gr[q] -= gE2[q] * cd[q] / ls2;
        }
    }
    for (int k = 0; k < M.n_bar; ++k) {  // barriers: dc_b/dx from the record
        float *gk = gx + M.bar_idx[k] * TILE;
        const float *db = rec + L.cb + k * TILE;
        for (int q = 0; q < TILE; ++q) gk[q] += gc[q] * db[q];
    }
    // integration: g_state = g A, g_Delta = (g S) 1[inside]
    std::memcpy(gstate, gx, sizeof(float) * M.n * TILE);
    const float dt = M.dt, half_dt = 0.5f * dt;
    for (int k = 0; k < M.n_pairs; ++k) {
        const float *gp = gx + M.position_idx[k] * TILE, *gv = gx + M.velocity_idx[k] * TILE;
        float *sv = gstate + M.velocity_idx[k] * TILE, *gm = gmean + k * TILE;
        for (int q = 0; q < TILE; ++q) {
            sv[q] += dt * gp[q];
            gm[q] = half_dt * gp[q] + gv[q];
        }
    }
    for (int k = 0; k < M.n_delta; ++k)
        std::memcpy(gmean + (M.n_pairs + k) * TILE, gx + M.delta_idx[k] * TILE,
                    sizeof(float) * TILE);
    for (int k = 0; k < M.n_osc; ++k) {  // g_state = g A on the oscillator's block
        const int ip = M.osc_idx[2 * k], iv = M.osc_idx[2 * k + 1];
        const float *gp = gx + ip * TILE, *gv = gx + iv * TILE, *a = M.osc_coef + 6 * k;
        float *sp = gstate + ip * TILE, *sv = gstate + iv * TILE;
        for (int q = 0; q < TILE; ++q) {
            sp[q] = a[0] * gp[q] + a[2] * gv[q];
            sv[q] = a[1] * gp[q] + a[3] * gv[q];
        }
    }
    for (int b = 0; b < m; ++b) {
        float *gm = gmean + b * TILE, *gv = gvar + b * TILE;
        const float *in = rec + L.inside + b * TILE, *e = rec + L.eps + b * TILE;
        const float *sd = rec + L.sd + b * TILE, *on = rec + L.varon + b * TILE;
        for (int q = 0; q < TILE; ++q) {
            const float gd = gm[q] * in[q];
            gm[q] = gd;
            gv[q] = gd * e[q] / (2.0f * sd[q]) * on[q];
        }
    }
    std::memset(W.dxs.data(), 0, sizeof(float) * d * TILE);
    std::memset(W.dpsi.data(), 0, sizeof(float) * W.dpsi.size());
    std::memset(W.wprior.data(), 0, sizeof(float) * d * TILE);
}

// one tile's backward through the GP posterior of output b: adds to W.dxs, W.dpsi, W.wprior
// (dJ/dx^ by the RBF part, dJ/dpsi, the prior's weight) from W.gmean, W.gvar
void gp_backward_tile(const Model &M, const Lay &L, int b, const float *rec, Work &W,
                      Prefetch &pf, StageClock &clock) {
    const int m = M.m, N = M.N, d = M.d, F = M.f;
    const float *gmean = W.gmean.data(), *gvar = W.gvar.data(), *xs = rec + L.xs;
    float *dxs = W.dxs.data(), *dpsi = W.dpsi.data(), *wprior = W.wprior.data();
    float *dR = W.dR.data(), *dx = W.dx.data();
    {
        const float *r = rec + L.r + (int64_t)b * N * TILE;
        const float *V = rec + L.V + (int64_t)b * L.vrows * TILE;
        v8 gms[2], m2gv[2];  // g_m and -2 g_v (standardised), particles 0-7 and 8-15
        for (int h = 0; h < TILE; h += 8) {
            v8 ys = bc(M.y_scale[b]);
            v8 gv = ld(gvar + b * TILE + h) * (ys * ys) * ld(rec + L.active + b * TILE + h);
            gms[h / 8] = ld(gmean + b * TILE + h) * ys;
            m2gv[h / 8] = bc(-2.0f) * gv;
            if (M.p > 0) {  // prior: d/dx^ prod_s fac_s = sum_s prod_{s' != s} fac_s' 2 Sigma_s x^
                for (int s = 0; s < M.p; ++s) {
                    v8 other =
                        M.p == 1 ? bc(1.0f) : ld(rec + L.fac + ((1 - s) * m + b) * TILE + h);
                    v8 wv = gv * other;
                    for (int j = 0; j < d; ++j) {
                        v8 acc = ld(wprior + j * TILE + h);
                        st(wprior + j * TILE + h, acc + wv * bc(M.sig_diag[(s * m + b) * d + j]));
                    }
                }
            }
        }
        // the forward's active rows of r (active_row on the same values); a block of B^T whose
        // rows are all inactive ones is skipped (their dE = dr o r is not used: W_t dE below
        // takes the active rows only)
        int32_t *act = W.act.data();
        int n_act = 0;
        uint8_t *skip = W.skip.data();
        const int nblk = (int)W.skip.size();
        std::fill(skip, skip + nblk, uint8_t(1));
        for (int bb = 0; bb < nblk && bb * RB < F; ++bb) skip[bb] = 0;  // rows of dpsi
        for (int j = 0; j < N; ++j)
            if (active_row(ld(r + j * TILE), ld(r + j * TILE + 8))) {
                act[n_act++] = j;
                skip[(F + j) / RB] = 0;
            }
        const Cols cols = n_act < N ? Cols{act, n_act} : Cols{};
        // dR = B^T dV + alpha_aug g_m with dV = -2 g_v V: (B^T V) (-2 g_v) + alpha_aug g_m,
        // row by row as the kernel hands them over: dpsi += dR (rows < F), dE = dr o r
        float *dE = dR + (int64_t)F * TILE;
        const float *al = M.alpha_aug + (int64_t)b * (F + N);
        gemm_tile(M.bwd[b], V, NO_SPLIT, V, [&](int first, const v8 *c0, const v8 *c1) {
            pf.next();
            const int rows = F + N - first < RB ? F + N - first : RB;
            for (int q = 0; q < rows; ++q) {
                const int j = first + q;
                const v8 a = bc(al[j]);
                const v8 v0 = c0[q] * m2gv[0] + a * gms[0], v1 = c1[q] * m2gv[1] + a * gms[1];
                if (j < F) {
                    st(dpsi + j * TILE, ld(dpsi + j * TILE) + v0);
                    st(dpsi + j * TILE + 8, ld(dpsi + j * TILE + 8) + v1);
                } else {
                    const float *rj = r + (int64_t)(j - F) * TILE;
                    st(dE + (j - F) * TILE, v0 * ld(rj));
                    st(dE + (j - F) * TILE + 8, v1 * ld(rj + 8));
                }
            }
        }, {}, n_act < N ? skip : nullptr);
        if (n_act < N)  // the skipped blocks' share of the next record's prefetch
            for (int bb = 0; bb < nblk; ++bb)
                if (skip[bb]) pf.next();
        clock.lap(STAGE_BWD_TRI);
        // [(X/l^2)^T dE; 1^T dE] = W_t dE
        gemm_tile_store(M.w_t[b], dE, 0, dE, dx, cols);
        for (int h = 0; h < TILE; h += 8) {
            v8 sumE = ld(dx + d * TILE + h);
            for (int j = 0; j < d; ++j) {
                v8 acc = ld(dxs + j * TILE + h) + ld(dx + j * TILE + h);
                acc -= ld(xs + j * TILE + h) * (sumE * bc(M.inv_l2[b * d + j]));
                st(dxs + j * TILE + h, acc);
            }
        }
    }
    clock.lap(STAGE_BWD_RBF);
}

// one tile's backward through the GP inputs and the policy: g (n x 16) out, dJ/dx_t, from
// W.gstate and the GP input gradients; the policy-parameter sums to PG
void inputs_backward_tile(const Model &M, const Lay &L, const Pol &P, const float *rec, Work &W,
                          float *g, PolGrad &PG) {
    const int d = M.d, F = M.f, np = M.n_plain, fp = M.fp, nb = M.nb;
    const float *xs = rec + L.xs, *dpsi = W.dpsi.data(), *wprior = W.wprior.data();
    const float *gstate = W.gstate.data();
    float *dxs = W.dxs.data();
    if (M.p == 2) {
        for (int fi = 0; fi < F; ++fi) {
            int ia = M.idx_a[fi], ic = M.idx_c[fi];
            for (int h = 0; h < TILE; h += 8) {
                v8 dp = ld(dpsi + fi * TILE + h);
                v8 za = ia == 0 ? bc(1.0f) : ld(xs + (ia - 1) * TILE + h);
                v8 zc = ic == 0 ? bc(1.0f) : ld(xs + (ic - 1) * TILE + h);
                if (ia > 0) st(dxs + (ia - 1) * TILE + h, ld(dxs + (ia - 1) * TILE + h) + dp * zc);
                if (ic > 0) st(dxs + (ic - 1) * TILE + h, ld(dxs + (ic - 1) * TILE + h) + dp * za);
            }
        }
    } else if (M.p == 1) {  // dpsi/dx^ of z = [1, x^]: the rows after the first
        for (int j = 0; j < d * TILE; ++j) dxs[j] += dpsi[TILE + j];
    }
    if (M.p > 0)
        for (int j = 0; j < d * TILE; ++j) dxs[j] += 2.0f * xs[j] * wprior[j];
    // GP inputs -> state and action (loops over the tile's particles); policy
    float *gin = W.gin.data(), *gf = W.gf.data(), *gs = W.gs.data(), *Gb = W.G.data();
    const GRow g_row = pick_g_row(fp);
    const TileSums tile_sums = pick_tile_sums(fp);
    const float *bT = P.bT.data(), *wT = P.wT.data(), *a_rec = rec + L.a;
    for (int j = 0; j < d; ++j) {
        const float sc = M.x_scale[j];
        for (int q = 0; q < TILE; ++q) gin[j * TILE + q] = dxs[j * TILE + q] / sc;
    }
    std::memcpy(g, gstate, sizeof(float) * M.n * TILE);
    for (int k = 0; k < np; ++k) {
        float *gk = g + M.plain_idx[k] * TILE;
        for (int q = 0; q < TILE; ++q) gk[q] += gin[k * TILE + q];
    }
    for (int k = 0; k < M.n_ang; ++k) {
        float *gk = g + M.angle_idx[k] * TILE;
        const float *gsn = gin + (np + 2 * k) * TILE, *gcs = gsn + TILE;
        const float *sn = rec + L.sn + k * TILE, *cs = rec + L.cs + k * TILE;
        for (int q = 0; q < TILE; ++q) gk[q] += gsn[q] * cs[q] - gcs[q] * sn[q];
    }
    // policy: gs = g_u (1 - t^2), G = (gs w^T) o phi = dJ/d log phi
    for (int a = 0; a < M.A; ++a) {
        const float *t = rec + L.t + a * TILE, *gu = gin + (fp + a) * TILE;
        for (int q = 0; q < TILE; ++q) gs[a * TILE + q] = gu[q] * (1.0f - t[q] * t[q]);
    }
    for (int q = 0; q < TILE; ++q) {
        const float *phi = rec + L.phi + (int64_t)q * nb;
        // dJ/da = G b - a rowsum(G); dJ/dfeat = dJ/da / l
        const float rs = g_row(fp, M.A, nb, phi, gs + q, wT, bT, Gb + (int64_t)q * nb,
                               W.ga.data());
        for (int j = 0; j < fp; ++j) {
            float aj = a_rec[j * TILE + q];
            float g_a = W.ga[j] - aj * rs;
            PG.gl[j] += g_a * aj;
            gf[j * TILE + q] = g_a * P.inv_l[j];
        }
    }
    // the policy input's features -> state
    for (int k = 0; k < np; ++k) {
        float *gk = g + M.plain_idx[k] * TILE;
        for (int q = 0; q < TILE; ++q) gk[q] += gf[k * TILE + q];
    }
    for (int k = 0; k < M.n_ang; ++k) {
        float *gk = g + M.angle_idx[k] * TILE;
        const float *gsn = gf + (np + 2 * k) * TILE, *gcs = gsn + TILE;
        const float *so = rec + L.so + k * TILE, *co = rec + L.co + k * TILE;
        for (int q = 0; q < TILE; ++q) gk[q] += gsn[q] * co[q] - gcs[q] * so[q];
    }
    // the tile's sums over its particles: colsum(G), phi^T gs and G^T a
    tile_sums(fp, M.A, nb, Gb, rec + L.phi, gs, a_rec, PG.gcol.data(), PG.gw.data(),
              PG.gb.data());
}

}  // namespace

int64_t record_floats(const Model &M) { return Lay(M).size; }

int vector_floats() { return MCP_WIDE ? 16 : 8; }

int64_t l2_cache_bytes() {
#if defined(_SC_LEVEL2_CACHE_SIZE)
    const long sc = sysconf(_SC_LEVEL2_CACHE_SIZE);
    if (sc > 0) return sc;
#endif
    for (int index = 0; index < 8; ++index) {  // Linux: the cache levels of CPU 0
        const std::string dir = "/sys/devices/system/cpu/cpu0/cache/index" + std::to_string(index);
        std::ifstream level(dir + "/level"), type(dir + "/type"), size(dir + "/size");
        int lv = 0;
        std::string ty, sz;
        if (!(level >> lv) || !(type >> ty) || !(size >> sz)) continue;
        if (lv != 2 || ty == "Instruction") continue;
        const int64_t value = std::atoll(sz.c_str());
        const char unit = sz.empty() ? ' ' : sz.back();
        return unit == 'K' ? value << 10 : unit == 'M' ? value << 20 : value;
    }
    return 0;
}

int default_group(const Model &M, int64_t l2_bytes) {
    if (l2_bytes <= 0) l2_bytes = FALLBACK_L2_BYTES;
    const int64_t F = M.p > 0 ? M.f : 0, N = M.N;
    auto floats = [](const Packed &P) { return P.off[P.blocks - 1] + (int64_t)RB * (P.end[P.blocks - 1] - P.beg[P.blocks - 1]); };
    int64_t consts = 0;  // the larger of one output's forward and backward constant matrices
    for (int b = 0; b < M.m; ++b) {
        const int64_t f = floats(M.w_aug[b]) + floats(M.fwd[b]);
        const int64_t g = floats(M.bwd[b]) + floats(M.w_t[b]);
        consts = std::max(consts, std::max(f, g));
    }
    // one tile's data of one output: r, [V; mean], dR = [dpsi; dE], psi and x_aug
    const int64_t tile = (int64_t)TILE * (N + pad_rows(N + 1) + pad_rows(F + N) + F + M.d + 2);
    const int64_t room = l2_bytes / 2 / (int64_t)sizeof(float) - consts;
    const int64_t group = room > 0 ? room / tile : 1;
    return (int)std::max<int64_t>(1, std::min<int64_t>(MAX_GROUP, group));
}

void stage_seconds(double *out, bool reset) {
    for (int i = 0; i < NUM_STAGES; ++i)
        out[i] = 1e-9 * (double)(reset ? STAGE_NS[i].exchange(0) : STAGE_NS[i].load());
}

void kernel_rows(int64_t *out, bool reset) {
    for (int i = 0; i < 2; ++i) out[i] = reset ? KERNEL_ROWS[i].exchange(0) : KERNEL_ROWS[i].load();
}

void forward(const Model &M, int horizon, int K, int per, const float *x0, const float *eps,
             const float *nu, const uint8_t *const *bytes, float keep_t, float keep_scale,
             const float *centers, const float *log_l, const float *w, float *costs, float *rec) {
    const FlushDenormals ftz;
    const int n = M.n, m = M.m, nb = M.nb, rows = K * per, tiles_per = (per + TILE - 1) / TILE;
    const int G = M.group < tiles_per ? M.group : tiles_per;
    const Lay L(M);
    std::vector<Work> W(G, Work(M));
    Pol P(M);
    std::vector<float> x((int64_t)G * n * TILE), e(m * TILE), v(n * TILE);
    std::vector<float *> rc(G);
    float cost[TILE];
    StageClock clock;
    for (int k = 0; k < K; ++k) {
        P.load(M, centers + (int64_t)k * nb * M.fp, log_l + (int64_t)k * M.fp,
               w + (int64_t)k * nb * M.A);
        // a group of G tiles runs each time step together, output by output, so that one
        // output's constant matrices serve G tiles while they are in the core's caches
        for (int tile0 = 0; tile0 < tiles_per; tile0 += G) {
            const int g_n = tiles_per - tile0 < G ? tiles_per - tile0 : G;
            std::fill(x.begin(), x.end(), 0.0f);
            for (int g = 0; g < g_n; ++g) {
                const int first = k * per + (tile0 + g) * TILE;
                const int valid = per - (tile0 + g) * TILE < TILE ? per - (tile0 + g) * TILE : TILE;
                float *xg = x.data() + (int64_t)g * n * TILE;
                for (int q = 0; q < valid; ++q)
                    for (int j = 0; j < n; ++j) xg[j * TILE + q] = x0[(int64_t)(first + q) * n + j];
            }
            for (int t = 0; t < horizon; ++t) {
                for (int g = 0; g < g_n; ++g) {
                    const int tile = tile0 + g, first = k * per + tile * TILE;
                    const int valid = per - tile * TILE < TILE ? per - tile * TILE : TILE;
                    std::fill(v.begin(), v.end(), 0.0f);
                    for (int q = 0; q < valid; ++q) {
                        const int64_t r = (int64_t)t * rows + first + q;
                        for (int j = 0; j < n; ++j) v[j * TILE + q] = nu[r * n + j];
                    }
                    rc[g] = rec + ((int64_t)t * K * tiles_per + (int64_t)k * tiles_per + tile) * L.size;
                    inputs_forward_tile(M, L, P, x.data() + (int64_t)g * n * TILE, v.data(),
                                        bytes[t] + (int64_t)first * nb, valid, keep_t,
                                        keep_scale, rc[g], W[g]);
                }
                clock.lap(STAGE_FWD_INPUTS);
                for (int b = 0; b < m; ++b)
                    for (int g = 0; g < g_n; ++g) gp_forward_tile(M, L, b, rc[g], W[g], clock);
                for (int g = 0; g < g_n; ++g) {
                    const int tile = tile0 + g, first = k * per + tile * TILE;
                    const int valid = per - tile * TILE < TILE ? per - tile * TILE : TILE;
                    std::fill(e.begin(), e.end(), 0.0f);
                    for (int q = 0; q < valid; ++q) {
                        const int64_t r = (int64_t)t * rows + first + q;
                        for (int j = 0; j < m; ++j) e[j * TILE + q] = eps[r * m + j];
                    }
                    sample_forward_tile(M, L, x.data() + (int64_t)g * n * TILE, e.data(), rc[g],
                                        W[g], cost);
                    for (int q = 0; q < valid; ++q) costs[(int64_t)t * rows + first + q] = cost[q];
                }
                clock.lap(STAGE_FWD_SAMPLE);
            }
        }
    }
}

void backward(const Model &M, int horizon, int K, int per, const float *rec,
              const float *centers, const float *log_l, const float *w, const float *g_costs,
              float *g_centers, float *g_log_l, float *g_w) {
    const FlushDenormals ftz;
    const int n = M.n, m = M.m, nb = M.nb, fp = M.fp, rows = K * per,
              tiles_per = (per + TILE - 1) / TILE;
    const int G = M.group < tiles_per ? M.group : tiles_per;
    const Lay L(M);
    std::vector<Work> W(G, Work(M));
    Pol P(M);
    PolGrad PG(M);
    std::vector<float> g((int64_t)G * n * TILE);
    std::vector<const float *> rc(G), prev(G);
    float gc[TILE];
    Prefetch pf;
    StageClock clock;
    const int64_t stride = (int64_t)K * tiles_per;
    for (int k = 0; k < K; ++k) {
        P.load(M, centers + (int64_t)k * nb * fp, log_l + (int64_t)k * fp,
               w + (int64_t)k * nb * M.A);
        PG.zero();
        for (int tile0 = 0; tile0 < tiles_per; tile0 += G) {
            const int g_n = tiles_per - tile0 < G ? tiles_per - tile0 : G;
            std::fill(g.begin(), g.end(), 0.0f);
            rc.resize(g_n);
            prev.resize(g_n);
            for (int t = horizon - 1; t >= 0; --t) {
                for (int q = 0; q < g_n; ++q) {
                    const int tile = tile0 + q, first = k * per + tile * TILE;
                    const int valid = per - tile * TILE < TILE ? per - tile * TILE : TILE;
                    for (int j = 0; j < TILE; ++j)
                        gc[j] = j < valid ? g_costs[(int64_t)t * rows + first + j] : 0.0f;
                    const int64_t at = (int64_t)k * tiles_per + tile;
                    rc[q] = rec + (t * stride + at) * L.size;
                    prev[q] = t > 0 ? rec + ((t - 1) * stride + at) * L.size : nullptr;
                    sample_backward_tile(M, L, rc[q], W[q], g.data() + (int64_t)q * n * TILE, gc);
                }
                pf.start(prev, L.size);
                clock.lap(STAGE_BWD_SAMPLE);
                for (int b = 0; b < m; ++b)
                    for (int q = 0; q < g_n; ++q) gp_backward_tile(M, L, b, rc[q], W[q], pf, clock);
                for (int q = 0; q < g_n; ++q)
                    inputs_backward_tile(M, L, P, rc[q], W[q], g.data() + (int64_t)q * n * TILE, PG);
                clock.lap(STAGE_BWD_INPUTS);
            }
        }
        // g_b = G^T a - b o colsum(G); g_c = g_b / l; g_log_l = -(sum g_a o a + sum g_b o b)
        for (int j = 0; j < fp; ++j) {
            float sb = 0.0f;
            for (int i = 0; i < nb; ++i) {
                float bv = P.bT[j * nb + i];
                float g_b = PG.gb[j * nb + i] - bv * PG.gcol[i];
                sb += g_b * bv;
                g_centers[((int64_t)k * nb + i) * fp + j] += g_b * P.inv_l[j];
            }
            g_log_l[(int64_t)k * fp + j] += -(PG.gl[j] + sb);
        }
        for (int i = 0; i < nb; ++i)
            for (int a = 0; a < M.A; ++a)
                g_w[((int64_t)k * nb + i) * M.A + a] += PG.gw[a * nb + i];
    }
}

}  // namespace mcp
