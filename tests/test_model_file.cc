// Model files (pk/model_file.h): every shipped file against its catalogue twin on every bundled
// dataset and event type, every gradient route against finite differences, covariates and
// if/else, and the errors a model file can have, each with its line and column.

#include <catch2/catch.hpp>

#include <fstream>
#include <sstream>

#include "pk/catalogue.h"
#include "pk/error.h"
#include "pk/linear_model.h"
#include "pk/model_file.h"
#include "pk/objective.h"
#include "pk/ode_model.h"
#include "test_util.h"

namespace {

std::string ModelPath(const std::string& name) { return std::string(PK_SOURCE_DIR) + "/models/" + name + ".pkm"; }

const std::vector<std::string>& LinearTwins() {
  static const std::vector<std::string> names = {"1cmt_iv", "1cmt_oral", "2cmt_iv", "2cmt_oral", "3cmt_iv",
                                                 "3cmt_oral", "1cmt_oral_transit", "tf1", "tf2", "tf3", "tf4"};
  return names;
}
const std::vector<std::string>& OdeTwins() {
  static const std::vector<std::string> names = {"1cmt_iv_mm", "1cmt_oral_mm", "2cmt_iv_mm", "1cmt_iv_emax"};
  return names;
}

const std::vector<std::string>& Datasets() {
  static const std::vector<std::string> names = {"theophylline", "theophylline_blq", "cefamandole", "indomethacin",
                                                 "phenobarbital", "quinidine", "remifentanil", "mm_synthetic",
                                                 "emax_synthetic"};
  return names;
}

double MaxRel(const Eigen::VectorXd& a, const Eigen::VectorXd& b) {
  const double scale = std::max(a.cwiseAbs().maxCoeff(), 1e-300);
  return (a - b).cwiseAbs().maxCoeff() / scale;
}

// The two models' objective, predictions and gradient (each route) agree on subject `i`.
void CompareTwins(const std::shared_ptr<const pk::Model>& catalogue, const std::shared_ptr<const pk::Model>& file,
                  const std::shared_ptr<pk::Dataset>& data, int i, double tolerance,
                  const std::vector<pk::GradientRoute>& routes) {
  pk::ObjectiveOptions options;
  options.ode.relative_tolerance = 1e-10;
  options.ode.absolute_tolerance = 1e-12;
  const pk::Objective a(catalogue, data, i, options);
  const pk::Objective b(file, data, i, options);
  REQUIRE(a.parameter_names() == b.parameter_names());
  Eigen::VectorXd values = a.DefaultValues();
  std::vector<int> free;
  for (int k = 0; k < catalogue->num_parameters(); ++k) {
    values(k) *= 1.0 + 0.07 * k;  // away from round numbers
    free.push_back(k);
  }
  for (pk::GradientRoute route : routes) {
    const auto ea = a.Evaluate(values, free, pk::Objective::Need::kGradient, route);
    const auto eb = b.Evaluate(values, free, pk::Objective::Need::kGradient, route);
    INFO("subject " << i << ", route " << pk::ToString(route) << ": " << ea.message << " / " << eb.message);
    REQUIRE(ea.ok == eb.ok);
    if (!ea.ok) continue;
    CHECK(std::string(ea.propagator) == eb.propagator);
    CHECK(pk_test::RelDiff(ea.value, eb.value) < tolerance);
    CHECK(MaxRel(ea.predictions, eb.predictions) < tolerance);
    INFO("catalogue " << ea.gradient.transpose() << "\nfile      " << eb.gradient.transpose());
    CHECK(MaxRel(ea.gradient, eb.gradient) < tolerance);
  }
}

void CompareOnDatasets(const std::string& name, double tolerance, const std::vector<pk::GradientRoute>& routes) {
  const auto catalogue = pk::MakeModel(name);
  const auto file = pk::LoadModelFile(ModelPath(name));
  int compared = 0;
  for (const std::string& d : Datasets()) {
    auto data = std::make_shared<pk::Dataset>(
        pk::ReadDataset(std::string(PK_SOURCE_DIR) + "/datasets/" + d + ".csv"));
    INFO(name << " on " << d);
    for (int i : {0, static_cast<int>(data->subjects.size()) - 1}) {
      bool catalogue_takes = true;
      try {
        pk::Objective probe(catalogue, data, i, pk::ObjectiveOptions());
      } catch (const pk::InputError&) {
        catalogue_takes = false;
      }
      if (!catalogue_takes) {
        CHECK_THROWS_AS(pk::Objective(file, data, i, pk::ObjectiveOptions()), pk::InputError);
        continue;
      }
      // An observation in a compartment other than the central one measures its amount in a model
      // file, and a concentration (or, in tf<n>, the output) in the catalogue: not twins there.
      bool elsewhere = false;
      for (const pk::Record& r : data->subjects[static_cast<size_t>(i)].records) {
        elsewhere = elsewhere || (r.evid == pk::Evid::kObservation && r.cmt > 0 && r.cmt != catalogue->central_compartment());
      }
      if (elsewhere) continue;
      CompareTwins(catalogue, file, data, i, tolerance, routes);
      ++compared;
    }
  }
  CHECK(compared >= 4);
}

}  // namespace

