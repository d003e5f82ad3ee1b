// Rigid body motion of Gaussians (recon/dtg/motion.py apply_motion) and its VJP, each one pass over
// the rows. In torch the same motion is a gather, two batched 3x3 / 4x4 products, two lerps and a
// scatter, whose autograd graph cost ~4 ms forward + backward per call at 12k Gaussians (2.5k on
// bodies), three calls per dtg iteration; here it is a few tens of microseconds.
//
// Per body b (packed by motion.body_transforms, row-major): R (3x3) | c (3) | L (4x4). A Gaussian
// of body b (basis = b + 1; 0 = static) with gate g moves its mean mu to mu + g (R mu + c - mu) and
// its rotation q to q + g (L q - q). Float and double builds (double for gradcheck).
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <optional>
#include <stdexcept>
#include <string>

namespace py = pybind11;

namespace {

constexpr int kPacked = 28;

template <typename T>
using Arr = py::array_t<T, py::array::c_style | py::array::forcecast>;

template <typename T>
void check(const Arr<T>& a, const char* name, int64_t rows, int64_t cols) {
  const bool ok = a.ndim() == (cols < 0 ? 1 : 2) && a.shape(0) == rows && (cols < 0 || a.shape(1) == cols);
  if (!ok) {
    std::string seen = "(";
    for (py::ssize_t j = 0; j < a.ndim(); ++j) seen += (j ? "," : "") + std::to_string(a.shape(j));
    throw py::value_error(std::string("native motion: bad shape for ") + name + ": " + seen + ")");
  }
}

// The shared checks; -> (N, B, has quats).
template <typename T>
std::tuple<int64_t, int64_t, bool> check_inputs(const Arr<T>& means, const Arr<T>& quats, const Arr<T>& basis,
                                                const Arr<T>& gate, const Arr<T>& transforms) {
  const int64_t n = means.ndim() == 2 ? means.shape(0) : -1;
  check(means, "means", n, 3);
  const bool has_quats = quats.ndim() == 2 && quats.shape(0) != 0;
  if (has_quats) check(quats, "quats", n, 4);
  check(basis, "basis", n, -1);
  check(gate, "gate", n, -1);
  const int64_t nb = transforms.ndim() == 2 ? transforms.shape(0) : -1;
  check(transforms, "transforms", nb, kPacked);
  const T* bs = basis.data();
  for (int64_t i = 0; i < n; ++i)
    if (!(bs[i] >= 0) || bs[i] > (T)nb || bs[i] != (T)(int64_t)bs[i])
      throw py::value_error("native motion: basis[" + std::to_string(i) + "] = " + std::to_string((double)bs[i]) +
                            " is not 0 or a body 1.." + std::to_string(nb));
  return {n, nb, has_quats};
}

template <typename T>
py::tuple forward(const Arr<T>& means, const Arr<T>& quats, const Arr<T>& basis, const Arr<T>& gate,
                  const Arr<T>& transforms) {
  const auto [n, nb, has_quats] = check_inputs(means, quats, basis, gate, transforms);
  Arr<T> out_m({(py::ssize_t)n, (py::ssize_t)3});
  Arr<T> out_q({(py::ssize_t)(has_quats ? n : 0), (py::ssize_t)4});
  const T *mu = means.data(), *q = has_quats ? quats.data() : nullptr, *bs = basis.data(), *gs = gate.data(),
          *tr = transforms.data();
  T *om = out_m.mutable_data(), *oq = has_quats ? out_q.mutable_data() : nullptr;
  {
    py::gil_scoped_release nogil;
    std::memcpy(om, mu, sizeof(T) * 3 * n);
    if (has_quats) std::memcpy(oq, q, sizeof(T) * 4 * n);
    for (int64_t i = 0; i < n; ++i) {
      if (bs[i] == 0) continue;
      const T* P = tr + ((int64_t)bs[i] - 1) * kPacked;
      const T g = gs[i], *m = mu + 3 * i;
      for (int k = 0; k < 3; ++k) {
        const T moved = P[3 * k] * m[0] + P[3 * k + 1] * m[1] + P[3 * k + 2] * m[2] + P[9 + k];
        om[3 * i + k] = m[k] + g * (moved - m[k]);
      }
      if (!has_quats) continue;
      const T *L = P + 12, *qi = q + 4 * i;
      for (int k = 0; k < 4; ++k) {
        const T turned = L[4 * k] * qi[0] + L[4 * k + 1] * qi[1] + L[4 * k + 2] * qi[2] + L[4 * k + 3] * qi[3];
        oq[4 * i + k] = qi[k] + g * (turned - qi[k]);
      }
    }
  }
  return py::make_tuple(out_m, out_q);
}

// v_means (N,3), v_quats (N,4) or (0,4) -> (d means, d quats, d gate (N,), d transforms (B,28)).
// One thread: the bodies' sums are then the same bits on every run.
template <typename T>
py::tuple backward(const Arr<T>& means, const Arr<T>& quats, const Arr<T>& basis, const Arr<T>& gate,
                   const Arr<T>& transforms, const Arr<T>& v_means, const Arr<T>& v_quats) {
  const auto [n, nb, has_quats] = check_inputs(means, quats, basis, gate, transforms);
  check(v_means, "v_means", n, 3);
  if (has_quats) check(v_quats, "v_quats", n, 4);
  Arr<T> d_m({(py::ssize_t)n, (py::ssize_t)3});
  Arr<T> d_q({(py::ssize_t)(has_quats ? n : 0), (py::ssize_t)4});
  Arr<T> d_g({(py::ssize_t)n});
  Arr<T> d_t({(py::ssize_t)nb, (py::ssize_t)kPacked});
  const T *mu = means.data(), *q = has_quats ? quats.data() : nullptr, *bs = basis.data(), *gs = gate.data(),
          *tr = transforms.data(), *vm = v_means.data(), *vq = has_quats ? v_quats.data() : nullptr;
  T *dm = d_m.mutable_data(), *dq = has_quats ? d_q.mutable_data() : nullptr, *dg = d_g.mutable_data(),
    *dt = d_t.mutable_data();
  {
    py::gil_scoped_release nogil;
    std::memcpy(dm, vm, sizeof(T) * 3 * n);
    if (has_quats) std::memcpy(dq, vq, sizeof(T) * 4 * n);
    std::memset(dg, 0, sizeof(T) * n);
    std::memset(dt, 0, sizeof(T) * kPacked * nb);
    for (int64_t i = 0; i < n; ++i) {
      if (bs[i] == 0) continue;
      const int64_t b = (int64_t)bs[i] - 1;
      const T* P = tr + b * kPacked;
      T* D = dt + b * kPacked;
      const T g = gs[i], *m = mu + 3 * i, *v = vm + 3 * i;
      T gate_grad = 0;
      for (int k = 0; k < 3; ++k) {
        const T moved = P[3 * k] * m[0] + P[3 * k + 1] * m[1] + P[3 * k + 2] * m[2] + P[9 + k];
        gate_grad += v[k] * (moved - m[k]);
        for (int j = 0; j < 3; ++j) D[3 * k + j] += g * v[k] * m[j];
        D[9 + k] += g * v[k];
      }
      for (int j = 0; j < 3; ++j)
        dm[3 * i + j] = (1 - g) * v[j] + g * (P[j] * v[0] + P[3 + j] * v[1] + P[6 + j] * v[2]);
      if (has_quats) {
        const T *L = P + 12, *qi = q + 4 * i, *w = vq + 4 * i;
        T* DL = D + 12;
        for (int k = 0; k < 4; ++k) {
          const T turned = L[4 * k] * qi[0] + L[4 * k + 1] * qi[1] + L[4 * k + 2] * qi[2] + L[4 * k + 3] * qi[3];
          gate_grad += w[k] * (turned - qi[k]);
          for (int j = 0; j < 4; ++j) DL[4 * k + j] += g * w[k] * qi[j];
        }
        for (int j = 0; j < 4; ++j)
          dq[4 * i + j] = (1 - g) * w[j] + g * (L[j] * w[0] + L[4 + j] * w[1] + L[8 + j] * w[2] + L[12 + j] * w[3]);
      }
      dg[i] = gate_grad;
    }
  }
  return py::make_tuple(d_m, d_q, d_g, d_t);
}


// The packed transforms of B bodies from their axis-angle rotations, translations and pivots
// (B,3 each): motion.body_transforms' quaternion q = [cos(h), v sin(h) / |v|] (h = |v| / 2; near 0
// the series 0.5 - |v|^2 / 48 for sin(h) / |v|), L = L(q), R = the lower 3x3 of L(q) R(conj q),
// c = pivot + translation - R pivot. In torch these are ~25 autograd nodes on a few rows each.
template <typename T>
struct Quat {
  T q[4];
  T s, theta, theta2, half;
};

template <typename T>
Quat<T> axis_angle(const T* v) {
  Quat<T> o;
  o.theta2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
  o.theta = std::sqrt(std::max(o.theta2, (T)1e-12));
  o.half = (T)0.5 * o.theta;
  o.s = o.theta2 < (T)1e-8 ? (T)0.5 - o.theta2 / (T)48 : std::sin(o.half) / o.theta;
  o.q[0] = std::cos(o.half);
  for (int i = 0; i < 3; ++i) o.q[i + 1] = v[i] * o.s;
  return o;
}

// L(q) (left multiplication) and R(conj q) (right multiplication by the conjugate), row-major,
// as the gathers of motion._LEFT / _RIGHT_CONJ: entry k is sign[k] * q[index[k]].
constexpr int kIndex[16] = {0, 1, 2, 3, 1, 0, 3, 2, 2, 3, 0, 1, 3, 2, 1, 0};
constexpr int kLeftSign[16] = {1, -1, -1, -1, 1, 1, -1, 1, 1, 1, 1, -1, 1, -1, 1, 1};
constexpr int kRightConjSign[16] = {1, 1, 1, 1, -1, 1, -1, 1, -1, 1, 1, -1, -1, -1, 1, 1};

template <typename T>
void quat_matrices(const T* q, T* L, T* Rc) {
  for (int k = 0; k < 16; ++k) {
    L[k] = kLeftSign[k] * q[kIndex[k]];
    Rc[k] = kRightConjSign[k] * q[kIndex[k]];
  }
}

template <typename T>
Arr<T> transforms_forward(const Arr<T>& rotation, const Arr<T>& translation, const Arr<T>& pivots) {
  const int64_t nb = rotation.ndim() == 2 ? rotation.shape(0) : -1;
  check(rotation, "rotation", nb, 3);
  check(translation, "translation", nb, 3);
  check(pivots, "pivots", nb, 3);
  Arr<T> out({(py::ssize_t)nb, (py::ssize_t)kPacked});
  const T *rot = rotation.data(), *tr = translation.data(), *pv = pivots.data();
  T* o = out.mutable_data();
  for (int64_t b = 0; b < nb; ++b) {
    const Quat<T> a = axis_angle(rot + 3 * b);
    T L[16], Rc[16];
    quat_matrices(a.q, L, Rc);
    T* P = o + b * kPacked;
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) {
        T m = 0;
        for (int k = 0; k < 4; ++k) m += L[4 * (i + 1) + k] * Rc[4 * k + (j + 1)];
        P[3 * i + j] = m;
      }
    const T* p = pv + 3 * b;
    for (int i = 0; i < 3; ++i)
      P[9 + i] = p[i] + tr[3 * b + i] - (P[3 * i] * p[0] + P[3 * i + 1] * p[1] + P[3 * i + 2] * p[2]);
    for (int k = 0; k < 16; ++k) P[12 + k] = L[k];
  }
  return out;
}

