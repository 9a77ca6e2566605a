// libpk: nonlinear compartment models, dx/dt = f(x, θ) + u, y_k = g_k(x, θ).
//
// A nonlinear model is a functor with a templated right-hand side and output;
// libpk differentiates it by automatic differentiation: f is recorded on a
// tape (pk::TapeScalar) and swept forward for f_x and f_θ and backward for the
// adjoint's λᵀf_x and λᵀf_θ; g's directional derivatives come from forward mode
// (pk::Dual), its gradient at an adjoint's sample from the tape. So both Rhs and
// Output must compile with T = double, pk::Dual, pk::HyperDual, pk::HyperDual3 and pk::TapeScalar, and Rhs
// also with pk::FixedDual<W> and pk::SparsityScalar (the one-step adjoint's compressed Jacobians).
// The input u is the vector of infusion rates into each compartment and adds
// to f; boluses are jumps of x. Such a model is propagated by the ODE propagator
// (Dormand–Prince or CVODES, docs/ode_routes.md); linear catalogue models can use
// the same propagator.
//
//   struct OneCmtIvMm {  // Michaelis–Menten elimination; θ = (VMAX, KM, V)
//     template <typename T>
//     void Rhs(const T* x, const T* theta, T* dxdt) const {
//       const T c = x[0] / theta[2];
//       dxdt[0] = -theta[0] * c / (theta[1] + c);
//     }
//     template <typename T>
//     T Output(int output, const T* x, const T* theta) const { return x[0] / theta[2]; }
//   };
//
//   pk::OdeModelSpec spec;
//   spec.name = "1cmt_iv_mm";
//   spec.compartments = {"CENTRAL"};
//   spec.parameters = {{"VMAX", 10}, {"KM", 2}, {"V", 30}};
//   std::shared_ptr<const pk::Model> model = pk::MakeOdeModel(spec, OneCmtIvMm());
//
// f must not depend on time explicitly (events carry all time dependence).
// Rhs and Output must not themselves evaluate a libpk model: the tape and the lanes' buffers are kept
// per thread and are not re-entrant. A row of dxdt that Rhs leaves unset is 0. Where a function's
// partial is infinite (sqrt, log or pow at 0), a direction whose tangent is 0 keeps a derivative of 0
// on every first-order type (Dual, FixedDual's lanes, the tape's tangents), whatever the number of
// directions. Products and quotients are not guarded: 0 times an infinite tangent (x·√y at
// x = y = 0) or an infinite operand (−K/x at x = 0) can give NaN on the lanes (up to 8 directions)
// where Dual or the tape gives 0 (a guard in FixedDual's * made f on lanes 1.6 times slower).
// libpk's "same bits" between double and the lanes assume the compiler does not contract a*b+c
// into an FMA differently in the two (GCC and clang do not at their default x86-64 baseline).
// Outputs are numbered from 1; an observation measures output DVID (a data
// column, default 1). Output 1 is the model's "central concentration" used by
// pksim's CP column and exposure metrics.
#ifndef PK_ODE_MODEL_H_
#define PK_ODE_MODEL_H_

#include <memory>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "pk/dual.h"
#include "pk/fixed_dual.h"
#include "pk/hyper_dual.h"
#include "pk/model.h"
#include "pk/sparsity_scalar.h"
#include "pk/tape_scalar.h"