TEST_CASE("model files: linear twins run on the exact route and equal the catalogue to 1e-10", "[model_file]") {
  for (const std::string& name : LinearTwins()) {
    const auto file = pk::LoadModelFile(ModelPath(name));
    INFO(name << ": " << pk::WhyNotLinear(*file));
    REQUIRE(dynamic_cast<const pk::LinearModel*>(file.get()) != nullptr);
    CHECK(file->name() == name);
    CHECK(file->parameter_names() == pk::MakeModel(name)->parameter_names());
    CompareOnDatasets(name, 1e-10, {pk::GradientRoute::kForward, pk::GradientRoute::kAdjoint});
  }
}

TEST_CASE("model files: nonlinear twins run on the ODE routes and equal the catalogue to 1e-7", "[model_file]") {
  for (const std::string& name : OdeTwins()) {
    const auto file = pk::LoadModelFile(ModelPath(name));
    INFO(name);
    REQUIRE(dynamic_cast<const pk::OdeModel*>(file.get()) != nullptr);
    CHECK(!pk::WhyNotLinear(*file).empty());
    CompareOnDatasets(name, 1e-7, {pk::GradientRoute::kForward, pk::GradientRoute::kAdjoint});
  }
}

TEST_CASE("model files: linear twins equal the catalogue on every event type", "[model_file]") {
  const std::vector<pk_test::Scenario> scenarios = {
      {"bolus", "1,0,100,0,0,0,0,1,.\n", {}, {}},
      {"infusion", "1,0,100,40,0,0,0,1,.\n", {}, {}},
      {"addl", "1,0,100,0,6,3,0,1,.\n", {}, {}},
      {"ss1 bolus", "1,0,100,0,12,0,1,1,.\n", {}, {}},
      {"ss constant infusion", "1,0,0,10,0,0,1,1,.\n", {}, {}},
      {"lag and F", "1,0,100,0,6,2,0,1,.\n", {"ALAG1", "F1"}, {0.7, 0.8}},
      {"D", "1,0,100,-2,0,0,0,1,.\n", {"D1"}, {2.2}},
      {"initial state", "1,0,100,0,6,2,0,1,.\n", {"X0_1"}, {30.0}},
  };
  for (const char* name : {"1cmt_oral", "2cmt_iv", "3cmt_oral", "1cmt_iv_mm", "1cmt_iv_emax"}) {
    const auto catalogue = pk::MakeModel(name);
    const auto file = pk::LoadModelFile(ModelPath(name));
    const bool ode = dynamic_cast<const pk::OdeModel*>(file.get()) != nullptr;
    for (const pk_test::Scenario& sc : scenarios) {
      INFO(name << " / " << sc.name);
      const auto data = pk_test::ScenarioData(sc);
      pk::ObjectiveOptions options;
      options.ode.relative_tolerance = 1e-10;
      options.ode.absolute_tolerance = 1e-12;
      const pk::Objective a(catalogue, data, 0, options), b(file, data, 0, options);
      Eigen::VectorXd values = a.DefaultValues();
      std::vector<int> free;
      for (int k = 0; k < catalogue->num_parameters(); ++k) free.push_back(k);
      for (size_t e = 0; e < sc.extra_free.size(); ++e) {
        const int k = a.ParameterIndex(sc.extra_free[e]);
        values(k) = sc.extra_values[e];
        free.push_back(k);
      }
      for (pk::GradientRoute route : {pk::GradientRoute::kForward, pk::GradientRoute::kAdjoint}) {
        const auto ea = a.Evaluate(values, free, pk::Objective::Need::kGradient, route);
        const auto eb = b.Evaluate(values, free, pk::Objective::Need::kGradient, route);
        REQUIRE(ea.ok);
        REQUIRE(eb.ok);
        CHECK(MaxRel(ea.predictions, eb.predictions) < (ode ? 1e-7 : 1e-10));
        CHECK(MaxRel(ea.gradient, eb.gradient) < (ode ? 1e-7 : 1e-10));
      }
    }
  }
}

