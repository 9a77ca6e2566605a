// pk::Model from a model file: a LinearModel when the analysis finds the structure the exact
// propagator needs, otherwise an OdeModel that evaluates the expression graph on the AD types.
#include <algorithm>
#include <cmath>
#include <fstream>
#include <memory>
#include <sstream>
#include <utility>

#include "hyper_dual_number.h"
#include "language/analysis.h"
#include "language/expression.h"
#include "pk/error.h"
#include "pk/linear_model.h"
#include "pk/model_file.h"
#include "pk/ode_model.h"

namespace pk {
namespace internal {
namespace lang {
namespace {

// Scratch slots per scalar type and thread: an evaluation allocates nothing once warm.
template <typename T>
std::vector<T>& Slots() {
  thread_local std::vector<T> slots;
  return slots;
}

// The analysed model as a functor with templated Rhs and Output, which MakeOdeModel wraps as it
// wraps a catalogue functor: the programs run on double, TapeScalar and Dual alike.
struct ProgramFunctor {
  Program rhs;
  std::vector<Program> outputs;  // output k (from 1) is outputs[k - 1]

  template <typename T>
  void Rhs(const T* x, const T* theta, T* dxdt) const {
    rhs.Run<T>(x, theta, dxdt, &Slots<T>());
  }
  template <typename T>
  T Output(int output, const T* x, const T* theta) const {
    T y(0.0);
    outputs[static_cast<size_t>(output - 1)].Run<T>(x, theta, &y, &Slots<T>());
    return y;
  }
};

// The $PK definitions' values from a model parameter vector: one program, no state.
ModelDeclarations WithPkValues(const CompiledModel& m, int n) {
  ModelDeclarations declarations = m.declarations;
  declarations.pk_definitions = m.pk_names;
  if (m.pk_roots.empty()) return declarations;
  const Program program(m.graph, m.pk_roots, n);
  declarations.pk_values = [program, n](const Eigen::VectorXd& parameters) {
    Eigen::VectorXd out(program.num_roots());
    const std::vector<double> x(static_cast<size_t>(n), 0.0);  // $PK reads no amount (checked)
    std::vector<double> slots;
    program.Run<double>(x.data(), parameters.data(), out.data(), &slots);
    return out;
  };
  return declarations;
}

// F1 = …, ALAG2 = … of $PK: one program over the modifiers' roots, on double and on pk::Dual.
ComputedModifiers Modifiers(const CompiledModel& m, int n) {
  ComputedModifiers out;
  if (m.modifier_roots.empty()) return out;
  out.names = m.modifier_names;
  out.reads = m.modifier_reads;
  const auto program = std::make_shared<const Program>(m.graph, m.modifier_roots, n);
  // The modifiers read no amount (checked: they are $PK definitions).
  out.evaluate = [program, n](const double* theta, double* values) {
    thread_local std::vector<double> zeros;
    zeros.assign(static_cast<size_t>(n), 0.0);
    program->Run<double>(zeros.data(), theta, values, &Slots<double>());
  };
  out.evaluate_dual = [program, n](const Dual* theta, Dual* values) {
    thread_local std::vector<Dual> zeros;
    zeros.assign(static_cast<size_t>(n), Dual(0.0));
    program->Run<Dual>(zeros.data(), theta, values, &Slots<Dual>());
  };
  out.evaluate_third = [program, n](const HyperDual3* theta, HyperDual3* values) {
    thread_local std::vector<HyperDual3> zeros;
    zeros.assign(static_cast<size_t>(n), HyperDual3(0.0));
    program->Run<HyperDual3>(zeros.data(), theta, values, &Slots<HyperDual3>());
  };
  return out;
}

// ψ(θ) from the coefficient nodes, with its Jacobian by forward-mode AD (pk::Dual).
DerivedCoefficients Coefficients(const CompiledModel& m, int n) {
  DerivedCoefficients derived;
  derived.count = static_cast<int>(m.derived_roots.size());
  if (derived.count == 0) return derived;
  derived.reads = m.derived_reads;
  const auto program = std::make_shared<const Program>(m.graph, m.derived_roots, n);
  derived.evaluate = [program, n](const Eigen::VectorXd& theta, Eigen::VectorXd* psi, Eigen::MatrixXd* jacobian) {
    const int p = static_cast<int>(theta.size());
    psi->resize(program->num_roots());
    thread_local std::vector<double> zeros;  // ψ reads no amount (checked)
    zeros.assign(static_cast<size_t>(n), 0.0);
    if (jacobian == nullptr) {
      program->Run<double>(zeros.data(), theta.data(), psi->data(), &Slots<double>());
      return;
    }
    thread_local std::vector<Dual> seeded, out, dual_zeros;
    seeded.resize(static_cast<size_t>(p));
    for (int j = 0; j < p; ++j) seeded[static_cast<size_t>(j)] = Dual(theta(j), p, j);
    dual_zeros.assign(static_cast<size_t>(n), Dual(0.0));
    out.resize(static_cast<size_t>(program->num_roots()));
    program->Run<Dual>(dual_zeros.data(), seeded.data(), out.data(), &Slots<Dual>());
    jacobian->setZero(program->num_roots(), p);
    for (int k = 0; k < program->num_roots(); ++k) {
      const Dual& v = out[static_cast<size_t>(k)];
      (*psi)(k) = v.value();
      if (v.derivatives().size() == p) jacobian->row(k) = v.derivatives().transpose();
    }
  };
  derived.evaluate_second = [program, n](const Eigen::VectorXd& theta, const Eigen::VectorXd& u,
                                         const Eigen::VectorXd& v, Eigen::VectorXd* psi, Eigen::VectorXd* psi_u,
                                         Eigen::VectorXd* psi_v, Eigen::VectorXd* psi_uv) {
    using internal::HyperDualNumber;
    const Eigen::Index p = theta.size(), q = program->num_roots();
    thread_local std::vector<HyperDualNumber> seeded, out, zeros;
    seeded.resize(static_cast<size_t>(p));
    for (Eigen::Index j = 0; j < p; ++j) seeded[static_cast<size_t>(j)] = HyperDualNumber(theta(j), u(j), v(j), 0);
    zeros.assign(static_cast<size_t>(n), HyperDualNumber(0.0));
    out.resize(static_cast<size_t>(q));
    program->Run<HyperDualNumber>(zeros.data(), seeded.data(), out.data(), &Slots<HyperDualNumber>());
    psi->resize(q), psi_u->resize(q), psi_v->resize(q), psi_uv->resize(q);
    for (Eigen::Index k = 0; k < q; ++k) {
      const HyperDualNumber& x = out[static_cast<size_t>(k)];
      (*psi)(k) = x.value(), (*psi_u)(k) = x.e1(), (*psi_v)(k) = x.e2(), (*psi_uv)(k) = x.e12();
    }
  };
  derived.evaluate_third = [program, n](const Eigen::VectorXd& theta, const Eigen::MatrixXd& directions,
                                        std::vector<Eigen::VectorXd>* parts) {
    const Eigen::Index p = theta.size(), q = program->num_roots();
    thread_local std::vector<HyperDual3> seeded, out, zeros;
    seeded.assign(static_cast<size_t>(p), HyperDual3());
    for (Eigen::Index j = 0; j < p; ++j) {
      HyperDual3& t = seeded[static_cast<size_t>(j)];
      t = HyperDual3(theta(j));
      for (int d = 0; d < 3; ++d) t.part(1 << d) = directions(j, d);
    }
    zeros.assign(static_cast<size_t>(n), HyperDual3(0.0));
    out.resize(static_cast<size_t>(q));
    program->Run<HyperDual3>(zeros.data(), seeded.data(), out.data(), &Slots<HyperDual3>());
    parts->assign(8, Eigen::VectorXd(q));
    for (Eigen::Index k = 0; k < q; ++k) {
      for (int s = 0; s < 8; ++s) (*parts)[static_cast<size_t>(s)](k) = out[static_cast<size_t>(k)].part(s);
    }
  };
  return derived;
}

std::shared_ptr<const Model> Build(const CompiledModel& m) {
  const ModelText& t = m.text;
  const int n = static_cast<int>(m.compartments.size());
  ModelDeclarations declarations = WithPkValues(m, n);
  declarations.computed_modifiers = Modifiers(m, n);
  if (m.linear) {
    // An observation with a DVID measures that output (row n + DVID); without one, in the central
    // compartment, the first output; in another compartment, its amount.
    std::vector<std::vector<LinearTerm>> rows(static_cast<size_t>(n));
    for (int c = 0; c < n; ++c) {
      if (c + 1 == m.central) {
        rows[static_cast<size_t>(c)] = m.c_terms.front();
      } else {
        LinearTerm amount;
        amount.col = c;
        rows[static_cast<size_t>(c)] = {amount};
      }
    }
    rows.insert(rows.end(), m.c_terms.begin(), m.c_terms.end());
    // Offsets (baselines) follow the rows: the central compartment's is output 1's.
    std::vector<std::vector<LinearTerm>> offsets;
    if (!m.d_terms.empty()) {
      offsets.assign(static_cast<size_t>(n), {});
      offsets[static_cast<size_t>(m.central - 1)] = m.d_terms.front();
      offsets.insert(offsets.end(), m.d_terms.begin(), m.d_terms.end());
    }
    return LinearModel::FromTerms(t.name, t.description, m.compartments, m.parameters, m.defaults, m.central,
                                  m.default_dose, m.a_terms, rows, 0, InitialStructure(), declarations,
                                  m.signed_parameters, Coefficients(m, n), m.output_names, std::move(offsets));
  }
  OdeModelSpec spec;
  spec.name = t.name;
  spec.description = t.description;
  spec.compartments = m.compartments;
  for (size_t i = 0; i < m.parameters.size(); ++i) spec.parameters.push_back({m.parameters[i], m.defaults(static_cast<Eigen::Index>(i))});
  spec.outputs = m.output_names;
  spec.central = m.central;
  spec.default_dose = m.default_dose;
  spec.signed_parameters = m.signed_parameters;
  spec.declarations = declarations;
  ProgramFunctor f{Program(m.graph, m.rhs, n), {}};
  for (int root : m.outputs) f.outputs.emplace_back(m.graph, std::vector<int>{root}, n);
  return MakeOdeModel(spec, std::move(f));
}

}  // namespace
}  // namespace lang
}  // namespace internal

std::shared_ptr<const Model> ParseModel(const std::string& text, const std::string& source, RandomEffects etas) {
  using namespace internal::lang;
  return Build(Analyse(Parse(text, source), etas == RandomEffects::kParameters));
}

std::shared_ptr<const Model> LoadModelFile(const std::string& path, RandomEffects etas) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError(path, 0, 0, "cannot read the model file");
  std::ostringstream text;
  text << in.rdbuf();
  if (in.bad()) throw InputError(path, 0, 0, "cannot read the model file");
  return ParseModel(text.str(), path, etas);
}