namespace pk {

/// Names, sizes and defaults of a nonlinear model.
struct OdeModelSpec {
  std::string name;
  std::string description;
  std::vector<std::string> compartments;
  /// Parameter names (upper case) with sensible starting values.
  std::vector<std::pair<std::string, double>> parameters;
  /// Output names; outputs are numbered 1, 2, … (the DVID of an observation).
  std::vector<std::string> outputs = {"CP"};
  int central = 1;       ///< 1-based compartment shown as the central one
  int default_dose = 1;  ///< 1-based compartment receiving doses with CMT=0
  /// What data-driven starting values may assume (pk/model.h); none by default.
  InitialStructure initial_structure;
  /// Parameters that may be zero or negative; every other one must be positive.
  std::vector<std::string> signed_parameters;
  /// What a model file declares (pk/model.h); empty for the catalogue.
  ModelDeclarations declarations;
};

/// Two first-order directions d₁ = (dx1, dθ1), d₂ = (dx2, dθ2) in (x, θ) and the state's own
/// second-order part dx12 along them: what a second-order sensitivity step asks of f and g.
/// Each pointer addresses n (dx) or m (dθ) values; dx12 may be null (zero).
struct SecondDirections {
  const double* dx1 = nullptr;
  const double* dtheta1 = nullptr;
  const double* dx2 = nullptr;
  const double* dtheta2 = nullptr;
  const double* dx12 = nullptr;
};

/// Three first-order directions and their mixed parts, indexed by bit mask as pk::HyperDual3's
/// parts: dx[1], dx[2], dx[4] the directions in x, dx[3], dx[5], dx[6] the state's second-order
/// parts along their pairs, dx[7] its third-order part; dtheta[1], dtheta[2], dtheta[4] the
/// directions in θ (θ is linear in the parameters: no mixed parts). A null pointer is zero.
struct ThirdDirections {
  const double* dx[8] = {nullptr, nullptr, nullptr, nullptr, nullptr, nullptr, nullptr, nullptr};
  const double* dtheta[8] = {nullptr, nullptr, nullptr, nullptr, nullptr, nullptr, nullptr, nullptr};
};

namespace internal {
class StageTape;  // records f at a one-step method's stages (libpk/src/ode/ode_system.h)
class ColouredJacobian;  // compressed Jacobians of f (libpk/src/ode/coloured_jacobian.h)
class OdeSystem;         // the propagators' view of a model (libpk/src/ode/ode_system.h)
}  // namespace internal

/// The runtime interface of a nonlinear model. Implemented by AutoDiffOdeModel (use
/// MakeOdeModel); derivatives always come from AD. f is recorded on a tape (RecordRhs) at each
/// (x, θ) it is asked about, per thread, and the recording is swept forward for directional
/// derivatives and backward for vector–Jacobian products (libpk/src/ode_model.cc).
class OdeModel : public Model {
 public:
  ~OdeModel() override;
  bool is_linear() const override { return false; }

  /// Output 1 when `cmt` is the central compartment, otherwise the amount in `cmt`.
  double Output(int cmt, const Eigen::VectorXd& x, const Eigen::VectorXd& theta) const override;

  /// f(x, θ) (the input u is added by the propagator).
  virtual void Rhs(const Eigen::VectorXd& x, const Eigen::VectorXd& theta, Eigen::VectorXd* f) const = 0;
  /// f and, for k directions (columns of dx, n×k, and dtheta, m×k), the
  /// directional derivatives df = f_x dx + f_θ dtheta (n×k). With dx = [I 0]
  /// and dtheta = [0 I] they are the Jacobians [f_x f_θ]. Up to 8 directions are one evaluation of f
  /// on pk::FixedDual lanes; more, a sweep of the recording.
  void RhsDirectional(const Eigen::VectorXd& x, const Eigen::VectorXd& theta, const Eigen::MatrixXd& dx,
                      const Eigen::MatrixXd& dtheta, Eigen::VectorXd* f, Eigen::MatrixXd* df) const;
  /// f and the vector–Jacobian products wᵀf_x (n) and wᵀf_θ (m), by one
  /// reverse-mode pass (the adjoint route's λᵀf_x and λᵀf_θ).
  void RhsVectorJacobian(const Eigen::VectorXd& x, const Eigen::VectorXd& theta, const Eigen::VectorXd& w,
                         Eigen::VectorXd* f, Eigen::VectorXd* wfx, Eigen::VectorXd* wftheta) const;
  /// y = g_output(x, θ), output numbered from 1.
  virtual double OutputValue(int output, const Eigen::VectorXd& x, const Eigen::VectorXd& theta) const = 0;
  /// y and its gradients g_x (n) and g_θ (m), by one reverse-mode pass (the adjoint's jump at a sample).
  /// Records on the calling thread's active tape (pk::Tape::Active()) and clears it.
  double OutputGradient(int output, const Eigen::VectorXd& x, const Eigen::VectorXd& theta, Eigen::VectorXd* gx,
                        Eigen::VectorXd* gtheta) const;
  /// y and dy = g_x dx + g_θ dtheta (1×k).
  virtual void OutputDirectional(int output, const Eigen::VectorXd& x, const Eigen::VectorXd& theta,
                                 const Eigen::MatrixXd& dx, const Eigen::MatrixXd& dtheta, double* y,
                                 Eigen::RowVectorXd* dy) const = 0;
  /// The mixed second derivative of f along `d`: f12 = f_x dx12 + f''[d₁, d₂] (n), the
  /// right-hand side of the second-order sensitivity ∂²x/∂p_k∂p_l. One evaluation on pk::HyperDual.
  virtual void RhsSecondDirectional(const Eigen::VectorXd& x, const Eigen::VectorXd& theta,
                                    const SecondDirections& d, Eigen::VectorXd* f12) const = 0;
  /// The same for output `output`: g_x dx12 + g''[d₁, d₂].
  virtual double OutputSecondDirectional(int output, const Eigen::VectorXd& x, const Eigen::VectorXd& theta,
                                         const SecondDirections& d) const = 0;
  /// The mixed third derivative of f along `d` (n): the ε₁ε₂ε₃ part of f on pk::HyperDual3, the
  /// right-hand side of the third-order sensitivity ∂³x/∂p_i∂p_j∂p_k.
  virtual void RhsThirdDirectional(const Eigen::VectorXd& x, const Eigen::VectorXd& theta, const ThirdDirections& d,
                                   Eigen::VectorXd* f123) const = 0;
  /// The same for output `output`.
  virtual double OutputThirdDirectional(int output, const Eigen::VectorXd& x, const Eigen::VectorXd& theta,
                                        const ThirdDirections& d) const = 0;
  /// f on pk::HyperDual3 with every part of x (n) and θ (m) given, into f (n), every part: the
  /// higher-order sensitivities when a dose moves with the parameters carry the state as such a jet.
  virtual void RhsJet(const HyperDual3* x, const HyperDual3* theta, HyperDual3* f) const = 0;
  /// The same for output `output`.
  virtual HyperDual3 OutputJet(int output, const HyperDual3* x, const HyperDual3* theta) const = 0;

