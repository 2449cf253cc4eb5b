// Python binding of the native rollout (native_rollout.cpp), built by
// torch.utils.cpp_extension: a NativeModel holds the tensors of one loss's task, GP and cost
// (float32, int32 and int64 CPU tensors, checked here) and runs one shard's forward or
// backward loop on tensors given by Python, without the GIL.

#include <torch/extension.h>

#include <string>
#include <vector>

#include "native_rollout.h"

namespace {

using torch::Tensor;

// a contiguous CPU tensor of `dtype` with `numel` entries (-1: any), else a clear error
const Tensor &checked(const Tensor &t, torch::ScalarType dtype, int64_t numel, const char *name) {
    TORCH_CHECK(t.device().is_cpu(), name, " must be on the CPU");
    TORCH_CHECK(t.scalar_type() == dtype, name, " must be ", c10::toString(dtype), ", got ",
                c10::toString(t.scalar_type()));
    TORCH_CHECK(t.is_contiguous(), name, " must be contiguous");
    TORCH_CHECK(numel < 0 || t.numel() == numel, name, " must have ", numel, " entries, got ",
                t.numel());
    return t;
}

class NativeModel {
  public:
    // ints: n, A, m, d, fp, nb, N, p, f; index: plain, angle, position, velocity, delta,
    // cost_idx, cost_mode, idx_a, idx_c, cost_ref, bar_idx, osc_idx (int32); floats: u_mid,
    // u_half, cost_target, cost_ls, cost_ls2, x_mean, x_scale, y_mean, y_scale, inv_l2,
    // outputscale, sig_diag, sig2, noise_var, bound (empty: none), alpha_aug, bar_lo, bar_hi,
    // bar_inv_w, osc_coef;
    // packed: per output (w_aug, fwd, bwd, w_t) as 4 tensors each (values, beg, end, off).
    NativeModel(std::vector<int64_t> ints, std::vector<Tensor> index, std::vector<Tensor> floats,
                double dt, std::vector<std::vector<Tensor>> packed)
        : index_(std::move(index)), floats_(std::move(floats)) {
        TORCH_CHECK(ints.size() == 9 && index_.size() == 12 && floats_.size() == 20,
                    "NativeModel: wrong argument counts");
        mcp::Model &M = model_;
        M.n = (int)ints[0];
        M.A = (int)ints[1];
        M.m = (int)ints[2];
        M.d = (int)ints[3];
        M.fp = (int)ints[4];
        M.nb = (int)ints[5];
        M.N = (int)ints[6];
        M.p = (int)ints[7];
        M.f = (int)ints[8];
        TORCH_CHECK(M.d == M.fp + M.A, "GP inputs must be the features and the actions");
        TORCH_CHECK(M.p >= 0 && M.p <= 2, "MPK degree must be 0, 1 or 2");
        TORCH_CHECK(M.p != 1 || M.f == M.d + 1, "degree-1 MPK: F must be d + 1");
        auto idx = [&](int i, const char *name) {
            return checked(index_[i], torch::kInt32, -1, name).data_ptr<int32_t>();
        };
        M.n_plain = (int)index_[0].numel();
        M.n_ang = (int)index_[1].numel();
        M.n_pairs = (int)index_[2].numel();
        M.n_delta = (int)index_[4].numel();
        M.n_terms = (int)index_[5].numel();
        TORCH_CHECK(M.n_plain + M.n_ang == M.n && M.n_plain + 2 * M.n_ang == M.fp,
                    "plain and angle coordinates must split the state");
        TORCH_CHECK(M.n_pairs + M.n_delta == M.m && (int)index_[3].numel() == M.n_pairs,
                    "the GP outputs must be the pairs' velocities and the unpaired coordinates");
        M.plain_idx = idx(0, "plain_idx");
        M.angle_idx = idx(1, "angle_idx");
        M.position_idx = idx(2, "position_idx");
        M.velocity_idx = idx(3, "velocity_idx");
        M.delta_idx = idx(4, "delta_idx");
        M.cost_idx = idx(5, "cost_idx");
        TORCH_CHECK(index_[6].numel() == M.n_terms, "cost_mode needs one entry per term");
        M.cost_mode = idx(6, "cost_mode");
        TORCH_CHECK(index_[9].numel() == M.n_terms, "cost_ref needs one entry per term");
        M.cost_ref = idx(9, "cost_ref");
        for (int j = 0; j < M.n_terms; ++j)
            TORCH_CHECK(M.cost_ref[j] >= -1 && M.cost_ref[j] < M.n && M.cost_idx[j] >= 0 &&
                            M.cost_idx[j] < M.n,
                        "cost term ", j, ": state index out of range");
        const int F = M.p > 0 ? M.f : 0;  // MPK features (rows of B before L^-1's)
        const int F_pairs = M.p == 2 ? F : 0;  // monomial index pairs: degree 2 only
        TORCH_CHECK(index_[7].numel() >= F_pairs && index_[8].numel() >= F_pairs,
                    "idx_a, idx_c too short");
        M.idx_a = idx(7, "idx_a");
        M.idx_c = idx(8, "idx_c");
        auto flt = [&](int i, int64_t numel, const char *name) -> const float * {
            if (numel == 0 && floats_[i].numel() == 0) return nullptr;
            return checked(floats_[i], torch::kFloat32, numel, name).data_ptr<float>();
        };
        const int m = M.m, d = M.d;
        M.u_mid = flt(0, M.A, "u_mid");
        M.u_half = flt(1, M.A, "u_half");
        M.cost_target = flt(2, M.n_terms, "cost_target");
        M.cost_ls = flt(3, M.n_terms, "cost_ls");
        M.cost_ls2 = flt(4, M.n_terms, "cost_ls2");
        M.x_mean = flt(5, d, "x_mean");
        M.x_scale = flt(6, d, "x_scale");
        M.y_mean = flt(7, m, "y_mean");
        M.y_scale = flt(8, m, "y_scale");
        M.inv_l2 = flt(9, (int64_t)m * d, "inv_l2");
        M.outputscale = flt(10, m, "outputscale");
        M.sig_diag = M.p ? flt(11, (int64_t)M.p * m * d, "sig_diag") : nullptr;
        M.sig2 = M.p ? flt(12, (int64_t)M.p * m, "sig2") : nullptr;
        M.noise_var = floats_[13].numel() ? flt(13, m, "noise_var") : nullptr;
        M.bound = floats_[14].numel() ? flt(14, m, "bound") : nullptr;
        M.alpha_aug = flt(15, (int64_t)m * (F + M.N), "alpha_aug");
        M.n_bar = (int)index_[10].numel();
        M.bar_idx = idx(10, "bar_idx");
        for (int k = 0; k < M.n_bar; ++k)
            TORCH_CHECK(M.bar_idx[k] >= 0 && M.bar_idx[k] < M.n, "barrier ", k,
                        ": state index out of range");
        M.bar_lo = M.n_bar ? flt(16, M.n_bar, "bar_lo") : nullptr;
        M.bar_hi = M.n_bar ? flt(17, M.n_bar, "bar_hi") : nullptr;
        M.bar_inv_w = M.n_bar ? flt(18, M.n_bar, "bar_inv_w") : nullptr;
        TORCH_CHECK(index_[11].numel() % 2 == 0, "osc_idx needs (position, velocity) pairs");
        M.n_osc = (int)index_[11].numel() / 2;
        M.osc_idx = idx(11, "osc_idx");
        for (int k = 0; k < 2 * M.n_osc; ++k)
            TORCH_CHECK(M.osc_idx[k] >= 0 && M.osc_idx[k] < M.n, "oscillator ", k / 2,
                        ": state index out of range");
        M.osc_coef = M.n_osc ? flt(19, 6 * M.n_osc, "osc_coef") : nullptr;
        M.dt = (float)dt;
        TORCH_CHECK((int)packed.size() == 4, "packed needs w_aug, fwd, bwd, w_t");
        for (auto &kind : packed) {
            TORCH_CHECK((int)kind.size() == 4 * m, "packed needs 4 tensors per output");
            for (auto &t : kind) packed_tensors_.push_back(t);
        }
        const int nblk = (M.N + mcp::RB - 1) / mcp::RB;
        const int want[4] = {nblk, (M.N + 1 + mcp::RB - 1) / mcp::RB,
                             (F + M.N + mcp::RB - 1) / mcp::RB, (d + 1 + mcp::RB - 1) / mcp::RB};
        for (int kind = 0; kind < 4; ++kind) {
            for (int b = 0; b < m; ++b) {
                const Tensor *t = &packed[kind][4 * b];
                mcp::Packed P;
                P.a = checked(t[0], torch::kFloat32, -1, "packed values").data_ptr<float>();
                P.blocks = (int)t[1].numel();
                TORCH_CHECK(P.blocks == want[kind] && t[2].numel() == P.blocks &&
                                t[3].numel() == P.blocks,
                            "packed matrix ", kind, " has ", P.blocks, " blocks, expected ",
                            want[kind]);
                P.beg = checked(t[1], torch::kInt32, -1, "packed beg").data_ptr<int32_t>();
                P.end = checked(t[2], torch::kInt32, -1, "packed end").data_ptr<int32_t>();
                P.off = checked(t[3], torch::kInt64, -1, "packed off").data_ptr<int64_t>();
                packs_[kind].push_back(P);
            }
        }
        M.w_aug = packs_[0].data();
        M.fwd = packs_[1].data();
        M.bwd = packs_[2].data();
        M.w_t = packs_[3].data();
        M.group = mcp::default_group(M, mcp::l2_cache_bytes());
    }

