// Model files (pk/model_file.h): every shipped file against its catalogue twin on every bundled
// dataset and event type, every gradient route against finite differences, covariates and
// if/else, and the errors a model file can have, each with its line and column.

#include <catch2/catch.hpp>

#include <algorithm>
#include <cctype>
#include <clocale>
#include <cstdlib>
#include <fstream>
#include <iterator>
#include <map>
#include <sstream>

#include "events.h"
#include "pk/catalogue.h"
#include "pk/error.h"
#include "pk/fit_subjects.h"
#include "pk/linear_model.h"
#include "pk/model_file.h"
#include "pk/objective.h"
#include "pk/ode_model.h"
#include "pk/parameters.h"
#include "pk/units.h"
#include "test_util.h"

namespace {

std::string ModelPath(const std::string& name) { return std::string(PK_SOURCE_DIR) + "/models/" + name + ".pkm"; }

// `o` on CVODES at rtol 1e-12 (atol 1e-14): the integrated reference of an exact route.
pk::ObjectiveOptions CvodesTwin(pk::ObjectiveOptions o) {
  o.propagator = pk::Propagator::kOde;
  o.ode.relative_tolerance = 1e-12;
  o.ode.absolute_tolerance = 1e-14;
  return o;
}

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
      // A linear catalogue model reads no DVID; its file twin refuses a DVID beyond its outputs.
      const int dvid = data->ExtraColumn("DVID");
      bool other_output = false;
      for (const pk::Record& r : data->subjects[static_cast<size_t>(i)].records) {
        other_output = other_output || (dvid >= 0 && r.IsSample() && r.extra[dvid] > file->num_outputs());
      }
      if (!catalogue_takes) {
        CHECK_THROWS_AS(pk::Objective(file, data, i, pk::ObjectiveOptions()), pk::InputError);
        continue;
      }
      auto compared_data = data;
      if (other_output && catalogue->num_outputs() == 0) {  // compared on the file's outputs alone
        CHECK_THROWS_AS(pk::Objective(file, data, i, pk::ObjectiveOptions()), pk::InputError);
        compared_data = std::make_shared<pk::Dataset>(*data);
        auto& records = compared_data->subjects[static_cast<size_t>(i)].records;
        records.erase(std::remove_if(records.begin(), records.end(),
                                     [&](const pk::Record& r) { return r.IsSample() && r.extra[dvid] > file->num_outputs(); }),
                      records.end());
      }
      // An observation in a compartment other than the central one measures its amount in a model
      // file, and a concentration (or, in tf<n>, the output) in the catalogue: not twins there.
      bool elsewhere = false;
      for (const pk::Record& r : data->subjects[static_cast<size_t>(i)].records) {
        elsewhere = elsewhere || (r.evid == pk::Evid::kObservation && r.cmt > 0 && r.cmt != catalogue->central_compartment());
      }
      if (elsewhere) continue;
      CompareTwins(catalogue, file, compared_data, i, tolerance, routes);
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

TEST_CASE("model files: identifiers are ASCII under a locale whose isalpha takes Latin letters", "[model_file][locale]") {
  // tests/cli/test_locale.sh runs this under tr_TR.ISO-8859-9, where isalpha(0xE7) ('ç') is true: a
  // name with that byte must be the same error there as in the C locale, at its line and column.
  const char* turkish = std::getenv("PK_TEST_DOTTED_I_LOCALE");
  const pk_test::LocaleGuard locale(turkish);
  if (turkish != nullptr) {
    REQUIRE(locale.set());
    REQUIRE(std::isalpha(0xE7));
  }
  std::string text = kBase;
  const size_t k = text.find("K = CL / V");
  REQUIRE(k != std::string::npos);
  text.insert(k + 1, "\xE7");
  try {
    pk::ParseModel(text, "latin.pkm");
    FAIL("a name with a byte that is not ASCII was accepted");
  } catch (const pk::InputError& e) {
    CHECK_THAT(e.what(), Catch::StartsWith("latin.pkm:10:2:"));
  }
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
      {"a dose modifier computed outside $PK", Replace(13, "d/dt(CENTRAL) = KA * DEPOT - K * CENTRAL\nALAG1 = 0.5 * K"),
       "ALAG1 is a dose modifier: compute it in $PK", 14, 1},
      {"a computed modifier of a missing compartment", Replace(10, "K = CL / V\nF3 = 0.5"),
       "F3 modifies compartment 3, but the model has 2 compartments", 11, 1},
      {"a modifier both declared and computed", Replace(5, "V = 30\nF1 = 0.5\n$PK\nF1 = 0.9 * KA / 1.5"),
       "F1 is declared twice", 8, 1},
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
      {"a block with the wrong number of values", Replace(5, "V = 30\n$OMEGA\nETA_V + ETA_K ~ c(0.1, 0.01)\n$PARAM"),
       "a block of 2 random effects needs 3 values (the lower triangle by rows", 7, 1},
      {"a block that is not positive definite", Replace(5, "V = 30\n$OMEGA\nETA_V + ETA_K ~ c(0.1, 0.5, 0.1)\n$PARAM"),
       "the block of ETA_V, ETA_K is not positive definite", 7, 1},
      {"a block without its values", Replace(5, "V = 30\n$OMEGA\nETA_V + ETA_K ~ 0.1\n$PARAM"),
       "expected the block's values", 7, 17},
      {"a word after a variance", Replace(5, "V = 30\n$OMEGA\nETA_V ~ 0.1 FIXD\n$PARAM"),
       "expected FIX or the end of the line, found 'FIXD'", 7, 13},
      {"SAME with no block before it", Replace(5, "V = 30\n$OMEGA\nETA_V ~ SAME\n$PARAM"),
       "SAME repeats the $OMEGA line before it, and there is none", 7, 9},
      {"SAME over another number of η", Replace(5, "V = 30\n$OMEGA\nETA_V ~ 0.1\nETA_K + ETA_C ~ SAME\n$PARAM"),
       "SAME repeats the block before it, of 1 random effect, so this line needs as many, not 2", 8, 17},
      {"a word after SAME", Replace(5, "V = 30\n$OMEGA\nETA_V ~ 0.1\nETA_K ~ SAME FIX\n$PARAM"),
       "expected the end of the line after SAME, found 'FIX'", 8, 14},
      {"a σ name taken", Replace(5, "V = 30\nSIGMA_ADD = 1"), "SIGMA_ADD is the name of a residual-error σ", 6, 1},
      {"$INIT of an unknown compartment", std::string(kBase) + "$INIT\nCENTRL = 1\n",
       "the initial amount of CENTRL is set, but it is not a compartment (the compartments are DEPOT, CENTRAL)", 17, 1},
      {"a compartment set twice in $INIT", std::string(kBase) + "$INIT\nCENTRAL = 1, CENTRAL = 2\n",
       "the initial amount of CENTRAL is set twice: here and at line 17", 17, 14},
      {"CMT(0) in $PK and in $INIT", Replace(10, "K = CL / V\nCENTRAL(0) = 1") + "$INIT\nCENTRAL = 2\n",
       "the initial amount of CENTRAL is set twice: here and at line 11", 18, 1},
      {"an initial amount in $INIT and as X0_n", Replace(10, "K = CL / V\nX0_2 = 1") + "$INIT\nCENTRAL = 2\n",
       "the initial amount of CENTRAL is given twice: here and as X0_2 at line 11", 18, 1},
      {"an initial amount in $INIT and in $PARAM", Replace(5, "V = 30\nX0_2 = 1") + "$INIT\nCENTRAL = 2\n",
       "the initial amount of CENTRAL is given twice: here and as X0_2 in $PARAM at line 6", 18, 1},
      {"$INIT reads an amount", std::string(kBase) + "$INIT\nCENTRAL = DEPOT / 2\n",
       "the initial amount of CENTRAL reads the amount in DEPOT", 17, 1},
      {"CMT(0) in $ODE", Replace(13, "d/dt(CENTRAL) = KA * DEPOT - K * CENTRAL\nCENTRAL(0) = 1"),
       "an initial amount, CENTRAL(0), belongs in $PK or $INIT, not in $ODE", 14, 1},
      {"$INIT before the $PK CMT(0) it repeats", Replace(9, "$INIT\nCENTRAL = 2\n$PK\nCENTRAL(0) = 1"),
       "the initial amount of CENTRAL is set twice: here and at line 10", 12, 1},
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

namespace {

const char* const kShipped[] = {"1cmt_iv", "1cmt_oral", "2cmt_iv", "2cmt_oral", "3cmt_iv", "3cmt_oral",
                                "1cmt_oral_transit", "tf1", "tf2", "tf3", "tf4", "1cmt_iv_mm", "1cmt_oral_mm",
                                "2cmt_iv_mm", "1cmt_iv_emax", "1cmt_iv_parallel", "idr1", "idr2", "idr3", "idr4",
                                "turnover", "parent_metabolite", "emax_baseline", "effect_linear"};

// The regimen of tests/reference/make_pd_reference.R: 100 at 0, 50 at rate 25 from 12; samples of
// every output at `times`.
std::shared_ptr<pk::Dataset> ReferenceRegimen(int outputs) {
  std::ostringstream csv;
  csv << "ID,TIME,AMT,RATE,EVID,DVID,DV\n1,0,100,0,1,.,.\n";
  const double times[] = {0.5, 1, 2, 4, 8, 12, 12.5, 13, 14, 16, 24, 36};
  for (double t : times) {
    if (t == 12) {
      csv << "1,12,50,25,1,.,.\n";
      continue;
    }
    for (int j = 1; j <= outputs; ++j) csv << "1," << t << ",0,0,0," << j << "," << 1 + 0.3 * j + 0.01 * t << "\n";
  }
  return std::make_shared<pk::Dataset>(pk::ParseDataset(csv.str(), "regimen.csv"));
}

int Outputs(const pk::Model& m) { return std::max(1, m.num_outputs()); }

}  // namespace

TEST_CASE("model files: the new models equal R deSolve's solution of their equations", "[model_file][reference]") {
  std::ifstream in(std::string(PK_SOURCE_DIR) + "/tests/reference/pd_reference.csv");
  REQUIRE(in);
  std::map<std::string, std::vector<double>> reference;  // per model, in (time, DVID) order
  std::string line;
  std::getline(in, line);
  while (std::getline(in, line)) {
    const size_t comma = line.find(',');
    reference[line.substr(0, comma)].push_back(std::stod(line.substr(line.rfind(',') + 1)));
  }
  REQUIRE(reference.size() == 9);
  for (const auto& kv : reference) {
    INFO(kv.first);
    const auto model = pk::LoadModelFile(ModelPath(kv.first));
    pk::ObjectiveOptions options;
    options.ode.relative_tolerance = 1e-11;
    options.ode.absolute_tolerance = 1e-12;
    const pk::Objective objective(model, ReferenceRegimen(Outputs(*model)), 0, options);
    const auto e = objective.Evaluate(objective.DefaultValues(), {}, pk::Objective::Need::kValue);
    REQUIRE(e.ok);
    REQUIRE(static_cast<size_t>(e.predictions.size()) == kv.second.size());
    for (size_t k = 0; k < kv.second.size(); ++k) {
      INFO("sample " << k);
      CHECK(pk_test::RelDiff(e.predictions(static_cast<Eigen::Index>(k)), kv.second[k], 1e-6) < 1e-7);
    }
  }
}

TEST_CASE("model files: every gradient route agrees with central differences on every shipped file",
          "[model_file][gradient]") {
  for (const char* name : kShipped) {
    const auto model = pk::LoadModelFile(ModelPath(name));
    for (const char* error : {"least-squares", "proportional"}) {
      INFO(name << " / " << error);
      pk::ObjectiveOptions options;
      options.error_model = pk::MakeResidualError(error);
      options.ode.relative_tolerance = 1e-10;
      options.ode.absolute_tolerance = 1e-12;
      const pk::Objective objective(model, ReferenceRegimen(Outputs(*model)), 0, options);
      Eigen::VectorXd values = objective.DefaultValues();
      std::vector<int> free;
      for (int k = 0; k < model->num_parameters(); ++k) {
        values(k) *= 1.0 + 0.05 * k;
        free.push_back(k);
      }
      for (int k : objective.sigma_indices()) free.push_back(k);
      using Route = pk::GradientRoute;
      // Differences of order four on an objective integrated at rtol 1e-12 (exact: to rounding).
      pk::ObjectiveOptions tight = options;
      tight.ode.relative_tolerance = 1e-12;
      tight.ode.absolute_tolerance = 1e-14;
      const Eigen::VectorXd fd =
          pk_test::CentralDifferences(pk::Objective(model, ReferenceRegimen(Outputs(*model)), 0, tight), values, free);
      const double scale = fd.cwiseAbs().maxCoeff();
      REQUIRE(scale > 0);
      for (Route route : {Route::kForward, Route::kAdjoint}) {
        const auto g = objective.Evaluate(values, free, pk::Objective::Need::kGradient, route);
        REQUIRE(g.ok);
        INFO(pk::ToString(route) << " " << g.gradient.transpose() << "\nfd " << fd.transpose());
        CHECK((g.gradient - fd).cwiseAbs().maxCoeff() / scale < 1e-6);
      }
    }
  }
}

TEST_CASE("model files: covariates are dataset columns, time-varying, with if/else", "[model_file]") {
  const char* text =
      "$PROBLEM allometric  1cmt IV with weight and sex on clearance\n"
      "$PARAM\nTVCL = 3 (0, 100) L/h\nV = 30 L\n"
      "$COVARIATE\nWT kg\nSEX\n"
      "$OMEGA\nETA_CL ~ 0.09\n"
      "$CMT\nCENTRAL dose central\n"
      "$PK\n"
      "if (SEX == 1) {\n  FSEX = 1.25\n} else {\n  FSEX = 1\n}\n"
      "CL = TVCL * FSEX * (WT / 70)^0.75 * exp(ETA_CL)\n"
      "$ODE\nd/dt(CENTRAL) = -CL / V * CENTRAL\n"
      "$OUTPUT\nCP = CENTRAL / V\n";
  const auto file = pk::ParseModel(text, "allometric.pkm");
  // (WT/70)^0.75 is not a ratio of parameters, but the right-hand side is linear in the amount:
  // −CL/V is a derived coefficient and the model runs on Φ/Γ.
  REQUIRE(file->is_linear());
  CHECK(pk::WhyNotLinear(*file).empty());
  CHECK(file->is_covariate(file->ParameterIndex("WT")));
  CHECK_FALSE(file->is_covariate(file->ParameterIndex("TVCL")));
  CHECK(file->ParameterIndex("ETA_CL") < 0);  // η = 0 in an individual model
  // The weight changes at t = 5; the catalogue's 1cmt_iv gets the clearance as a column instead.
  const double tvcl = 2.6;
  auto cl = [&](double wt, int sex) { return tvcl * (sex == 1 ? 1.25 : 1.0) * std::pow(wt / 70, 0.75); };
  for (int sex : {0, 1}) {
    std::ostringstream a, b;
    a << "ID,TIME,AMT,DV,WT,SEX\n";
    b << "ID,TIME,AMT,DV,CL\n";
    b.precision(17);
    const double rows[][3] = {{0, 100, 60}, {1, 0, 60}, {3, 0, 60}, {5, 0, 80}, {8, 0, 80}, {12, 0, 80}};
    for (const auto& r : rows) {
      a << "1," << r[0] << "," << r[1] << "," << (r[1] > 0 ? "." : "1") << "," << r[2] << "," << sex << "\n";
      b << "1," << r[0] << "," << r[1] << "," << (r[1] > 0 ? "." : "1") << "," << cl(r[2], sex) << "\n";
    }
    pk::ObjectiveOptions options;
    options.ode.relative_tolerance = 1e-11;
    options.ode.absolute_tolerance = 1e-12;
    const pk::Objective fo(file, std::make_shared<pk::Dataset>(pk::ParseDataset(a.str(), "a.csv")), 0, options);
    const pk::Objective co(pk::MakeModel("1cmt_iv"), std::make_shared<pk::Dataset>(pk::ParseDataset(b.str(), "b.csv")),
                           0, options);
    Eigen::VectorXd fv = fo.DefaultValues(), cv = co.DefaultValues();
    fv(fo.ParameterIndex("TVCL")) = tvcl;
    const auto ef = fo.Evaluate(fv, {fo.ParameterIndex("V")}, pk::Objective::Need::kGradient);
    const auto ec = co.Evaluate(cv, {co.ParameterIndex("V")}, pk::Objective::Need::kGradient);
    REQUIRE(ef.ok);
    REQUIRE(ec.ok);
    INFO("sex " << sex << "\nfile " << ef.predictions.transpose() << "\ncatalogue " << ec.predictions.transpose());
    CHECK(MaxRel(ef.predictions, ec.predictions) < 1e-12);
    CHECK(MaxRel(ef.gradient, ec.gradient) < 1e-11);
  }
  // A dataset without the covariate's column: named at the header.
  const auto data = std::make_shared<pk::Dataset>(pk::ParseDataset("ID,TIME,AMT,DV,SEX\n1,0,100,.,0\n1,1,0,1,0\n", "nowt.csv"));
  CHECK_THROWS_WITH(pk::Objective(file, data, 0, pk::ObjectiveOptions()), Catch::Contains("no column WT"));
}

TEST_CASE("model files: linear models whose coefficients are expressions run on Φ/Γ with exact gradients",
          "[model_file][gradient]") {
  // Allometric clearance and central volume, a sex factor by if/else, covariates changing over time:
  // no entry of A or C is c·θa/θb, so each becomes a derived coefficient ψ(θ) whose derivatives come
  // from AD of the file's expressions. The same equations on CVODES at rtol 1e-12 and central
  // differences check the exact route, with and without eigen-coordinates (modal propagation).
  const char* text =
      "$PROBLEM allometric2  two compartments, oral, allometric\n"
      "$PARAM\nKA = 1.1\nTVCL = 3\nTVV1 = 20\nQ = 2\nV2 = 40\n"
      "$COVARIATE\nWT kg\nSEX\n"
      "$CMT\nDEPOT dose\nCENTRAL central\nPERIPH\n"
      "$PK\nif (SEX == 1) {\n  FSEX = 1.25\n} else {\n  FSEX = 1\n}\n"
      "CL = TVCL * FSEX * (WT / 70)^0.75\nV1 = TVV1 * WT / 70\n"
      "$ODE\nd/dt(DEPOT) = -KA * DEPOT\n"
      "d/dt(CENTRAL) = KA * DEPOT - (CL + Q) / V1 * CENTRAL + Q / V2 * PERIPH\n"
      "d/dt(PERIPH) = Q / V1 * CENTRAL - Q / V2 * PERIPH\n"
      "$OUTPUT\nCP = CENTRAL / V1\n";
  const auto model = pk::ParseModel(text, "allometric2.pkm");
  const auto* linear = dynamic_cast<const pk::LinearModel*>(model.get());
  REQUIRE(linear != nullptr);
  CHECK(linear->derived_coefficients().count >= 3);  // (CL+Q)/V1, Q/V1 and 1/V1 at least
  const auto data = std::make_shared<pk::Dataset>(pk::ParseDataset(
      "ID,TIME,AMT,DV,WT,SEX\n"
      "1,0,100,.,60,1\n1,0.5,0,2.1,60,1\n1,2,0,2.9,60,1\n1,6,0,1.7,75,1\n1,12,100,.,75,1\n1,13,0,3.8,75,1\n"
      "1,24,0,1.2,80,1\n"
      "2,0,80,.,90,0\n2,1,0,1.3,90,0\n2,4,0,1.1,90,0\n2,8,0,0.7,90,0\n",
      "allometric2.csv"));
  for (int subject : {0, 1}) {
    pk::ObjectiveOptions exact;
    exact.error_model = pk::MakeResidualError("proportional");
    const pk::ObjectiveOptions ode = CvodesTwin(exact);
    const pk::Objective objective(model, data, subject, exact);
    const pk::Objective reference(model, data, subject, ode);
    Eigen::VectorXd values = objective.DefaultValues();
    std::vector<int> free;
    for (const char* name : {"KA", "TVCL", "TVV1", "Q", "V2"}) free.push_back(objective.ParameterIndex(name));
    for (int k : objective.sigma_indices()) free.push_back(k);
    const auto want = reference.Evaluate(values, free, pk::Objective::Need::kGradient, pk::GradientRoute::kForward);
    REQUIRE(want.ok);
    const Eigen::VectorXd fd = pk_test::CentralDifferences(objective, values, free);
    for (bool modal : {true, false}) {
      pk::ObjectiveOptions o = exact;
      o.modal_propagation = modal;
      const pk::Objective route(model, data, subject, o);
      for (pk::GradientRoute r : {pk::GradientRoute::kForward, pk::GradientRoute::kAdjoint}) {
        const auto got = route.Evaluate(values, free, pk::Objective::Need::kGradient, r);
        INFO("subject " << subject << ", modal " << modal << ", " << pk::ToString(r) << "\n"
                        << got.gradient.transpose() << "\node " << want.gradient.transpose() << "\nfd  "
                        << fd.transpose());
        REQUIRE(got.ok);
        CHECK(std::string(got.propagator) == "exact");
        CHECK(got.modal == modal);  // eigen-coordinates ran when asked
        CHECK(MaxRel(got.predictions, want.predictions) < 1e-9);
        CHECK(MaxRel(got.gradient, want.gradient) < 1e-8);
        CHECK(MaxRel(got.gradient, fd) < 1e-6);
      }
    }
  }
}

namespace {

// A scenario's doses, and samples of both outputs (DVID 1 and 2) at each time.
std::shared_ptr<pk::Dataset> TwoOutputData(const pk_test::Scenario& sc) {
  std::ostringstream csv;
  csv << "ID,TIME,AMT,RATE,II,ADDL,SS,EVID,DV,DVID\n";
  std::vector<std::pair<double, std::string>> rows;
  std::istringstream doses(sc.doses);
  for (std::string line; std::getline(doses, line);) rows.push_back({std::stod(line.substr(2)), line + ",."});
  const double times[] = {0.25, 0.9, 1.7, 3.1, 5.3, 7.9, 11.2, 15.5, 23.6};
  for (int k = 0; k < 9; ++k) {
    for (int dvid : {1, 2}) {
      std::ostringstream row;
      row << "1," << times[k] << ",0,0,0,0,0,0," << 0.5 + 0.3 * dvid + 0.1 * k << "," << dvid;
      rows.push_back({times[k], row.str()});
    }
  }
  std::stable_sort(rows.begin(), rows.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
  for (const auto& r : rows) csv << r.second << "\n";
  return std::make_shared<pk::Dataset>(pk::ParseDataset(csv.str(), sc.name));
}

// A linear file with two outputs (DVID 1 and 2), each with its own combined σ, on every event type:
// the exact route (with and without eigen-coordinates, forward and adjoint) against the same
// equations integrated by CVODES at rtol 1e-12, and against central differences of its own objective.
void CheckTwoOutputFile(const std::shared_ptr<const pk::Model>& model, const std::vector<std::string>& outputs) {
  INFO(pk::WhyNotLinear(*model));
  REQUIRE(dynamic_cast<const pk::LinearModel*>(model.get()) != nullptr);
  REQUIRE(model->output_names() == outputs);
  const auto error =
      pk::MakePerOutputError({pk::MakeResidualError("combined"), pk::MakeResidualError("combined")}, outputs);
  for (const pk_test::Scenario& sc : pk_test::OdeScenarios()) {
    INFO(sc.name);
    const auto data = TwoOutputData(sc);
    pk::ObjectiveOptions exact;
    exact.error_model = error;
    const pk::ObjectiveOptions ode = CvodesTwin(exact);
    const pk::Objective objective(model, data, 0, exact), reference(model, data, 0, ode);
    CHECK(objective.sample_outputs() == std::vector<int>{1, 2, 1, 2, 1, 2, 1, 2, 1, 2, 1, 2, 1, 2, 1, 2, 1, 2});
    Eigen::VectorXd values = objective.DefaultValues();
    std::vector<int> free;
    for (int k = 0; k < model->num_parameters(); ++k) free.push_back(k);
    for (size_t e = 0; e < sc.extra_free.size(); ++e) {
      const int k = objective.ParameterIndex(sc.extra_free[e]);
      values(k) = sc.extra_values[e];
      free.push_back(k);
    }
    for (int k : objective.sigma_indices()) {
      values(k) = 0.1 + 0.05 * k;
      free.push_back(k);
    }
    const auto want = reference.Evaluate(values, free, pk::Objective::Need::kGradient, pk::GradientRoute::kForward);
    REQUIRE(want.ok);
    CHECK(std::string(want.propagator) == "ode");
    // The second output's samples are not the first's: the two differ at every time with drug.
    for (Eigen::Index j = 0; j + 1 < want.predictions.size(); j += 2) {
      if (want.predictions(j) == 0) continue;  // before a lagged first dose
      CHECK(std::fabs(want.predictions(j) - want.predictions(j + 1)) > 1e-6 * std::fabs(want.predictions(j)));
    }
    const Eigen::VectorXd fd = pk_test::CentralDifferences(objective, values, free);
    for (bool modal : {true, false}) {
      pk::ObjectiveOptions o = exact;
      o.modal_propagation = modal;
      const pk::Objective route(model, data, 0, o);
      for (pk::GradientRoute r : {pk::GradientRoute::kForward, pk::GradientRoute::kAdjoint}) {
        const auto got = route.Evaluate(values, free, pk::Objective::Need::kGradient, r);
        INFO("modal " << modal << ", " << pk::ToString(r) << "\n" << got.gradient.transpose() << "\node "
                      << want.gradient.transpose() << "\nfd  " << fd.transpose());
        REQUIRE(got.ok);
        CHECK(std::string(got.propagator) == "exact");
        CHECK(MaxRel(got.predictions, want.predictions) < 1e-9);
        CHECK(MaxRel(got.gradient, want.gradient) < 1e-8);
        CHECK(MaxRel(got.gradient, fd) < 1e-6);
      }
    }
  }
}

}  // namespace

TEST_CASE("model files: a linear model with two outputs runs on Φ/Γ, its samples chosen by DVID",
          "[model_file][gradient]") {
  // parent_metabolite: CP (DVID 1) and CPM (DVID 2).
  const auto model = pk::LoadModelFile(ModelPath("parent_metabolite"));
  CheckTwoOutputFile(model, {"CP", "CPM"});
  // A DVID the model does not have names the file, line and column, and the outputs.
  const auto bad = std::make_shared<pk::Dataset>(pk::ParseDataset(
      "ID,TIME,AMT,DV,DVID\n1,0,100,.,.\n1,1,0,2,1\n1,2,0,1,3\n", "three.csv"));
  try {
    pk::Objective(model, bad, 0, pk::ObjectiveOptions());
    FAIL("DVID 3 was accepted");
  } catch (const pk::InputError& e) {
    CHECK(e.file() == "three.csv");
    CHECK(e.line() == 4);
    CHECK(e.column() == 5);
    CHECK_THAT(e.message(), Catch::Contains("DVID 3") && Catch::Contains("1=CP, 2=CPM"));
  }
}

TEST_CASE("model files: an output with a baseline runs on Φ/Γ, its offset with every derivative",
          "[model_file][gradient]") {
  // effect_linear: CP (DVID 1) and E = E0 + SLOPE·CE (DVID 2), whose E0 is the output's offset d(θ).
  const auto model = pk::LoadModelFile(ModelPath("effect_linear"));
  const auto* linear = dynamic_cast<const pk::LinearModel*>(model.get());
  REQUIRE(linear != nullptr);
  CHECK(linear->has_output_offsets());
  CHECK(linear->output_offset_terms(model->num_compartments() + 1).empty());  // CP
  // E0 is a parameter term of the offset, not a derived coefficient: the model has none.
  const auto& baseline = linear->output_offset_terms(model->num_compartments() + 2);
  REQUIRE(baseline.size() == 1);
  CHECK(baseline[0].numerator == 3);  // E0
  CHECK(baseline[0].denominator == -1);
  CHECK(linear->derived_coefficients().count == 0);
  CheckTwoOutputFile(model, {"CP", "E"});
  // Baselines written other ways are offsets too, each equal to its integrated twin: under a negation,
  // an if/else on a covariate, a product with the response, and a quotient. An output that reads no
  // amount keeps the model on the ODE routes, and says so.
  const std::string base = "$PROBLEM b  forms of a baseline\n$PARAM\nCL = 3\nV = 30\nKE0 = 0.5\nE0 = 10\nS = 4\n"
                           "$COVARIATE\nWT kg\n$CMT\nCENTRAL dose central\nEFFECT\n$ODE\nC = CENTRAL / V\n"
                           "d/dt(CENTRAL) = -CL * WT / 70 * C\nd/dt(EFFECT) = KE0 * (C - EFFECT)\n$OUTPUT\nCP = C\nE = ";
  const auto wt_data = std::make_shared<pk::Dataset>(pk::ParseDataset(
      "ID,TIME,AMT,DVID,DV,WT\n1,0,100,.,.,60\n1,1,0,2,12,60\n1,3,0,2,15,80\n1,6,0,1,2,80\n1,6,0,2,16,80\n"
      "1,12,0,2,13,90\n",
      "wt.csv"));
  for (const char* e : {"-(-E0 - S * EFFECT)", "ifelse(WT > 70, E0 * WT / 70 + S * EFFECT, E0 + S * EFFECT)",
                        "E0 * (1 + S * EFFECT)", "(E0 * V + S * EFFECT * V) / V"}) {
    INFO(e);
    const auto form = pk::ParseModel(base + e + "\n", "b.pkm");
    const auto* lf = dynamic_cast<const pk::LinearModel*>(form.get());
    INFO(pk::WhyNotLinear(*form));
    REQUIRE(lf != nullptr);
    CHECK(lf->has_output_offsets());
    pk::ObjectiveOptions o;
    o.error_model = pk::MakeResidualError("proportional");
    const pk::ObjectiveOptions integrated = CvodesTwin(o);
    const pk::Objective exact(form, wt_data, 0, o), ode(form, wt_data, 0, integrated);
    std::vector<int> free = {0, 1, 2, 3, 4};
    for (int k : exact.sigma_indices()) free.push_back(k);
    const Eigen::VectorXd values = exact.DefaultValues();
    const auto a = exact.Evaluate(values, free, pk::Objective::Need::kGradient, pk::GradientRoute::kAdjoint);
    const auto b = ode.Evaluate(values, free, pk::Objective::Need::kGradient, pk::GradientRoute::kForward);
    REQUIRE((a.ok && b.ok));
    CHECK(MaxRel(a.predictions, b.predictions) < 1e-9);
    CHECK(MaxRel(a.gradient, b.gradient) < 1e-7);
  }
  const auto none = pk::ParseModel(base + "E0 * S\n", "none.pkm");
  CHECK(dynamic_cast<const pk::OdeModel*>(none.get()) != nullptr);
  CHECK_THAT(pk::WhyNotLinear(*none), Catch::Contains("output E reads no amount"));
  // A bolus of 100 at 0: E = E0 + SLOPE·Ce with Ce = (D/V)·KE0/(KE0 − k)·(e^{−kt} − e^{−KE0·t}), k = CL/V;
  // and, in the exogenous turnover (its central output CP = (KIN/KOUT + A)/V has the offset), the
  // AUC adds KIN/KOUT/V·t: AUC = (KIN/KOUT·t + 100/KOUT·(1 − e^{−KOUT·t}))/V.
  const double cl = 3, v = 30, ke0 = 0.5, e0 = 10, slope = 4, k = cl / v;
  const double kin = 10, kout = 0.5, vt = 20;
  const auto turnover = pk::ParseModel(
      "$PROBLEM turnover_exo  the exogenous part as the state\n$PARAM\nKIN = 10\nKOUT = 0.5\nV = 20\n"
      "$CMT\nEXOGENOUS  dose central\n$ODE\nd/dt(EXOGENOUS) = -KOUT * EXOGENOUS\n"
      "$OUTPUT\nCP = (KIN / KOUT + EXOGENOUS) / V\n",
      "turnover_exo.pkm");
  const pk::Dataset data = pk::ParseDataset(
      "ID,TIME,AMT,DVID,DV\n1,0,100,.,.\n1,1,0,2,.\n1,4,0,2,.\n1,10,0,2,.\n", "bolus.csv");
  const pk::Dataset one_output = pk::ParseDataset("ID,TIME,AMT,DV\n1,0,100,.\n1,1,0,.\n1,4,0,.\n1,10,0,.\n", "b.csv");
  pk::SimulationOptions options;
  options.track_auc = true;
  options.ode.relative_tolerance = 1e-12;
  options.ode.absolute_tolerance = 1e-14;
  for (pk::Propagator propagator : {pk::Propagator::kExact, pk::Propagator::kOde}) {
    INFO(pk::ToString(propagator));
    options.propagator = propagator;
    const pk::SubjectSimulation sim = pk::SimulateSubject(
        *model, data, 0, {{"CL", cl}, {"V", v}, {"KE0", ke0}, {"E0", e0}, {"SLOPE", slope}}, options);
    const pk::SubjectSimulation exo =
        pk::SimulateSubject(*turnover, one_output, 0, {{"KIN", kin}, {"KOUT", kout}, {"V", vt}}, options);
    REQUIRE((sim.ok && exo.ok));
    REQUIRE((sim.rows.size() == 3 && exo.rows.size() == 3));
    for (size_t r = 0; r < 3; ++r) {
      const double t = sim.rows[r].time;
      const double ce = 100 / v * ke0 / (ke0 - k) * (std::exp(-k * t) - std::exp(-ke0 * t));
      CHECK(sim.rows[r].pred == Approx(e0 + slope * ce).epsilon(1e-10));
      CHECK(exo.rows[r].cp == Approx((kin / kout + 100 * std::exp(-kout * t)) / vt).epsilon(1e-10));
      CHECK(exo.rows[r].auc == Approx((kin / kout * t + 100 / kout * (1 - std::exp(-kout * t))) / vt).epsilon(1e-9));
    }
  }
}

TEST_CASE("model files: a zero-order input in d/dt runs on Φ/Γ as K0_n, equal to the exogenous form",
          "[model_file][gradient]") {
  // The shipped turnover.pkm, d/dt(A) = KIN − KOUT·A from the baseline X0_1 = KIN/KOUT, against the
  // same turnover with the exogenous part as the state and the baseline in the output (the output's
  // offset), integrated by CVODES at rtol 1e-12 and on Φ/Γ, on every event type (a reset record sets X0_1 again, as
  // NONMEM's A_0, which is where the exogenous form's reset leaves it) but the one that gives X0_1
  // (computed here).
  const auto model = pk::LoadModelFile(ModelPath("turnover"));
  INFO(pk::WhyNotLinear(*model));
  REQUIRE(dynamic_cast<const pk::LinearModel*>(model.get()) != nullptr);
  CHECK(model->declarations().computed_modifiers.names == std::vector<std::string>{"X0_1", "K0_1"});
  const auto exogenous = pk::ParseModel(
      "$PROBLEM turnover_exo  the exogenous part as the state\n"
      "$PARAM\nKIN = 10\nKOUT = 0.5\nV = 20\n"
      "$CMT\nEXOGENOUS  dose central\n"
      "$ODE\nd/dt(EXOGENOUS) = -KOUT * EXOGENOUS\n"
      "$OUTPUT\nCP = (KIN / KOUT + EXOGENOUS) / V\n",
      "turnover_exo.pkm");
  INFO(pk::WhyNotLinear(*exogenous));
  REQUIRE(dynamic_cast<const pk::LinearModel*>(exogenous.get()) != nullptr);
  for (const pk_test::Scenario& sc : pk_test::OdeScenarios()) {
    if (std::string(sc.name) == "initial state") continue;
    INFO(sc.name);
    const auto data = pk_test::ScenarioData(sc);
    pk::ObjectiveOptions exact;
    exact.error_model = pk::MakeResidualError("proportional");
    const pk::ObjectiveOptions ode = CvodesTwin(exact);
    const pk::Objective objective(model, data, 0, exact), reference(exogenous, data, 0, ode),
        exogenous_exact(exogenous, data, 0, exact);
    Eigen::VectorXd values = objective.DefaultValues();
    std::vector<int> free;
    for (const char* name : {"KIN", "KOUT", "V"}) free.push_back(objective.ParameterIndex(name));
    for (size_t e = 0; e < sc.extra_free.size(); ++e) {
      const int k = objective.ParameterIndex(sc.extra_free[e]);
      values(k) = sc.extra_values[e];
      free.push_back(k);
    }
    for (int k : objective.sigma_indices()) free.push_back(k);
    // The same vector without the amount form's computed X0_1 and K0_1 (0 in the exogenous form).
    Eigen::VectorXd exogenous_values = values;
    for (const char* name : {"X0_1", "K0_1"}) exogenous_values(reference.ParameterIndex(name)) = 0;
    const auto want =
        reference.Evaluate(exogenous_values, free, pk::Objective::Need::kGradient, pk::GradientRoute::kForward);
    REQUIRE(want.ok);
    const Eigen::VectorXd fd = pk_test::CentralDifferences(objective, values, free);
    for (pk::GradientRoute r : {pk::GradientRoute::kForward, pk::GradientRoute::kAdjoint}) {
      const auto got = objective.Evaluate(values, free, pk::Objective::Need::kGradient, r);
      INFO(pk::ToString(r) << "\n" << got.gradient.transpose() << "\node " << want.gradient.transpose() << "\nfd  "
                           << fd.transpose());
      REQUIRE(got.ok);
      CHECK(std::string(got.propagator) == "exact");
      CHECK(MaxRel(got.predictions, want.predictions) < 1e-9);
      CHECK(MaxRel(got.gradient, want.gradient) < 1e-7);
      CHECK(MaxRel(got.gradient, fd) < 1e-6);
      // The exogenous form on Φ/Γ, its baseline as the output's offset, route by route.
      const auto offset = exogenous_exact.Evaluate(exogenous_values, free, pk::Objective::Need::kGradient, r);
      REQUIRE(offset.ok);
      CHECK(std::string(offset.propagator) == "exact");
      CHECK(MaxRel(offset.predictions, want.predictions) < 1e-9);
      CHECK(MaxRel(offset.gradient, want.gradient) < 1e-7);
      CHECK(MaxRel(offset.gradient, got.gradient) < 1e-9);
    }
  }
  // Both a term without an amount and a K0_1 of $PK, or a d/dt that reads K0_1: the event engine
  // adds K0_1 whatever the equations say, so the input would count twice. Errors at the d/dt.
  std::ifstream in(ModelPath("turnover"));
  const std::string shipped((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const int ode_line = 1 + static_cast<int>(std::count(shipped.begin(), shipped.begin() + shipped.find("d/dt(A)"), '\n'));
  std::string both = shipped;
  both.insert(both.find("$ODE"), "K0_1 = 2\n");
  std::string reads = shipped;
  reads.insert(reads.find("$ODE"), "K0_1 = KIN\n");
  reads.replace(reads.find("KIN - KOUT * A"), 14, "K0_1 - KOUT * A");
  std::string declared = shipped;
  declared.insert(declared.find("$CMT"), "K0_1 = 2\n");
  for (const std::string& text : {both, reads, declared}) {
    try {
      pk::ParseModel(text, "twice.pkm");
      FAIL("an input counted twice was accepted");
    } catch (const pk::InputError& e) {
      CHECK(e.file() == "twice.pkm");
      CHECK(e.line() == ode_line + 1);  // the d/dt, one line down for the inserted line
      CHECK(e.column() > 0);
      CHECK_THAT(e.message(), Catch::Contains("would count twice"));
    }
  }
}

namespace {

// 1cmt oral whose F1, ALAG1, D1 and X0_2 are computed in $PK from parameters and a time-varying weight.
const char* const kComputedModifiers =
    "$PROBLEM modifiers  1cmt oral with computed F1, ALAG1, D1 and X0_2\n"
    "$PARAM\nKA = 1.2\nCL = 3\nV = 30\nFPOP = 0.7 (0, 1)\nTLAG = 0.4\nTVD = 1.5\nA0 = 5\n"
    "$COVARIATE\nWT kg\n"
    "$CMT\nDEPOT dose\nCENTRAL central\n"
    "$PK\nF1 = FPOP * (WT / 70)^0.25\nALAG1 = TLAG * WT / 70\nD1 = TVD * sqrt(WT / 70)\nX0_2 = A0 * WT / 70\n"
    "$ODE\nd/dt(DEPOT) = -KA * DEPOT\nd/dt(CENTRAL) = KA * DEPOT - CL / V * CENTRAL\n"
    "$OUTPUT\nCP = CENTRAL / V\n";

// Rows TIME, AMT, RATE, CMT, II, ADDL, WT (DV follows from the time); the weight changes at t = 12.
const double kModifierRows[][7] = {
    {0, 100, 0, 1, 0, 0, 60},   {0.5, 0, 0, 2, 0, 0, 60},  {1, 0, 0, 2, 0, 0, 60},   {3, 0, 0, 2, 0, 0, 60},
    {8, 0, 0, 2, 0, 0, 60},     {12, 100, -2, 1, 0, 0, 75}, {12.5, 0, 0, 2, 0, 0, 75}, {13.5, 0, 0, 2, 0, 0, 75},
    {16, 0, 0, 2, 0, 0, 75},    {24, 50, 0, 1, 6, 2, 80},  {25, 0, 0, 2, 0, 0, 80},   {31, 0, 0, 2, 0, 0, 80},
    {40, 0, 0, 2, 0, 0, 80}};

// The dataset with WT (for the file) or with the modifiers' values as columns (for the catalogue).
std::shared_ptr<pk::Dataset> ModifierData(bool columns) {
  const double fpop = 0.7, tlag = 0.4, tvd = 1.5, a0 = 5;
  std::ostringstream out;
  out.precision(17);
  out << "ID,TIME,AMT,RATE,CMT,II,ADDL,DV," << (columns ? "F1,ALAG1,D1,X0_2" : "WT") << "\n";
  for (const auto& r : kModifierRows) {
    out << "1," << r[0] << "," << r[1] << "," << r[2] << "," << r[3] << "," << r[4] << "," << r[5] << ","
        << (r[1] > 0 ? std::string(".") : std::to_string(1 + 0.1 * r[0])) << ",";
    const double w = r[6] / 70;
    if (columns) {
      out << fpop * std::pow(w, 0.25) << "," << tlag * w << "," << tvd * std::sqrt(w) << "," << a0 * w << "\n";
    } else {
      out << r[6] << "\n";
    }
  }
  return std::make_shared<pk::Dataset>(pk::ParseDataset(out.str(), columns ? "columns.csv" : "wt.csv"));
}

}  // namespace

TEST_CASE("model files: dose modifiers computed in $PK follow covariates, with exact gradients", "[model_file][gradient]") {
  const auto model = pk::ParseModel(kComputedModifiers, "modifiers.pkm");
  REQUIRE(model->is_linear());
  CHECK(model->declarations().computed_modifiers.names == std::vector<std::string>{"F1", "ALAG1", "D1", "X0_2"});
  pk::ObjectiveOptions options;
  options.error_model = pk::MakeResidualError("proportional");
  const pk::Objective file(model, ModifierData(false), 0, options);
  const pk::Objective catalogue(pk::MakeModel("1cmt_oral"), ModifierData(true), 0, options);
  Eigen::VectorXd values = file.DefaultValues(), cvalues = catalogue.DefaultValues();
  for (const char* name : {"KA", "CL", "V"}) cvalues(catalogue.ParameterIndex(name)) = values(file.ParameterIndex(name));
  std::vector<int> structural, cstructural, all;
  for (const char* name : {"KA", "CL", "V"}) {
    structural.push_back(file.ParameterIndex(name));
    cstructural.push_back(catalogue.ParameterIndex(name));
  }
  for (const char* name : {"KA", "CL", "V", "FPOP", "TLAG", "TVD", "A0"}) all.push_back(file.ParameterIndex(name));
  for (int k : file.sigma_indices()) all.push_back(k);
  // The same predictions as the catalogue given the modifiers' values as data columns.
  const auto want = catalogue.Evaluate(cvalues, cstructural, pk::Objective::Need::kGradient);
  REQUIRE(want.ok);
  for (pk::GradientRoute r : {pk::GradientRoute::kForward, pk::GradientRoute::kAdjoint}) {
    const auto got = file.Evaluate(values, structural, pk::Objective::Need::kGradient, r);
    REQUIRE(got.ok);
    INFO(pk::ToString(r) << "\nfile " << got.predictions.transpose() << "\ncatalogue " << want.predictions.transpose());
    CHECK(MaxRel(got.predictions, want.predictions) < 1e-12);
    CHECK(MaxRel(got.gradient, want.gradient) < 1e-10);
  }
  // Derivatives through the modifiers: every route against central differences, and the exact
  // routes against the same equations on CVODES.
  const Eigen::VectorXd fd = pk_test::CentralDifferences(file, values, all);
  const pk::ObjectiveOptions ode = CvodesTwin(options);
  const pk::Objective reference(model, ModifierData(false), 0, ode);
  for (pk::GradientRoute r : {pk::GradientRoute::kForward, pk::GradientRoute::kAdjoint}) {
    for (const pk::Objective* o : {&file, &reference}) {
      const auto got = o->Evaluate(values, all, pk::Objective::Need::kGradient, r);
      REQUIRE(got.ok);
      INFO(pk::ToString(r) << " " << got.propagator << "\n" << got.gradient.transpose() << "\nfd " << fd.transpose());
      CHECK(MaxRel(got.gradient, fd) < 1e-6);
      CHECK(pk_test::RelDiff(got.value, file.Evaluate(values, {}, pk::Objective::Need::kValue).value) < 1e-9);
    }
  }
  // A cached event schedule (eigen-coordinates, TLAG not free) follows a change of what ALAG1 reads.
  Eigen::VectorXd moved = values;
  moved(file.ParameterIndex("TLAG")) = 0.9;
  const auto before = file.Evaluate(values, structural, pk::Objective::Need::kGradient);
  const auto after = file.Evaluate(moved, structural, pk::Objective::Need::kGradient);
  const auto fresh = pk::Objective(model, ModifierData(false), 0, options).Evaluate(moved, structural, pk::Objective::Need::kGradient);
  REQUIRE(after.ok);
  CHECK(after.modal);
  CHECK(MaxRel(after.predictions, fresh.predictions) < 1e-14);
  CHECK(MaxRel(after.predictions, before.predictions) > 1e-3);
}

TEST_CASE("model files: a fit with a computed lag, and a computed lag below 0 fails its evaluation", "[model_file][fit]") {
  // ALAG1 reads only parameters with finite defaults: the fitted values (and the curves drawn from
  // them) hold a finite ALAG1, which must not be handed back as a given value.
  const char* text =
      "$PROBLEM lagged  1cmt oral with a computed lag\n"
      "$PARAM\nKA = 1.5\nCL = 3\nV = 30\nTLAG = 0.3\nSHIFT = 0 (-1, 1)\n"
      "$CMT\nDEPOT dose\nCENTRAL central\n"
      "$PK\nALAG1 = TLAG + SHIFT\n"
      "$ODE\nd/dt(DEPOT) = -KA * DEPOT\nd/dt(CENTRAL) = KA * DEPOT - CL / V * CENTRAL\n"
      "$OUTPUT\nCP = CENTRAL / V\n";
  const auto model = pk::ParseModel(text, "lagged.pkm");
  pk::FitSubjectsRequest req;
  req.model = model;
  req.data = std::make_shared<pk::Dataset>(pk::ReadDataset(std::string(PK_SOURCE_DIR) + "/datasets/theophylline.csv"));
  req.subjects = {0};
  req.jobs = 1;
  req.curve_points = 3;
  pk::ParameterSettings settings;
  settings.fixed = {{"SHIFT", 0.0}};
  req.parameters = pk::MakeParameterSpecs(req, settings);
  const pk::SubjectFit fit = pk::FitSubjects(req).at(0);
  INFO(fit.error);
  REQUIRE(fit.ok);
  // A lag below 0 would run time backwards: the evaluation fails and says why.
  const pk::Objective objective(model, req.data, 0, pk::ObjectiveOptions());
  Eigen::VectorXd values = objective.DefaultValues();
  values(objective.ParameterIndex("SHIFT")) = -0.5;
  const auto e = objective.Evaluate(values, {}, pk::Objective::Need::kValue);
  CHECK_FALSE(e.ok);
  CHECK_THAT(e.message, Catch::Contains("ALAG1 is -0.2 for the dose at TIME 0: it must be 0 or more"));
}

TEST_CASE("model files: NONMEM's A_0(n) in $PK is X0_n", "[model_file]") {
  std::string text = kComputedModifiers;
  const size_t at = text.find("X0_2 = ");
  REQUIRE(at != std::string::npos);
  text.replace(at, 7, "A_0(2) = ");
  const auto a = pk::ParseModel(kComputedModifiers, "x0.pkm"), b = pk::ParseModel(text, "a0.pkm");
  CHECK(b->declarations().computed_modifiers.names == a->declarations().computed_modifiers.names);
  const pk::Objective oa(a, ModifierData(false), 0, pk::ObjectiveOptions()), ob(b, ModifierData(false), 0, pk::ObjectiveOptions());
  const auto ea = oa.Evaluate(oa.DefaultValues(), {}, pk::Objective::Need::kValue);
  const auto eb = ob.Evaluate(ob.DefaultValues(), {}, pk::Objective::Need::kValue);
  REQUIRE(ea.ok);
  CHECK(ea.predictions == eb.predictions);
  text.replace(at, 9, "A_0(B) = ");
  CHECK_THROWS_WITH(pk::ParseModel(text, "bad.pkm"), Catch::Contains("expected a compartment number in A_0(…)"));
}

TEST_CASE("model files: $INIT and CMT(0) set a compartment's initial amount, as X0_n in $PK", "[model_file][gradient]") {
  // kComputedModifiers' X0_2 = A0·WT/70 written as $INIT's CENTRAL = …, with several on a line.
  std::string text = kComputedModifiers;
  const size_t at = text.find("X0_2 = A0 * WT / 70\n");
  REQUIRE(at != std::string::npos);
  text.erase(at, 20);
  text += "$INIT\nCENTRAL = A0 * WT / 70, DEPOT = 0\n";
  const auto a = pk::ParseModel(kComputedModifiers, "x0.pkm"), b = pk::ParseModel(text, "init.pkm");
  CHECK(b->declarations().computed_modifiers.names == std::vector<std::string>{"F1", "ALAG1", "D1", "X0_2", "X0_1"});
  CHECK(dynamic_cast<const pk::LinearModel*>(b.get()) != nullptr);  // still on Φ/Γ
  const pk::Objective oa(a, ModifierData(false), 0, pk::ObjectiveOptions()), ob(b, ModifierData(false), 0, pk::ObjectiveOptions());
  std::vector<int> free;
  for (const char* name : {"KA", "CL", "V", "A0"}) free.push_back(oa.ParameterIndex(name));
  const auto ea = oa.Evaluate(oa.DefaultValues(), free, pk::Objective::Need::kGradient);
  const auto eb = ob.Evaluate(ob.DefaultValues(), free, pk::Objective::Need::kGradient);
  REQUIRE(ea.ok);
  REQUIRE(eb.ok);
  CHECK(MaxRel(ea.predictions, eb.predictions) < 1e-14);
  CHECK(MaxRel(ea.gradient, eb.gradient) < 1e-12);
  CHECK(std::abs(ea.gradient(3)) > 0);  // the initial amount's parameter counts
  // nlmixr2's CENTRAL(0) = … in $PK, also within if/else (both branches taken: WT is 60 at the
  // first record, 75 at a later one), is the same.
  std::string pk_form = kComputedModifiers;
  pk_form.replace(pk_form.find("X0_2 = A0 * WT / 70"), 19, "if (WT > 65) {\n  CENTRAL(0) = A0 * WT / 70\n} else {\n  CENTRAL(0) = A0 * (WT / 70)\n}");
  const auto c = pk::ParseModel(pk_form, "nlmixr.pkm");
  CHECK(c->declarations().computed_modifiers.names == a->declarations().computed_modifiers.names);
  const pk::Objective oc(c, ModifierData(false), 0, pk::ObjectiveOptions());
  const auto ec = oc.Evaluate(oc.DefaultValues(), free, pk::Objective::Need::kGradient);
  REQUIRE(ec.ok);
  CHECK(MaxRel(ea.predictions, ec.predictions) < 1e-14);
  CHECK(MaxRel(ea.gradient, ec.gradient) < 1e-12);
}

TEST_CASE("model files: a computed dose modifier cannot be given, fixed or read from the data", "[model_file]") {
  const auto model = pk::ParseModel(kComputedModifiers, "modifiers.pkm");
  const pk::ParameterLayout layout(*model);
  CHECK(layout.is_computed(layout.Index("ALAG1")));
  CHECK_FALSE(layout.is_computed(layout.Index("ALAG2")));
  CHECK_THROWS_WITH(layout.Resolve({{"F1", 0.5}}), Catch::Contains("F1 is computed in $PK of model modifiers"));
  // A data column of that name would be ignored: refused at the header.
  const auto data = ModifierData(true);
  try {
    pk::internal::CheckColumns(*model, *data, true);
    FAIL("no error");
  } catch (const pk::InputError& e) {
    CHECK(e.file() == "columns.csv");
    CHECK(e.line() == 1);
    CHECK(e.column() == data->ColumnNumber("F1"));
    CHECK_THAT(e.message(), Catch::Contains("the data column F1 cannot set it"));
  }
}

TEST_CASE("model files: fits recover known parameters and reach the catalogue twin's objective", "[model_file][fit]") {
  // Data from the model at known values, with a deterministic 0.5 % perturbation; the fit starts
  // from the file's defaults.
  struct Truth {
    const char* model;
    pk::ParameterValues values;
  };
  for (const Truth& t : {Truth{"idr3", {{"CL", 2.2}, {"V", 24}, {"KOUT", 0.3}, {"R0", 80}, {"EMAX", 3}, {"EC50", 1.5}}},
                         Truth{"parent_metabolite", {{"KA", 1.1}, {"CL", 4}, {"V", 25}, {"CLM", 9}, {"VM", 40}}}}) {
    INFO(t.model);
    const auto model = pk::LoadModelFile(ModelPath(t.model));
    const auto regimen = ReferenceRegimen(Outputs(*model));
    const pk::Objective truth(model, regimen, 0, pk::ObjectiveOptions());
    Eigen::VectorXd v = truth.DefaultValues();
    for (const auto& kv : t.values) v(truth.ParameterIndex(kv.first)) = kv.second;
    const auto e = truth.Evaluate(v, {}, pk::Objective::Need::kValue);
    REQUIRE(e.ok);
    auto data = std::make_shared<pk::Dataset>(*regimen);
    int k = 0;
    for (pk::Record& r : data->subjects[0].records) {
      if (r.IsSample()) {
        r.dv = e.predictions(k) * (1 + 0.005 * std::sin(1.7 * k));
        ++k;
      }
    }
    pk::FitSubjectsRequest req;
    req.model = model;
    req.data = data;
    req.objective.error_model = pk::MakeResidualError("proportional");
    req.jobs = 1;
    req.curve_points = 2;
    req.parameters = pk::MakeParameterSpecs(req, {});
    req.fit.optimizer = pk::ChooseOptimizer(req, "");
    const pk::SubjectFit fit = pk::FitSubjects(req).at(0);
    REQUIRE(fit.ok);
    CHECK(fit.summary.converged());
    for (const pk::ParameterEstimate& p : fit.summary.estimates) {
      if (!t.values.count(p.name)) continue;
      INFO(p.name << " " << p.estimate << " (truth " << t.values.at(p.name) << ")");
      CHECK(std::fabs(p.estimate / t.values.at(p.name) - 1) < 0.1);
    }
  }
  // The file twin of 1cmt_oral_mm reaches the catalogue's objective on its bundled data.
  double objective[2];
  for (int which = 0; which < 2; ++which) {
    pk::FitSubjectsRequest req;
    req.model = which == 0 ? pk::MakeModel("1cmt_iv_mm") : pk::LoadModelFile(ModelPath("1cmt_iv_mm"));
    req.data = std::make_shared<pk::Dataset>(pk::ReadDataset(std::string(PK_SOURCE_DIR) + "/datasets/mm_synthetic.csv"));
    req.subjects = {0};
    req.jobs = 1;
    req.curve_points = 2;
    req.parameters = pk::MakeParameterSpecs(req, {});
    const pk::SubjectFit fit = pk::FitSubjects(req).at(0);
    REQUIRE(fit.ok);
    objective[which] = fit.summary.objective;
  }
  CHECK(pk_test::RelDiff(objective[0], objective[1]) < 1e-6);
}

TEST_CASE("model files: definitions shared along a chain are analysed once each", "[model_file]") {
  // A_k = A_{k-1}·A_{k-1}/A_{k-1} reads its predecessor three times: visiting the graph as a tree
  // would take 3^60 steps (the test would never end); bound once each, it is K, and linear.
  std::string text = "$PROBLEM deep  a chain of shared definitions\n$PARAM\nK = 0.1\nV = 10\n$CMT\nC dose\n$ODE\nA0 = K\n";
  for (int k = 1; k <= 60; ++k) {
    text += "A" + std::to_string(k) + " = A" + std::to_string(k - 1) + " * A" + std::to_string(k - 1) + " / A" +
            std::to_string(k - 1) + "\n";
  }
  text += "d/dt(C) = -A60 * C\n$OUTPUT\nCP = C / V\n";
  const auto model = pk::ParseModel(text, "deep.pkm");
  REQUIRE(dynamic_cast<const pk::LinearModel*>(model.get()) != nullptr);
  const pk::Objective objective(model, std::make_shared<pk::Dataset>(pk::ParseDataset("ID,TIME,AMT,DV\n1,0,1,.\n1,1,0,1\n", "d.csv")), 0,
                                pk::ObjectiveOptions());
  const auto e = objective.Evaluate(objective.DefaultValues(), {}, pk::Objective::Need::kValue);
  REQUIRE(e.ok);
  CHECK(e.predictions(0) == Approx(std::exp(-0.1) / 10).epsilon(1e-13));
}

TEST_CASE("model files: declared bounds, modifiers, covariates and σ become the fit's parameters", "[model_file][fit]") {
  const char* text =
      "$PROBLEM declared  what a file tells the fit\n"
      "$PARAM\nKA = 1.2 (0.1, 10) 1/h\nCL = 3\nV = 30 (5, ) L\nF1 = 0.7 (0, 1)\n"
      "$COVARIATE\nWT = 70 kg\n"
      "$CMT\nDEPOT dose\nCENTRAL\n"
      "$ODE\nd/dt(DEPOT) = -KA * DEPOT\nd/dt(CENTRAL) = KA * DEPOT - CL * WT / 70 / V * CENTRAL\n"
      "$OUTPUT\nCP = CENTRAL / V\n$ERROR\nCP ~ proportional(0.05)\n";
  pk::FitSubjectsRequest req;
  req.model = pk::ParseModel(text, "declared.pkm");
  req.data = std::make_shared<pk::Dataset>(pk::ParseDataset("ID,TIME,AMT,DV\n1,0,100,.\n1,1,0,2\n1,4,0,1\n", "d.csv"));
  req.objective.error_model = pk::MakeResidualError(req.model->declarations().error_model);
  const std::vector<pk::ParameterSpec> specs = pk::MakeParameterSpecs(req, {});
  std::map<std::string, pk::ParameterSpec> by_name;
  for (const pk::ParameterSpec& s : specs) by_name[s.name] = s;
  CHECK(by_name.size() == 5);  // KA, CL, V, SIGMA_PROP, F1: not the covariate WT
  CHECK(by_name.count("WT") == 0);
  CHECK(by_name["KA"].lower == 0.1);
  CHECK(by_name["KA"].upper == 10);
  CHECK(by_name["V"].lower == 5);
  CHECK(std::isinf(by_name["V"].upper));
  CHECK(std::isinf(by_name["CL"].lower));
  CHECK(by_name["F1"].initial == 0.7);
  CHECK(by_name["F1"].upper == 1);
  CHECK(by_name["SIGMA_PROP"].initial == 0.05);
  // The layout starts F1 from the file's value; the units are the file's.
  const pk::ParameterLayout layout(*req.model);
  CHECK(layout.Defaults()(layout.Index("F1")) == 0.7);
  const pk::Units units = pk::ModelUnits(pk::Units(), *req.model);
  CHECK(pk::ParameterUnit("KA", units) == "1/h");
  CHECK(pk::ParameterUnit("WT", units) == "kg");
  CHECK(pk::ParameterUnit("CL", units).empty());
  // With another error model in use, the file's σ does not apply.
  req.objective.error_model = pk::MakeResidualError("additive");
  for (const pk::ParameterSpec& s : pk::MakeParameterSpecs(req, {})) {
    if (s.name == "SIGMA_ADD") CHECK(std::isnan(s.initial));
  }
}

namespace {

std::string FileText(const std::string& name) {
  std::ifstream in(ModelPath(name));
  std::ostringstream text;
  text << in.rdbuf();
  return text.str();
}

std::shared_ptr<pk::Dataset> EmaxData(const char* ignore = nullptr) {
  pk::DatasetFilter filter;
  if (ignore) filter.ignore = {ignore};
  return std::make_shared<pk::Dataset>(pk::ReadDataset(std::string(PK_SOURCE_DIR) + "/datasets/emax_synthetic.csv", filter));
}

}  // namespace

TEST_CASE("per-output error models: each output's samples follow their own model and σ", "[model_file][error]") {
  const auto model = pk::LoadModelFile(ModelPath("1cmt_iv_emax"));
  const auto error = pk::MakePerOutputError({pk::MakeResidualError("proportional"), pk::MakeResidualError("additive")},
                                            {"CP", "E"});
  CHECK(error->sigma_names() == std::vector<std::string>{"SIGMA_PROP_CP", "SIGMA_ADD_E"});
  CHECK(pk::DescribeErrorModel(*error) == "proportional (SIGMA_PROP_CP); additive (SIGMA_ADD_E)");
  pk::ObjectiveOptions options;
  options.error_model = error;
  options.ode.relative_tolerance = 1e-12;
  options.ode.absolute_tolerance = 1e-14;
  pk::ObjectiveOptions prop = options, add = options;
  prop.error_model = pk::MakeResidualError("proportional");
  add.error_model = pk::MakeResidualError("additive");
  for (int subject : {0, 3}) {
    INFO("subject " << subject);
    const pk::Objective both(model, EmaxData(), subject, options);
    // The same samples split by DVID, each output with its own single model.
    const pk::Objective cp(model, EmaxData("DVID.EQ.2"), subject, prop), e(model, EmaxData("DVID.EQ.1"), subject, add);
    REQUIRE(both.num_samples() == cp.num_samples() + e.num_samples());
    Eigen::VectorXd values = both.DefaultValues(), vcp = cp.DefaultValues(), ve = e.DefaultValues();
    // Each σ starts from its own output's observations.
    CHECK(values(both.ParameterIndex("SIGMA_ADD_E")) == ve(e.ParameterIndex("SIGMA_ADD")));
    values(both.ParameterIndex("SIGMA_PROP_CP")) = vcp(cp.ParameterIndex("SIGMA_PROP")) = 0.15;
    values(both.ParameterIndex("SIGMA_ADD_E")) = ve(e.ParameterIndex("SIGMA_ADD")) = 0.8;
    const double v = both.Evaluate(values, {}, pk::Objective::Need::kValue).value;
    const double split = cp.Evaluate(vcp, {}, pk::Objective::Need::kValue).value +
                         e.Evaluate(ve, {}, pk::Objective::Need::kValue).value;
    CHECK(pk_test::RelDiff(v, split) < 1e-9);
    // Scaled residuals: (y − ŷ)/(σ_prop ŷ) for CP, (y − ŷ)/σ_add for E.
    const auto ev = both.Evaluate(values, {}, pk::Objective::Need::kValue);
    const Eigen::VectorXd scaled = both.ScaledResiduals(values, ev.predictions);
    const std::vector<int> outputs = both.sample_outputs();
    for (Eigen::Index k = 0; k < scaled.size(); ++k) {
      const double yhat = ev.predictions(k), y = both.observations()(k);
      const double want = outputs[static_cast<size_t>(k)] == 1 ? (y - yhat) / (0.15 * yhat) : (y - yhat) / 0.8;
      CHECK(std::abs(scaled(k) - want) <= 1e-12 * std::max(1.0, std::abs(want)));
    }
    // Gradients through both σ and the model, every route against central differences.
    std::vector<int> free;
    for (int k = 0; k < model->num_parameters(); ++k) free.push_back(k);
    for (int k : both.sigma_indices()) free.push_back(k);
    const Eigen::VectorXd fd = pk_test::CentralDifferences(both, values, free);
    for (pk::GradientRoute r : {pk::GradientRoute::kForward, pk::GradientRoute::kAdjoint}) {
      const auto g = both.Evaluate(values, free, pk::Objective::Need::kGradient, r);
      REQUIRE(g.ok);
      INFO(pk::ToString(r) << "\n" << g.gradient.transpose() << "\nfd " << fd.transpose());
      CHECK(MaxRel(g.gradient, fd) < 1e-6);
    }
  }
}

TEST_CASE("per-output error models: a subject without an output's samples holds that σ fixed", "[model_file][error][fit]") {
  pk::FitSubjectsRequest req;
  req.model = pk::LoadModelFile(ModelPath("1cmt_iv_emax"));
  req.data = EmaxData("DVID.EQ.2");  // concentrations only
  req.subjects = {0};
  req.jobs = 1;
  req.curve_points = 2;
  req.objective.error_model = pk::MakePerOutputError(
      {pk::MakeResidualError("proportional"), pk::MakeResidualError("additive")}, {"CP", "E"});
  pk::ParameterSettings settings;  // the effect's parameters cannot be estimated from concentrations
  settings.fixed = {{"KE0", 0.5}, {"E0", 10}, {"EMAX", 50}, {"EC50", 1}, {"HILL", 1.5}};
  req.parameters = pk::MakeParameterSpecs(req, settings);
  req.fit.optimizer = pk::ChooseOptimizer(req, "");
  const pk::SubjectFit fit = pk::FitSubjects(req).at(0);
  INFO(fit.error);
  REQUIRE(fit.ok);
  bool seen = false;
  for (const pk::ParameterEstimate& p : fit.summary.estimates) {
    if (p.name == "SIGMA_ADD_E") {
      seen = true;
      CHECK(p.fixed);
    }
    if (p.name == "SIGMA_PROP_CP" || p.name == "CL") CHECK_FALSE(p.fixed);
  }
  CHECK(seen);
  CHECK(fit.summary.covariance.size() > 0);  // not singular for want of E samples
}

TEST_CASE("per-output error models from a model file's $ERROR, with their initial σ", "[model_file][error]") {
  const std::string base = FileText("1cmt_iv_emax");
  const auto model = pk::ParseModel(base + "$ERROR\nCP ~ proportional(0.12)\nE ~ additive(0.9)\n", "emax.pkm");
  const auto error = pk::DeclaredErrorModel(*model);
  REQUIRE(error);
  CHECK(error->num_outputs() == 2);
  CHECK(error->sigma_names() == std::vector<std::string>{"SIGMA_PROP_CP", "SIGMA_ADD_E"});
  CHECK(pk::DeclaredSigmas(*model, *error) == std::vector<double>{0.12, 0.9});
  // Another error model in use: the file's σ do not apply.
  CHECK(std::isnan(pk::DeclaredSigmas(*model, *pk::MakeResidualError("additive"))[0]));
  // A fit starts from them.
  pk::FitSubjectsRequest request;
  request.model = model;
  request.data = EmaxData();
  request.objective.error_model = error;
  const std::vector<pk::ParameterSpec> specs = pk::MakeParameterSpecs(request, pk::ParameterSettings());
  std::map<std::string, double> start;
  for (const pk::ParameterSpec& s : specs) start[s.name] = s.initial;
  CHECK(start.at("SIGMA_PROP_CP") == 0.12);
  CHECK(start.at("SIGMA_ADD_E") == 0.9);
  // One line serves every output with one σ, as before.
  const auto shared = pk::ParseModel(base + "$ERROR\nCP ~ proportional\n", "emax.pkm");
  CHECK(pk::DeclaredErrorModel(*shared)->num_outputs() == 0);
  // With a line per output, every output needs one.
  try {
    pk::ParseModel(base + "CE = EFFECT\n$ERROR\nCP ~ proportional\nE ~ additive\n", "emax3.pkm");
    FAIL("no error");
  } catch (const pk::InputError& e) {
    CHECK(e.file() == "emax3.pkm");
    CHECK_THAT(e.message(), Catch::Contains("but not CE"));
  }
}