 protected:
  explicit OdeModel(const OdeModelSpec& spec);
  /// Evaluates f with tape variables x (n) and θ (m) into f (n), recording it on the active tape.
  virtual void RecordRhs(const TapeScalar* x, const TapeScalar* theta, TapeScalar* f) const = 0;
  /// Evaluates output `output` with tape variables x (n) and θ (m), recording it on the active tape.
  virtual TapeScalar RecordOutput(int output, const TapeScalar* x, const TapeScalar* theta) const = 0;
  /// f on the lanes of a compressed Jacobian (pk/fixed_dual.h), for the widths libpk uses (4, 6, 8).
  /// A model that cannot evaluate on them returns false (the default), and its adjoint records f
  /// on the tape instead. It must write the rows RhsSparsity writes, as RhsSparsity does (the same
  /// template, as in AutoDiffOdeModel): where RhsSparsity sets every row without reading it, the output
  /// lanes are not zeroed first and hold an earlier stage's values.
  virtual bool ColouredRhs(const FixedDual<4>*, const FixedDual<4>*, FixedDual<4>*) const { return false; }
  virtual bool ColouredRhs(const FixedDual<6>*, const FixedDual<6>*, FixedDual<6>*) const { return false; }
  virtual bool ColouredRhs(const FixedDual<8>*, const FixedDual<8>*, FixedDual<8>*) const { return false; }
  /// f's dependence on x and θ (pk/sparsity_scalar.h); false (the default) when unknown.
  virtual bool RhsSparsity(const SparsityScalar*, const SparsityScalar*, SparsityScalar*) const { return false; }

 private:
  friend class internal::StageTape;
  friend class internal::ColouredJacobian;
  friend class internal::OdeSystem;
  // RhsDirectional's f (n) and df (n×k, column-major) on W ≥ k lanes, with dx (n×k, column-major); false
  // when k > 8 or the model does not evaluate on lanes.
  bool DirectionalOnLanes(const double* x, const double* dx, int k, const Eigen::VectorXd& theta,
                          const Eigen::MatrixXd& dtheta, double* f, double* df) const;
  template <int W>
  bool DirectionalOnLanes(const double* x, const double* dx, int k, const Eigen::VectorXd& theta,
                          const Eigen::MatrixXd& dtheta, double* f, double* df) const;
  unsigned long id_;  // identifies this model in the per-thread recordings (an address may be reused)
};

/// An OdeModel from a functor with templated `Rhs` and `Output` (see above).
template <typename Functor>
class AutoDiffOdeModel final : public OdeModel {
 public:
  AutoDiffOdeModel(const OdeModelSpec& spec, Functor functor) : OdeModel(spec), f_(std::move(functor)) {}