// v (B,28) -> (d rotation (B,3), d translation (B,3)); pivots get none.
template <typename T>
py::tuple transforms_backward(const Arr<T>& rotation, const Arr<T>& translation, const Arr<T>& pivots,
                              const Arr<T>& v) {
  const int64_t nb = rotation.ndim() == 2 ? rotation.shape(0) : -1;
  check(rotation, "rotation", nb, 3);
  check(translation, "translation", nb, 3);
  check(pivots, "pivots", nb, 3);
  check(v, "v", nb, kPacked);
  Arr<T> d_rot({(py::ssize_t)nb, (py::ssize_t)3}), d_tr({(py::ssize_t)nb, (py::ssize_t)3});
  const T *rot = rotation.data(), *pv = pivots.data(), *vv = v.data();
  T *dr = d_rot.mutable_data(), *dt = d_tr.mutable_data();
  for (int64_t b = 0; b < nb; ++b) {
    const T* r = rot + 3 * b;
    const T* p = pv + 3 * b;
    const T* V = vv + b * kPacked;
    const Quat<T> a = axis_angle(r);
    T L[16], Rc[16];
    quat_matrices(a.q, L, Rc);
    // c = p + t - R p: dt = dc, dR -= dc p^T
    T dR[9];
    for (int i = 0; i < 3; ++i) {
      dt[3 * b + i] = V[9 + i];
      for (int j = 0; j < 3; ++j) dR[3 * i + j] = V[3 * i + j] - V[9 + i] * p[j];
    }
    // M = L Rc with dM nonzero on its lower 3x3: dL = dM Rc^T (+ the packed L's own), dRc = L^T dM
    T dL[16], dRc[16];
    for (int k = 0; k < 16; ++k) dL[k] = V[12 + k];
    for (int i = 1; i < 4; ++i)
      for (int k = 0; k < 4; ++k)
        for (int j = 1; j < 4; ++j) dL[4 * i + k] += dR[3 * (i - 1) + (j - 1)] * Rc[4 * k + j];
    for (int k = 0; k < 4; ++k)
      for (int j = 0; j < 4; ++j) {
        T s = 0;
        if (j >= 1)
          for (int i = 1; i < 4; ++i) s += L[4 * i + k] * dR[3 * (i - 1) + (j - 1)];
        dRc[4 * k + j] = s;
      }
    T dq[4] = {0, 0, 0, 0};
    for (int k = 0; k < 16; ++k) dq[kIndex[k]] += kLeftSign[k] * dL[k] + kRightConjSign[k] * dRc[k];
    // q = [cos(h), r s]: h = theta / 2, theta = sqrt(max(|r|^2, 1e-12))
    const bool clamped = !(a.theta2 >= (T)1e-12);
    const bool series = a.theta2 < (T)1e-8;
    const T ds_dtheta = (T)0.5 * std::cos(a.half) / a.theta - std::sin(a.half) / (a.theta * a.theta);
    const T rq = dq[1] * r[0] + dq[2] * r[1] + dq[3] * r[2];
    for (int j = 0; j < 3; ++j) {
      const T dtheta = clamped ? (T)0 : r[j] / a.theta;
      const T ds = series ? -(T)2 * r[j] / (T)48 : ds_dtheta * dtheta;
      dr[3 * b + j] = dq[0] * -std::sin(a.half) * (T)0.5 * dtheta + dq[j + 1] * a.s + rq * ds;
    }
  }
  return py::make_tuple(d_rot, d_tr);
}

}  // namespace

PYBIND11_MODULE(_native, m) {
  m.doc() = "Rigid body motion of Gaussians and its VJP (recon/dtg/motion.py)";
  // one name per dtype: overloads would let a forcecast pick float for a double array
  m.def("forward_float32", &forward<float>);
  m.def("forward_float64", &forward<double>);
  m.def("backward_float32", &backward<float>);
  m.def("backward_float64", &backward<double>);
  m.def("transforms_forward_float32", &transforms_forward<float>);
  m.def("transforms_forward_float64", &transforms_forward<double>);
  m.def("transforms_backward_float32", &transforms_backward<float>);
  m.def("transforms_backward_float64", &transforms_backward<double>);
}