namespace {

// A valid model, and the same with one line replaced: the errors below each break one thing.
const char* const kBase =
    "$PROBLEM base  a test model\n"  // 1
    "$PARAM\n"                        // 2
    "KA = 1.5  1/h\n"                 // 3
    "CL = 3\n"                        // 4
    "V = 30\n"                        // 5
    "$CMT\n"                          // 6
    "DEPOT dose\n"                    // 7
    "CENTRAL central\n"               // 8
    "$PK\n"                           // 9
    "K = CL / V\n"                    // 10
    "$ODE\n"                          // 11
    "d/dt(DEPOT) = -KA * DEPOT\n"     // 12
    "d/dt(CENTRAL) = KA * DEPOT - K * CENTRAL\n"  // 13
    "$OUTPUT\n"                       // 14
    "CP = CENTRAL / V\n";             // 15

std::string Replace(int line, const std::string& text) {
  std::istringstream in(kBase);
  std::string out, l;
  for (int k = 1; std::getline(in, l); ++k) out += (k == line ? text : l) + "\n";
  return out;
}

struct ErrorCase {
  const char* kind;
  std::string text;
  const char* message;
  int line, column;
};

}  // namespace

TEST_CASE("model files: the base model of the error cases is valid and linear", "[model_file]") {
  const auto m = pk::ParseModel(kBase, "base.pkm");
  CHECK(dynamic_cast<const pk::LinearModel*>(m.get()) != nullptr);
  CHECK(m->declarations().parameters[0].unit == "1/h");
}