  const Functor& functor() const { return f_; }

  void Rhs(const Eigen::VectorXd& x, const Eigen::VectorXd& theta, Eigen::VectorXd* f) const override {
    f->setZero(num_compartments());  // a row f leaves unset is 0, as on the lanes and the tape
    f_.Rhs(x.data(), theta.data(), f->data());
  }

  double OutputValue(int output, const Eigen::VectorXd& x, const Eigen::VectorXd& theta) const override {
    return f_.Output(output, x.data(), theta.data());
  }

  void OutputDirectional(int output, const Eigen::VectorXd& x, const Eigen::VectorXd& theta,
                         const Eigen::MatrixXd& dx, const Eigen::MatrixXd& dtheta, double* y,
                         Eigen::RowVectorXd* dy) const override {
    // Up to 8 directions on FixedDual lanes, as RhsDirectional: nothing allocated per call.
    if (dx.cols() != dtheta.cols()) throw std::invalid_argument("OutputDirectional: dx and dtheta differ in columns");
    if (dx.cols() <= 4) return OutputOnLanes<4>(output, x, theta, dx, dtheta, y, dy);
    if (dx.cols() <= 8) return OutputOnLanes<8>(output, x, theta, dx, dtheta, y, dy);
    std::vector<Dual> xd, td;
    Seed(x, dx, &xd);
    Seed(theta, dtheta, &td);
    const Dual g = f_.Output(output, xd.data(), td.data());
    *y = g.value();
    if (g.derivatives().size()) {
      *dy = g.derivatives().transpose();
    } else {
      dy->setZero(dx.cols());
    }
  }

  void RhsSecondDirectional(const Eigen::VectorXd& x, const Eigen::VectorXd& theta, const SecondDirections& d,
                            Eigen::VectorXd* f12) const override {
    const int n = num_compartments();
    thread_local std::vector<HyperDual> xs, ts, fs;
    SeedSecond(x, d.dx1, d.dx2, d.dx12, &xs);
    SeedSecond(theta, d.dtheta1, d.dtheta2, nullptr, &ts);
    fs.assign(static_cast<size_t>(n), HyperDual());
    f_.Rhs(xs.data(), ts.data(), fs.data());
    f12->resize(n);
    for (int i = 0; i < n; ++i) (*f12)(i) = fs[static_cast<size_t>(i)].e12();
  }

  double OutputSecondDirectional(int output, const Eigen::VectorXd& x, const Eigen::VectorXd& theta,
                                 const SecondDirections& d) const override {
    thread_local std::vector<HyperDual> xs, ts;
    SeedSecond(x, d.dx1, d.dx2, d.dx12, &xs);
    SeedSecond(theta, d.dtheta1, d.dtheta2, nullptr, &ts);
    return f_.Output(output, xs.data(), ts.data()).e12();
  }

  void RhsThirdDirectional(const Eigen::VectorXd& x, const Eigen::VectorXd& theta, const ThirdDirections& d,
                           Eigen::VectorXd* f123) const override {
    const int n = num_compartments();
    thread_local std::vector<HyperDual3> xs, ts, fs;
    SeedThird(x, d.dx, &xs);
    SeedThird(theta, d.dtheta, &ts);
    fs.assign(static_cast<size_t>(n), HyperDual3());
    f_.Rhs(xs.data(), ts.data(), fs.data());
    f123->resize(n);
    for (int i = 0; i < n; ++i) (*f123)(i) = fs[static_cast<size_t>(i)].part(7);
  }

  double OutputThirdDirectional(int output, const Eigen::VectorXd& x, const Eigen::VectorXd& theta,
                                const ThirdDirections& d) const override {
    thread_local std::vector<HyperDual3> xs, ts;
    SeedThird(x, d.dx, &xs);
    SeedThird(theta, d.dtheta, &ts);
    return f_.Output(output, xs.data(), ts.data()).part(7);
  }

  void RhsJet(const HyperDual3* x, const HyperDual3* theta, HyperDual3* f) const override {
    for (int i = 0; i < num_compartments(); ++i) f[i] = HyperDual3();
    f_.Rhs(x, theta, f);
  }
  HyperDual3 OutputJet(int output, const HyperDual3* x, const HyperDual3* theta) const override {
    return f_.Output(output, x, theta);
  }