std::string WhyNotLinear(const Model& model) { return model.declarations().why_not_linear; }

std::vector<double> DeclaredSigmas(const Model& model, const ResidualErrorModel& in_use) {
  const ModelDeclarations& d = model.declarations();
  std::vector<double> out(in_use.sigma_names().size(), NAN);
  if (d.error_model != in_use.name()) return out;
  if (d.output_error_models.empty()) {
    if (d.sigma.size() == out.size()) out = d.sigma;
    return out;
  }
  for (int k = 1; k <= std::min<int>(in_use.num_outputs(), static_cast<int>(d.output_sigma.size())); ++k) {
    int first = 0;
    const ResidualErrorModel& e = in_use.ForOutput(k, &first);
    const std::vector<double>& given = d.output_sigma[static_cast<size_t>(k - 1)];
    if (given.size() != e.sigma_names().size() || e.name() != d.output_error_models[static_cast<size_t>(k - 1)]) continue;
    for (size_t j = 0; j < given.size(); ++j) out[static_cast<size_t>(first) + j] = given[j];
  }
  return out;
}

std::shared_ptr<const ResidualErrorModel> DeclaredErrorModel(const Model& model) {
  const ModelDeclarations& d = model.declarations();
  if (d.output_error_models.empty()) return d.error_model.empty() ? nullptr : MakeResidualError(d.error_model);
  std::vector<std::shared_ptr<const ResidualErrorModel>> models;
  for (const std::string& name : d.output_error_models) models.push_back(MakeResidualError(name));
  std::vector<std::string> outputs;
  for (size_t k = 0; k < models.size(); ++k) {
    outputs.push_back(k < model.output_names().size() ? model.output_names()[k] : "Y" + std::to_string(k + 1));
  }
  return MakePerOutputError(std::move(models), std::move(outputs));
}

}  // namespace pk