    int group() const { return model_.group; }

    // tiles per group (cache blocking); the default is default_group's for this CPU
    void set_group(int64_t group) {
        TORCH_CHECK(group >= 1, "group must be >= 1, got ", group);
        model_.group = (int)group;
    }

    int64_t record_floats() const { return mcp::record_floats(model_); }

    // one shard's forward loop (native_rollout.h); K candidates of `per` particles each
    void forward(int64_t K, int64_t per, const Tensor &x0, const Tensor &eps, const Tensor &nu,
                 const std::vector<Tensor> &bytes, double keep_t, double keep_scale,
                 const Tensor &centers, const Tensor &log_l, const Tensor &w, Tensor costs,
                 Tensor rec) const {
        const mcp::Model &M = model_;
        const int64_t rows = K * per, H = (int64_t)bytes.size();
        checked(x0, torch::kFloat32, rows * M.n, "x0");
        checked(eps, torch::kFloat32, H * rows * M.m, "eps");
        checked(nu, torch::kFloat32, H * rows * M.n, "nu");
        check_theta(K, centers, log_l, w);
        checked(costs, torch::kFloat32, H * rows, "costs");
        const int64_t tiles = K * ((per + mcp::TILE - 1) / mcp::TILE);
        checked(rec, torch::kFloat32, H * tiles * record_floats(), "rec");
        std::vector<const uint8_t *> ptrs;
        for (const Tensor &b : bytes)
            ptrs.push_back(checked(b, torch::kUInt8, rows * M.nb, "bytes").data_ptr<uint8_t>());
        const float *px0 = x0.data_ptr<float>(), *peps = eps.data_ptr<float>(),
                    *pnu = nu.data_ptr<float>(), *pc = centers.data_ptr<float>(),
                    *pl = log_l.data_ptr<float>(), *pw = w.data_ptr<float>();
        float *pcost = costs.data_ptr<float>(), *prec = rec.data_ptr<float>();
        pybind11::gil_scoped_release unlocked;
        mcp::forward(M, (int)H, (int)K, (int)per, px0, peps, pnu, ptrs.data(), (float)keep_t,
                     (float)keep_scale, pc, pl, pw, pcost, prec);
    }