 protected:
  void RecordRhs(const TapeScalar* x, const TapeScalar* theta, TapeScalar* f) const override { f_.Rhs(x, theta, f); }
  bool ColouredRhs(const FixedDual<4>* x, const FixedDual<4>* theta, FixedDual<4>* f) const override {
    internal::CallOnLanes([&] { f_.Rhs(x, theta, f); });
    return true;
  }
  bool ColouredRhs(const FixedDual<6>* x, const FixedDual<6>* theta, FixedDual<6>* f) const override {
    internal::CallOnLanes([&] { f_.Rhs(x, theta, f); });
    return true;
  }
  bool ColouredRhs(const FixedDual<8>* x, const FixedDual<8>* theta, FixedDual<8>* f) const override {
    internal::CallOnLanes([&] { f_.Rhs(x, theta, f); });
    return true;
  }
  bool RhsSparsity(const SparsityScalar* x, const SparsityScalar* theta, SparsityScalar* f) const override {
    f_.Rhs(x, theta, f);
    return true;
  }
  TapeScalar RecordOutput(int output, const TapeScalar* x, const TapeScalar* theta) const override {
    return f_.Output(output, x, theta);
  }

 private:
  static void SeedSecond(const Eigen::VectorXd& v, const double* d1, const double* d2, const double* d12,
                         std::vector<HyperDual>* out) {
    out->resize(static_cast<size_t>(v.size()));
    for (Eigen::Index i = 0; i < v.size(); ++i) {
      (*out)[static_cast<size_t>(i)] = HyperDual(v(i), d1[i], d2[i], d12 == nullptr ? 0.0 : d12[i]);
    }
  }

  static void SeedThird(const Eigen::VectorXd& v, const double* const* parts, std::vector<HyperDual3>* out) {
    out->resize(static_cast<size_t>(v.size()));
    for (Eigen::Index i = 0; i < v.size(); ++i) {
      HyperDual3& h = (*out)[static_cast<size_t>(i)];
      h = HyperDual3(v(i));
      for (int s = 1; s < 8; ++s) h.part(s) = parts[s] == nullptr ? 0.0 : parts[s][i];
    }
  }

  template <int W>
  void OutputOnLanes(int output, const Eigen::VectorXd& x, const Eigen::VectorXd& theta, const Eigen::MatrixXd& dx,
                     const Eigen::MatrixXd& dtheta, double* y, Eigen::RowVectorXd* dy) const {
    thread_local std::vector<FixedDual<W>> xs, ts;
    SeedLanes(x, dx, &xs);
    SeedLanes(theta, dtheta, &ts);
    const FixedDual<W> g = f_.Output(output, xs.data(), ts.data());
    *y = g.value();
    dy->resize(dx.cols());
    for (Eigen::Index j = 0; j < dx.cols(); ++j) (*dy)(j) = g.derivative(static_cast<int>(j));
  }

  // v's entries with the rows of d (at most W columns) in their first lanes.
  template <int W>
  static void SeedLanes(const Eigen::VectorXd& v, const Eigen::MatrixXd& d, std::vector<FixedDual<W>>* out) {
    out->resize(static_cast<size_t>(v.size()));
    for (Eigen::Index i = 0; i < v.size(); ++i) {
      FixedDual<W>& e = (*out)[static_cast<size_t>(i)];
      e = FixedDual<W>(v(i));
      for (Eigen::Index j = 0; j < d.cols(); ++j) e.derivative(static_cast<int>(j)) = d(i, j);
    }
  }

  static void Seed(const Eigen::VectorXd& v, const Eigen::MatrixXd& d, std::vector<Dual>* out) {
    out->resize(v.size());
    for (Eigen::Index i = 0; i < v.size(); ++i) (*out)[i] = Dual(v(i), d.row(i).transpose());
  }

  Functor f_;
};

/// Wraps a functor into a model (see the example at the top of this file).
template <typename Functor>
std::shared_ptr<const OdeModel> MakeOdeModel(const OdeModelSpec& spec, Functor functor) {
  return std::make_shared<AutoDiffOdeModel<Functor>>(spec, std::move(functor));
}

}  // namespace pk

#endif  // PK_ODE_MODEL_H_