TEST_CASE("model files: each kind of error names the file, line and column and what was expected", "[model_file]") {
  const std::vector<ErrorCase> cases = {
      {"unknown name", Replace(13, "d/dt(CENTRAL) = KA * DEPOT - KE * CENTRAL"), "reads KE, which is not defined (did you mean K?)", 13, 30},
      {"output reads an undefined symbol", Replace(15, "CP = CENTRAL / VC"), "output CP reads VC, which is not defined", 15, 16},
      {"cyclic definition", Replace(10, "K = CL / V * K2\nK2 = K"), "cyclic definition: K → K2 → K", 11, 6},
      {"division always by zero", Replace(10, "K = CL / (V - V + 0 * 2)"), "", 0, 0},
      {"division by a zero constant", Replace(10, "K = CL / (2 - 2)"), "division by zero: the denominator is always 0", 10, 8},
      {"compartment without an equation", Replace(12, ""), "compartment DEPOT has no equation", 7, 1},
      {"derivative of an unknown compartment", Replace(12, "d/dt(DEPT) = -KA * DEPOT"), "DEPT is not a compartment (did you mean DEPOT?)", 12, 1},
      {"derivative given twice", Replace(13, "d/dt(DEPOT) = 0"), "d/dt(DEPOT) is given twice (first on line 12)", 13, 1},
      {"name declared twice", Replace(10, "KA = CL / V"), "KA is declared twice", 10, 1},
      {"unknown function", Replace(10, "K = CL / sqr(V)"), "unknown function 'sqr' (did you mean sqrt?)", 10, 10},
      {"wrong number of arguments", Replace(10, "K = CL / pow(V)"), "pow() takes 2 arguments, not 1", 10, 10},
      {"unknown block", Replace(9, "$PKX"), "unknown block $PKX", 9, 1},
      {"statement before any block", std::string("K = 1\n") + kBase, "expected a block heading", 1, 1},
      {"syntax: missing operand", Replace(10, "K = CL / "), "expected a number, a name or '(', found the end of the line", 10, 10},
      {"syntax: unbalanced parenthesis", Replace(10, "K = (CL / V"), "expected ')'", 0, 0},
      {"assignment in a comparison", Replace(10, "K = ifelse(CL = 2, 1, 2)"), "write '==' to compare", 10, 15},
      {"unexpected character", Replace(10, "K = CL @ V"), "unexpected character '@'", 10, 8},
      {"malformed number", Replace(4, "CL = 3.5.1"), "", 4, 0},
      {"$PK reads a state", Replace(10, "K = CL / V + DEPOT"), "K in $PK reads the amount in DEPOT", 10, 1},
      {"unused parameter", Replace(5, "V = 30\nQ = 4"), "parameter Q is never used", 6, 1},
      {"reserved name TIME", Replace(10, "K = CL / V * TIME"), "TIME is reserved", 0, 0},
      {"bounds the wrong way round", Replace(4, "CL = 3 (10, 1)"), "the lower bound 10 is not below the upper bound 1", 4, 1},
      {"initial value outside its bounds", Replace(4, "CL = 30 (0, 10)"), "must lie strictly within its bounds", 4, 1},
      {"a parameter that must be positive", Replace(4, "CL = -3"), "CL must be positive", 4, 1},
      {"if without else", Replace(10, "if (CL > 2) {\n  K = CL / V\n}"), "K is assigned when the condition holds but not otherwise (add an else)", 10, 1},
      {"modifier of a missing compartment", Replace(5, "V = 30\nF3 = 0.5"), "F3 modifies compartment 3, but the model has 2 compartments", 6, 1},
      {"expression for a dose modifier", Replace(10, "K = CL / V\nALAG1 = 0.5 * K"), "ALAG1 is a dose modifier", 11, 1},
      {"unknown error model", std::string(kBase) + "$ERROR\nCP ~ lognormal\n", "$ERROR: unknown error model 'lognormal'", 17, 1},
      {"error for an unknown output", std::string(kBase) + "$ERROR\nCC ~ additive\n", "CC is not an output", 17, 1},
      {"wrong number of σ", std::string(kBase) + "$ERROR\nCP ~ combined(0.1)\n", "combined takes 2 σ", 17, 1},
      {"two central compartments", Replace(7, "DEPOT dose central"), "only one compartment can be the central compartment", 8, 1},
      {"unknown compartment attribute", Replace(7, "DEPOT oral"), "unknown compartment attribute 'oral'", 7, 7},
      {"no outputs", Replace(15, ""), "declares no outputs", 1, 1},
      {"no $PROBLEM", Replace(1, ""), "has no $PROBLEM line", 1, 1},
      {"log of a non-positive constant", Replace(10, "K = CL / V * log(0)"), "log of 0", 10, 14},
      {"random effect never used", Replace(5, "V = 30\n$OMEGA\nETA_V ~ 0.1\n$PARAM"), "random effect ETA_V is never used", 7, 1},
      {"variance not positive", Replace(5, "V = 30\n$OMEGA\nETA_V ~ 0\n$PARAM"), "the variance ω² of ETA_V must be positive", 7, 1},
      {"a σ name taken", Replace(5, "V = 30\nSIGMA_ADD = 1"), "SIGMA_ADD is the name of a residual-error σ", 6, 1},
  };
  int checked = 0;
  for (const ErrorCase& c : cases) {
    INFO(c.kind << "\n" << c.text);
    try {
      pk::ParseModel(c.text, "bad.pkm");
      FAIL("no error");
    } catch (const pk::InputError& e) {
      INFO(e.what());
      CHECK(e.file() == "bad.pkm");
      CHECK(e.line() > 0);
      if (c.line > 0) CHECK(e.line() == c.line);
      if (c.column > 0) CHECK(e.column() == c.column);
      CHECK_THAT(e.message(), Catch::Contains(c.message));
      ++checked;
    }
  }
  CHECK(checked >= 20);
}