    // one shard's backward loop: adds dJ/dtheta to g_centers, g_log_l, g_w
    void backward(int64_t K, int64_t per, int64_t horizon, const Tensor &rec,
                  const Tensor &centers, const Tensor &log_l, const Tensor &w,
                  const Tensor &g_costs, Tensor g_centers, Tensor g_log_l, Tensor g_w) const {
        const mcp::Model &M = model_;
        const int64_t rows = K * per;
        const int64_t tiles = K * ((per + mcp::TILE - 1) / mcp::TILE);
        checked(rec, torch::kFloat32, horizon * tiles * record_floats(), "rec");
        check_theta(K, centers, log_l, w);
        check_theta(K, g_centers, g_log_l, g_w);
        checked(g_costs, torch::kFloat32, horizon * rows, "g_costs");
        const float *prec = rec.data_ptr<float>(), *pc = centers.data_ptr<float>(),
                    *pl = log_l.data_ptr<float>(), *pw = w.data_ptr<float>(),
                    *pg = g_costs.data_ptr<float>();
        float *gc = g_centers.data_ptr<float>(), *gl = g_log_l.data_ptr<float>(),
              *gw = g_w.data_ptr<float>();
        pybind11::gil_scoped_release unlocked;
        mcp::backward(M, (int)horizon, (int)K, (int)per, prec, pc, pl, pw, pg, gc, gl, gw);
    }

