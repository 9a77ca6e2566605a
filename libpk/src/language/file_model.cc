// pk::Model from a model file: a LinearModel when the analysis finds the structure the exact
// propagator needs, otherwise an OdeModel that evaluates the expression graph on the AD types.
#include <fstream>
#include <mutex>
#include <sstream>
#include <utility>

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

class FileOdeModel final : public OdeModel {
 public:
  FileOdeModel(const OdeModelSpec& spec, const CompiledModel& m, std::string why_not_linear)
      : OdeModel(spec), rhs_(m.graph, m.rhs, static_cast<int>(m.compartments.size())),
        why_not_linear_(std::move(why_not_linear)) {
    for (int root : m.outputs) outputs_.emplace_back(m.graph, std::vector<int>{root}, rhs_num_states());
    set_declarations(m.declarations);
  }

  const std::string& why_not_linear() const { return why_not_linear_; }

  void Rhs(const Eigen::VectorXd& x, const Eigen::VectorXd& theta, Eigen::VectorXd* f) const override {
    f->resize(num_compartments());
    rhs_.Run<double>(x.data(), theta.data(), f->data(), &Slots<double>());
  }

  double OutputValue(int output, const Eigen::VectorXd& x, const Eigen::VectorXd& theta) const override {
    double y = 0;
    outputs_[static_cast<size_t>(output - 1)].Run<double>(x.data(), theta.data(), &y, &Slots<double>());
    return y;
  }

  void OutputDirectional(int output, const Eigen::VectorXd& x, const Eigen::VectorXd& theta,
                         const Eigen::MatrixXd& dx, const Eigen::MatrixXd& dtheta, double* y,
                         Eigen::RowVectorXd* dy) const override {
    thread_local std::vector<Dual> xd, td;
    Seed(x, dx, &xd);
    Seed(theta, dtheta, &td);
    Dual g;
    outputs_[static_cast<size_t>(output - 1)].Run<Dual>(xd.data(), td.data(), &g, &Slots<Dual>());
    *y = g.value();
    if (g.derivatives().size()) {
      *dy = g.derivatives().transpose();
    } else {
      dy->setZero(dx.cols());
    }
  }

 protected:
  void RecordRhs(const TapeScalar* x, const TapeScalar* theta, TapeScalar* f) const override {
    rhs_.Run<TapeScalar>(x, theta, f, &Slots<TapeScalar>());
  }

 private:
  int rhs_num_states() const { return num_compartments(); }
  static void Seed(const Eigen::VectorXd& v, const Eigen::MatrixXd& d, std::vector<Dual>* out) {
    out->resize(static_cast<size_t>(v.size()));
    for (Eigen::Index i = 0; i < v.size(); ++i) (*out)[static_cast<size_t>(i)] = Dual(v(i), d.row(i).transpose());
  }

  Program rhs_;
  std::vector<Program> outputs_;
  std::string why_not_linear_;
};

std::shared_ptr<const Model> Build(const CompiledModel& m) {
  const ModelText& t = m.text;
  const int n = static_cast<int>(m.compartments.size());
  if (m.linear) {
    // Observations in the central compartment measure the output; in another, its amount.
    std::vector<std::vector<LinearTerm>> rows(static_cast<size_t>(n));
    for (int c = 0; c < n; ++c) {
      if (c + 1 == m.central) {
        rows[static_cast<size_t>(c)] = m.c_terms;
      } else {
        LinearTerm amount;
        amount.col = c;
        rows[static_cast<size_t>(c)] = {amount};
      }
    }
    return LinearModel::FromTerms(t.name, t.description, m.compartments, m.parameters, m.defaults, m.central,
                                  m.default_dose, m.a_terms, rows, 0, InitialStructure(), m.declarations,
                                  m.signed_parameters);
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
  return std::make_shared<FileOdeModel>(spec, m, m.why_not_linear);
}

}  // namespace
}  // namespace lang
}  // namespace internal

std::shared_ptr<const Model> ParseModel(const std::string& text, const std::string& source) {
  using namespace internal::lang;
  return Build(Analyse(Parse(text, source)));
}

std::shared_ptr<const Model> LoadModelFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError(path, 0, 0, "cannot read the model file");
  std::ostringstream text;
  text << in.rdbuf();
  if (in.bad()) throw InputError(path, 0, 0, "cannot read the model file");
  return ParseModel(text.str(), path);
}

std::string WhyNotLinear(const Model& model) {
  const auto* file = dynamic_cast<const internal::lang::FileOdeModel*>(&model);
  return file == nullptr ? "" : file->why_not_linear();
}

}  // namespace pk