  private:
    void check_theta(int64_t K, const Tensor &c, const Tensor &l, const Tensor &w) const {
        const mcp::Model &M = model_;
        checked(c, torch::kFloat32, K * M.nb * M.fp, "centers");
        checked(l, torch::kFloat32, K * M.fp, "log_lengthscales");
        checked(w, torch::kFloat32, K * M.nb * M.A, "weights");
    }

    std::vector<Tensor> index_, floats_, packed_tensors_;  // kept alive: the model points in
    std::vector<mcp::Packed> packs_[4];
    mcp::Model model_{};
};

}  // namespace

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
    m.doc() = "MC-PILCO particle rollout, forward and backward through time, for one shard";
    m.def("tile", [] { return mcp::TILE; }, "particles per tile");
    m.def("row_block", [] { return mcp::RB; }, "rows per block of a packed matrix");
    m.def("vector_floats", &mcp::vector_floats, "floats per vector of the products' accumulators");
    m.def("l2_cache_bytes", &mcp::l2_cache_bytes, "this CPU's per-core L2 cache in bytes (0: unknown)");
    m.def(
        "stage_seconds",
        [](bool reset) {
            std::vector<double> out(mcp::NUM_STAGES);
            mcp::stage_seconds(out.data(), reset);
            return out;
        },
        pybind11::arg("reset") = false,
        "seconds spent in each stage of the loops (summed over threads) since the last reset");
    m.def(
        "kernel_rows",
        [](bool reset) {
            int64_t out[2];
            mcp::kernel_rows(out, reset);
            return std::vector<int64_t>(out, out + 2);
        },
        pybind11::arg("reset") = false,
        "RBF kernel rows the forward loops took into the products since the last reset, and all");
    pybind11::class_<NativeModel>(m, "NativeModel")
        .def(pybind11::init<std::vector<int64_t>, std::vector<Tensor>, std::vector<Tensor>,
                            double, std::vector<std::vector<Tensor>>>())
        .def("record_floats", &NativeModel::record_floats)
        .def("group", &NativeModel::group)
        .def("set_group", &NativeModel::set_group)
        .def("forward", &NativeModel::forward)
        .def("backward", &NativeModel::backward);
}
