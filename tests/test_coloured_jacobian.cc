// Compressed sparse Jacobians for the one-step method's discrete adjoint (src/ode/coloured_jacobian.h):
// the scalar types, the pattern and its colouring, each stage's products against the tape's, and the
// gradients the adjoint gives with and without them.
#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <memory>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include <unistd.h>

#include "ode/coloured_jacobian.h"
#include "ode/ode_system.h"
#include "pk/fixed_dual.h"
#include "pk/model_file.h"
#include "pk/objective.h"
#include "pk/ode_model.h"
#include "pk/sparsity_scalar.h"
#include "test_util.h"

namespace {

using Need = pk::Objective::Need;

double MaxAbs(const Eigen::MatrixXd& m) { return m.size() ? m.cwiseAbs().maxCoeff() : 0.0; }

// Every operation and function FixedDual offers, in one expression of two variables.
template <typename T>
T Expression(const T& a, const T& b) {
  T r = a * b - a / b + (-a) + exp(b / a) + log(a + b) + sqrt(a * a + b) + pow(a, 2.5) + pow(a, b) +
        pow(2.0, b) + fabs(b - a) + abs(a - b);
  r += a;
  r -= 0.5 * b;
  r *= b;
  r /= a + 1.0;
  return r;
}

// pkbench's saturable chain: x_i flows to x_{i+1} at VMAX_i x_i/(KM_i + x_i); θ = (VMAX, KM).
struct SaturableChain {
  int n;
  template <typename T>
  void Rhs(const T* x, const T* p, T* dxdt) const {
    T inflow(0.0);
    for (int i = 0; i < n; ++i) {
      const T out = p[i] * x[i] / (p[n + i] + x[i]);
      dxdt[i] = inflow - out;
      inflow = out;
    }
  }
  template <typename T>
  T Output(int, const T* x, const T*) const {
    return x[n - 1];
  }
};

std::shared_ptr<const pk::Model> Chain(int n) {
  pk::OdeModelSpec spec;
  spec.name = "chain";
  for (int i = 1; i <= n; ++i) spec.compartments.push_back("X" + std::to_string(i));
  for (int i = 1; i <= n; ++i) spec.parameters.push_back({"VMAX" + std::to_string(i), 40.0 + i});
  for (int i = 1; i <= n; ++i) spec.parameters.push_back({"KM" + std::to_string(i), 5.0 + 0.1 * i});
  spec.central = n;
  return pk::MakeOdeModel(spec, SaturableChain{n});
}

// Every compartment feeds every other: the x columns all share rows, so 9 need 9 lanes (more than 8).
struct Dense9 {
  template <typename T>
  void Rhs(const T* x, const T* p, T* dxdt) const {
    T total(0.0);
    for (int i = 0; i < 9; ++i) total += x[i];
    for (int i = 0; i < 9; ++i) dxdt[i] = p[0] * total - x[i];
  }
  template <typename T>
  T Output(int, const T* x, const T*) const {
    return x[0];
  }
};

std::shared_ptr<const pk::Model> Dense() {
  pk::OdeModelSpec spec;
  spec.name = "dense9";
  for (int i = 1; i <= 9; ++i) spec.compartments.push_back("X" + std::to_string(i));
  spec.parameters = {{"K", 0.01}};
  return pk::MakeOdeModel(spec, Dense9());
}

// Two decays, the first at a rate in sqrt(x₀): f_x's first row is NaN below x₀ = 0, the second never.
struct RootDecay {
  template <typename T>
  void Rhs(const T* x, const T* p, T* dxdt) const {
    dxdt[0] = -p[0] * sqrt(x[0]);
    dxdt[1] = p[0] * x[0] - p[1] * x[1];
  }
  template <typename T>
  T Output(int, const T* x, const T*) const {
    return x[1];
  }
};

// First-order elimination whose f refuses a rate that is not positive: on SparsityScalar, whose value
// is 0, it throws.
struct Refuses {
  template <typename T>
  void Rhs(const T* x, const T* p, T* dxdt) const {
    if (!(p[0] > T(0.0))) throw std::domain_error("K must be positive");
    dxdt[0] = -p[0] * x[0];
  }
  template <typename T>
  T Output(int, const T* x, const T*) const {
    return x[0];
  }
};

// A Hill-type rate x₀^K with x₀ at 0 and K < 1: ∂f/∂x₀ is infinite there, every other partial finite.
struct PowerAtZero {
  template <typename T>
  void Rhs(const T* x, const T* p, T* dxdt) const {
    dxdt[0] = -p[1] * sqrt(x[0]);
    dxdt[1] = pow(x[0], p[0]) - p[1] * x[1];
  }
  template <typename T>
  T Output(int, const T* x, const T* p) const {
    return x[1] + pow(x[0], p[0]);
  }
};

// A depot that f leaves unset (a model text's compartment with no d/dt line): its row is 0 on every route.
struct UnsetRow {
  template <typename T>
  void Rhs(const T* x, const T* p, T* dxdt) const {
    dxdt[1] = -p[0] * x[1] + p[1] * x[0];
  }
  template <typename T>
  T Output(int, const T* x, const T*) const {
    return x[1];
  }
};

// The first row added to rather than set: on double it starts from 0 (Rhs zeroes f first), and so
// must it on lanes, whose buffer holds the last step's stage.
struct AddsToRow {
  template <typename T>
  void Rhs(const T* x, const T* p, T* dxdt) const {
    dxdt[0] += -p[0] * x[0];
    dxdt[1] = p[0] * x[0] - p[1] * x[1];
  }
  template <typename T>
  T Output(int, const T* x, const T*) const {
    return x[1];
  }
};

template <typename Functor>
std::shared_ptr<const pk::Model> Small(const char* name, int n, Functor f) {
  pk::OdeModelSpec spec;
  spec.name = name;
  for (int i = 1; i <= n; ++i) spec.compartments.push_back("X" + std::to_string(i));
  spec.parameters = {{"K", 0.8}, {"K2", 10.0}};
  spec.central = n;
  return pk::MakeOdeModel(spec, f);
}

// One-compartment Michaelis–Menten elimination whose rate is switched off by a branch below a threshold.
const char kBranchModel[] = R"($PROBLEM branch  elimination switched by a branch
$PARAM
VMAX = 20  mg/h
KM   = 2   mg/L
V    = 30  L
$CMT
CENTRAL  dose central
$ODE
C = CENTRAL / V
if (C > 0.01) {
  R = VMAX * C / (KM + C)
} else {
  R = 0
}
d/dt(CENTRAL) = -R
$OUTPUT
CP = C
)";

// No two columns of one colour have a row in common, and every column has a colour below `colours`.
bool ValidColouring(const pk::internal::JacobianColouring& c) {
  for (int k = 0; k < c.n + c.m; ++k) {
    if (c.colour[static_cast<size_t>(k)] < 0) return false;
    if (c.column_start[k] < c.column_start[k + 1] && c.colour[static_cast<size_t>(k)] >= c.colours) return false;
    for (int l = k + 1; l < c.n + c.m; ++l) {
      if (c.colour[static_cast<size_t>(k)] != c.colour[static_cast<size_t>(l)]) continue;
      for (int p = c.column_start[k]; p < c.column_start[k + 1]; ++p) {
        for (int q = c.column_start[l]; q < c.column_start[l + 1]; ++q) {
          if (c.rows[static_cast<size_t>(p)] == c.rows[static_cast<size_t>(q)]) return false;
        }
      }
    }
  }
  return true;
}

// The sweep's table of the x columns' nonzeros: slot j of column k is the j-th of lane_offset's entries
// for k (rows in order), and padding (n·width, the sweep's 0) after the last; at least one column fills
// every slot. And x_lanes_below_theta says whether every x column with a nonzero has a colour below
// the θ lanes (the sweep then keeps those lanes only in its sum).
bool ValidGather(const pk::internal::JacobianColouring& c) {
  if (c.x_gather.size() != static_cast<size_t>(c.x_slots) * static_cast<size_t>(c.n)) return false;
  bool full = c.x_slots == 0, below = true;
  for (int k = 0; k < c.n; ++k) {
    const int count = c.column_start[k + 1] - c.column_start[k];
    full = full || count == c.x_slots;
    if (count > 0 && c.colour[static_cast<size_t>(k)] >= c.theta_lanes_begin) below = false;
    for (int j = 0; j < c.x_slots; ++j) {
      const int expected = j < count ? c.lane_offset[static_cast<size_t>(c.column_start[k] + j)] : c.n * c.width;
      if (c.x_gather[static_cast<size_t>(j * c.n + k)] != expected) return false;
    }
  }
  return full && below == c.x_lanes_below_theta;
}

// The pattern by finite differences of f at a generic point: entries that move with the column.
std::vector<std::vector<int>> DifferencedPattern(const pk::internal::OdeSystem& sys, const Eigen::VectorXd& x,
                                                 const Eigen::VectorXd& theta) {
  const int n = sys.n(), m = sys.num_theta();
  std::vector<std::vector<int>> rows(static_cast<size_t>(n + m));
  Eigen::VectorXd f0;
  sys.Rhs(x, theta, &f0);
  for (int k = 0; k < n + m; ++k) {
    Eigen::VectorXd xk = x, tk = theta, f;
    if (k < n) xk(k) *= 1 + 1e-6;
    else tk(k - n) *= 1 + 1e-6;
    sys.Rhs(xk, tk, &f);
    for (int i = 0; i < n; ++i) {
      if (f(i) != f0(i)) rows[static_cast<size_t>(k)].push_back(i);
    }
  }
  return rows;
}

Eigen::VectorXd Spread(const pk::Model& model) {
  Eigen::VectorXd theta = model.default_parameters();
  for (Eigen::Index i = 0; i < theta.size(); ++i) theta(i) *= 1 + 0.1 * static_cast<double>(i);
  return theta;
}

// Bytes of one kept stage of `model` (n numbers with the colouring's lanes), for budgets of kept stages.
long SlotBytes(const pk::Model& model) {
  const auto* ode = dynamic_cast<const pk::OdeModel*>(&model);
  const int width = pk::internal::ColouredJacobian::ColouringOf(*ode)->width;
  return static_cast<long>(sizeof(double)) * model.num_compartments() * (width + 1);
}

std::shared_ptr<pk::Dataset> ChainData() {
  std::ostringstream csv;
  csv << "ID,TIME,AMT,EVID,CMT,DV\n1,0,100,1,1,.\n";
  for (double t : {0.25, 0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0, 16.0, 24.0}) {
    csv << "1," << t << ",0,0,0," << 5 * std::exp(-0.1 * t) + 0.3 << "\n";
  }
  return std::make_shared<pk::Dataset>(pk::ParseDataset(csv.str(), "chain.csv"));
}

pk::ObjectiveOptions RkOptions(double rtol, bool compressed) {
  pk::ObjectiveOptions o;
  o.propagator = pk::Propagator::kRungeKutta;
  o.ode.relative_tolerance = rtol;
  o.ode.absolute_tolerance = rtol * 1e-2;
  o.ode.compressed_jacobians = compressed;
  return o;
}

// A FixedDual<W> copied by construction and by assignment keeps its value and each lane's bits.
template <int W>
bool CopiesEveryLane() {
  pk::FixedDual<W> a(-1.25);
  for (int j = 0; j < W; ++j) a.derivative(j) = 0.5 + j;
  const pk::FixedDual<W> constructed(a);
  pk::FixedDual<W> assigned(7.0);
  assigned = a;
  for (const pk::FixedDual<W>* copy : {&constructed, static_cast<const pk::FixedDual<W>*>(&assigned)}) {
    if (std::memcmp(copy, &a, sizeof a) != 0) return false;
  }
  return true;
}

}  // namespace

TEST_CASE("FixedDual: the values of double and the derivatives of Dual, lane by lane", "[coloured]") {
  for (const auto& ab : {std::pair<double, double>{1.7, 0.4}, {0.3, 2.9}, {5.0, 5.0}}) {
    const double a = ab.first, b = ab.second;
    pk::FixedDual<4> fa(a), fb(b);
    fa.derivative(0) = 1, fa.derivative(2) = 0.5;  // lanes: d/da, 0, d/da/2 + d/db, d/db/3
    fb.derivative(2) = 1, fb.derivative(3) = 1.0 / 3;
    const pk::FixedDual<4> r = Expression(fa, fb);
    const pk::Dual r_ref = Expression(pk::Dual(a, 2, 0), pk::Dual(b, 2, 1));
    CHECK(r.value() == Expression(a, b));  // the same double operations, the same bits
    const double da = r_ref.derivatives()(0), db = r_ref.derivatives()(1);
    const double scale = 1 + std::fabs(da) + std::fabs(db);
    CHECK(std::fabs(r.derivative(0) - da) <= 1e-14 * scale);
    CHECK(r.derivative(1) == 0);
    CHECK(std::fabs(r.derivative(2) - (0.5 * da + db)) <= 1e-14 * scale);
    CHECK(std::fabs(r.derivative(3) - db / 3) <= 1e-14 * scale);
  }
}

TEST_CASE("FixedDual copies its value and every lane, in groups of four, two and one", "[coloured]") {
  CHECK(CopiesEveryLane<4>());
  CHECK(CopiesEveryLane<6>());   // four and two
  CHECK(CopiesEveryLane<8>());
  CHECK(CopiesEveryLane<11>());  // four, four, two and one
}

TEST_CASE("FixedDual where a derivative is infinite: the lanes that do not pass through it stay finite",
          "[coloured]") {
  pk::FixedDual<4> a(0.0), b(2.0), p(0.5);
  a.derivative(0) = 1;
  b.derivative(1) = 1;
  p.derivative(2) = 1;
  const pk::FixedDual<4> results[] = {sqrt(a) + b, pow(a, 0.5) + b, log(a) + b * b, pow(a, p) + b};
  const double db[] = {1, 1, 4, 1};
  for (int r = 0; r < 4; ++r) {
    INFO("expression " << r);
    CHECK(std::isinf(results[r].derivative(0)));
    CHECK(results[r].derivative(1) == db[r]);  // 0·∞ would have made it NaN
    CHECK(results[r].derivative(2) == 0);      // ∂(0^p)/∂p taken as 0 at 0, as pk::TapeScalar does
    CHECK(results[r].derivative(3) == 0);
  }
}

TEST_CASE("SparsityScalar: the inputs each result depends on, and every look at a value counted", "[coloured]") {
  const pk::SparsityScalar a = pk::SparsityScalar::Input(3), b = pk::SparsityScalar::Input(1),
                           c = pk::SparsityScalar::Input(7);
  const long reads = pk::SparsityScalar::ValueReads();
  CHECK(Expression(a, b).inputs() == std::vector<int>{1, 3});
  CHECK((a * 2.0 + exp(c)).inputs() == std::vector<int>{3, 7});
  CHECK(pk::SparsityScalar(4.0).inputs().empty());
  CHECK((pk::SparsityScalar(4.0) * c).inputs() == std::vector<int>{7});
  CHECK(pk::SparsityScalar::ValueReads() == reads);  // abs and fabs above do not look
  const bool less = a < b;
  (void)less;
  const long after_comparison = pk::SparsityScalar::ValueReads();
  CHECK(after_comparison > reads);
  (void)c.value();
  CHECK(pk::SparsityScalar::ValueReads() == after_comparison + 1);
}

TEST_CASE("Jacobian colourings: valid, the differenced pattern, 6 lanes for a chain of any length", "[coloured]") {
  const auto file_branch = pk::ParseModel(kBranchModel, "branch.pkm");
  std::vector<std::shared_ptr<const pk::Model>> models = {Chain(3), Chain(32), Dense(), file_branch};
  for (const char* name : {"1cmt_iv_mm", "1cmt_oral_mm", "2cmt_iv_mm", "1cmt_iv_emax"}) {
    models.push_back(pk::MakeModel(name));
    models.push_back(pk::LoadModelFile(std::string(PK_SOURCE_DIR) + "/models/" + name + ".pkm"));
  }
  int x_lanes_below_theta[2] = {0, 0};  // colourings with the flag false, true (the sweep's two ways)
  for (const auto& model : models) {
    INFO(model->name());
    const auto* ode = dynamic_cast<const pk::OdeModel*>(model.get());
    REQUIRE(ode != nullptr);
    const auto c = pk::internal::ColouredJacobian::ColouringOf(*ode);
    CHECK(ValidColouring(*c));
    CHECK(ValidGather(*c));
    if (c->width > 0) ++x_lanes_below_theta[c->x_lanes_below_theta ? 1 : 0];
    // The pattern holds the differenced one (a structural nonzero may vanish at a point, not the converse).
    const pk::internal::OdeSystem sys(*model);
    Eigen::VectorXd x(sys.n());
    for (int i = 0; i < sys.n(); ++i) x(i) = 3.0 + 0.7 * i;
    const auto differenced = DifferencedPattern(sys, x, Spread(*model));
    // (Not where f looked at a value: its pattern is then that of the branch taken, and unused.)
    for (int k = 0; k < c->n + c->m && !c->looks_at_values; ++k) {
      const std::vector<int> rows(c->rows.begin() + c->column_start[k], c->rows.begin() + c->column_start[k + 1]);
      for (int i : differenced[static_cast<size_t>(k)]) {
        INFO("column " << k << " row " << i);
        CHECK(std::find(rows.begin(), rows.end(), i) != rows.end());
      }
    }
    if (model->name() == "chain") {
      // f_i reads x_{i−1}, x_i and their VMAX and KM: f_x bidiagonal, f_θ 4 a row (2 in the first).
      CHECK(c->column_start.back() == 6 * c->n - 3);
      CHECK(c->colours <= 6);
      if (c->n == 32) CHECK(c->colours == 6);
      CHECK(c->width == (c->colours <= 4 ? 4 : 6));
    } else if (model->name() == "dense9") {
      CHECK(c->colours == 10);  // nine x columns and K, all in every row
      CHECK(c->width == 0);
      CHECK(pk::internal::ColouredJacobian::For(*ode, Spread(*model)) == nullptr);
    } else if (model->name() == "branch") {
      CHECK(c->looks_at_values);
      CHECK(c->width == 0);
    } else {
      CHECK_FALSE(c->looks_at_values);
      CHECK(c->width >= c->colours);
    }
  }
  // Both ways of the sweep occur here (a chain's x lanes are 0 and 1, its θ lanes 2 to 5), and the sweep
  // tests below run models of both.
  CHECK(x_lanes_below_theta[0] > 0);
  CHECK(x_lanes_below_theta[1] > 0);
  // The check can fail: two chain columns that share a row, given one colour.
  auto broken = *pk::internal::ColouredJacobian::ColouringOf(*dynamic_cast<const pk::OdeModel*>(Chain(4).get()));
  broken.colour[1] = broken.colour[0];
  CHECK_FALSE(ValidColouring(broken));
}

TEST_CASE("ColouredJacobian: ‖f_x‖∞ exact, NaN kept from any row, a model whose f throws on the pattern",
          "[coloured]") {
  const auto model = Small("root_decay", 2, RootDecay());
  const auto* ode = dynamic_cast<const pk::OdeModel*>(model.get());
  const Eigen::VectorXd theta = model->default_parameters();
  const auto lanes = pk::internal::ColouredJacobian::For(*ode, theta);
  REQUIRE(lanes != nullptr);
  // f_x = [[−K/(2√x₀), 0], [K, −K2]]: row sums K/4 and K + K2 at x₀ = 4, 16K and K + K2 at 1/1024.
  Eigen::VectorXd x(2);
  x << 4.0, 1.0;
  CHECK(lanes->StateRowSumNorm(x) == theta(0) + theta(1));
  x << 1.0 / 1024, 1.0;
  CHECK(lanes->StateRowSumNorm(x) == 16 * theta(0));
  x << -1.0, 1.0;  // the first row NaN, the second finite and larger than 0
  CHECK(std::isnan(lanes->StateRowSumNorm(x)));
  CHECK_THROWS_AS(pk::internal::ColouredJacobian::For(*ode, Eigen::VectorXd::Ones(3)), std::invalid_argument);

  // RhsSparsity throws: no pattern, no lanes, and the adjoint records f on the tape instead.
  const auto refuses = Small("refuses", 1, Refuses());
  const auto c = pk::internal::ColouredJacobian::ColouringOf(*dynamic_cast<const pk::OdeModel*>(refuses.get()));
  CHECK(c->width == 0);
  CHECK(c->looks_at_values);
  const auto data = ChainData();
  const pk::Objective obj(refuses, data, 0, RkOptions(1e-10, true));
  const Eigen::VectorXd values = obj.DefaultValues();
  const auto adj = obj.Evaluate(values, {0}, Need::kGradient, pk::GradientRoute::kAdjoint);
  const auto fwd = obj.Evaluate(values, {0}, Need::kGradient, pk::GradientRoute::kForward);
  REQUIRE(adj.ok);
  REQUIRE(fwd.ok);
  CHECK(MaxAbs(adj.gradient - fwd.gradient) <= 1e-7 * MaxAbs(fwd.gradient));
}

TEST_CASE("RhsDirectional and OutputDirectional on lanes (k ≤ 8) equal the recording's and Dual's (k > 8)",
          "[coloured]") {
  for (const auto& model : {Chain(5), pk::MakeModel("1cmt_iv_emax"), pk::MakeModel("2cmt_iv_mm"),
                            pk::LoadModelFile(std::string(PK_SOURCE_DIR) + "/models/1cmt_oral_mm.pkm")}) {
    INFO(model->name());
    const auto* ode = dynamic_cast<const pk::OdeModel*>(model.get());
    const int n = ode->num_compartments(), m = ode->num_parameters();
    const Eigen::VectorXd theta = Spread(*model);
    Eigen::VectorXd x(n);
    for (int i = 0; i < n; ++i) x(i) = 2.0 + 1.3 * i;
    // Twelve directions; their first k through each route, k = 3, 6 and 8 on lanes, all 12 not.
    Eigen::MatrixXd dx(n, 12), dtheta(m, 12);
    for (int j = 0; j < 12; ++j) {
      for (int i = 0; i < n; ++i) dx(i, j) = std::sin(1.0 + i + 3.0 * j);
      for (int r = 0; r < m; ++r) dtheta(r, j) = std::cos(2.0 + r + 5.0 * j);
    }
    Eigen::VectorXd f_all, f;
    Eigen::MatrixXd df_all, df;
    ode->RhsDirectional(x, theta, dx, dtheta, &f_all, &df_all);
    double y_all, y;
    Eigen::RowVectorXd dy_all, dy;
    ode->OutputDirectional(1, x, theta, dx, dtheta, &y_all, &dy_all);
    for (int k : {3, 6, 8}) {
      INFO("k = " << k);
      ode->RhsDirectional(x, theta, dx.leftCols(k), dtheta.leftCols(k), &f, &df);
      CHECK(f == f_all);  // f in double either way
      REQUIRE(df.cols() == k);
      CHECK(MaxAbs(df - df_all.leftCols(k)) <= 1e-14 * (1 + MaxAbs(df_all)));
      ode->OutputDirectional(1, x, theta, dx.leftCols(k), dtheta.leftCols(k), &y, &dy);
      CHECK(y == y_all);
      REQUIRE(dy.size() == k);
      CHECK(MaxAbs(dy - dy_all.leftCols(k)) <= 1e-14 * (1 + MaxAbs(dy_all)));
    }
  }
}

TEST_CASE("Directions that miss an infinite partial stay finite on every route, for any number of them",
          "[coloured]") {
  // At x₀ = 0 with K = 0.8, x₀^K and √x₀ have infinite slopes in x₀. Direction 0 moves x₀; the other
  // eleven do not, and their derivatives are finite and the same whether they go on lanes (k ≤ 8), on
  // the recording's tangents (f, k > 8) or on Dual (the output, k > 8): 0·∞ made them NaN on the latter.
  const auto model = Small("power_at_zero", 2, PowerAtZero());
  const auto* ode = dynamic_cast<const pk::OdeModel*>(model.get());
  const Eigen::VectorXd theta = model->default_parameters();
  Eigen::VectorXd x(2);
  x << 0.0, 3.0;
  Eigen::MatrixXd dx = Eigen::MatrixXd::Zero(2, 12), dtheta(2, 12);
  dx(0, 0) = 1;
  for (int j = 0; j < 12; ++j) {
    if (j > 0) dx(1, j) = std::sin(1.0 + 3.0 * j);
    dtheta(0, j) = std::cos(2.0 + 5.0 * j);
    dtheta(1, j) = std::sin(0.5 + 2.0 * j);
  }
  Eigen::VectorXd f8, f12;
  Eigen::MatrixXd df8, df12;
  ode->RhsDirectional(x, theta, dx.leftCols(8), dtheta.leftCols(8), &f8, &df8);
  ode->RhsDirectional(x, theta, dx, dtheta, &f12, &df12);
  double y8, y12;
  Eigen::RowVectorXd dy8, dy12;
  ode->OutputDirectional(1, x, theta, dx.leftCols(8), dtheta.leftCols(8), &y8, &dy8);
  ode->OutputDirectional(1, x, theta, dx, dtheta, &y12, &dy12);
  CHECK(f8 == f12);
  CHECK(y8 == y12);
  for (const auto* d : {&df8, &df12}) CHECK(std::isinf((*d)(1, 0)));
  CHECK(std::isinf(dy8(0)));
  CHECK(std::isinf(dy12(0)));
  for (int j = 1; j < 12; ++j) {
    INFO("direction " << j);
    // f₁ = x₀^K − K2 x₁: along j, −K2 dx₁ − x₁ dK2 (x₀^K's partial in K is 0 at x₀ = 0).
    const double expected_f1 = -theta(1) * dx(1, j) - x(1) * dtheta(1, j);
    CHECK(df12(0, j) == 0);  // −K2 √x₀: √0 · dK2, and x₀ does not move
    CHECK(std::fabs(df12(1, j) - expected_f1) <= 1e-15 * (1 + std::fabs(expected_f1)));
    CHECK(dy12(j) == dx(1, j));
    if (j < 8) {
      CHECK(df8(0, j) == df12(0, j));
      CHECK(df8(1, j) == df12(1, j));
      CHECK(dy8(j) == dy12(j));
    }
  }
}

TEST_CASE("A row f leaves unset is 0 in Rhs, on lanes and on the recording's tangents", "[coloured]") {
  const auto model = Small("unset_row", 2, UnsetRow());
  const auto* ode = dynamic_cast<const pk::OdeModel*>(model.get());
  const Eigen::VectorXd theta = model->default_parameters();
  Eigen::VectorXd x(2), f;
  x << 2.0, 3.0;
  f = Eigen::VectorXd::Constant(2, 7.0);  // stale values that must not survive
  ode->Rhs(x, theta, &f);
  CHECK(f(0) == 0);
  CHECK(f(1) == -theta(0) * x(1) + theta(1) * x(0));
  for (int k : {3, 12}) {
    INFO("k = " << k);
    const Eigen::MatrixXd dx = Eigen::MatrixXd::Ones(2, k), dtheta = Eigen::MatrixXd::Ones(2, k);
    Eigen::VectorXd fd = Eigen::VectorXd::Constant(2, 7.0);
    Eigen::MatrixXd df = Eigen::MatrixXd::Constant(2, k, 7.0);
    ode->RhsDirectional(x, theta, dx, dtheta, &fd, &df);
    CHECK(fd == f);
    CHECK(df.row(0).isZero(0));
    CHECK(df.row(1).isApprox(Eigen::RowVectorXd::Constant(k, -theta(0) - x(1) + theta(1) + x(0))));
  }
}

TEST_CASE("StageTape compressed: each stage's products equal the recording's, over several steps", "[coloured][rk]") {
  for (const auto& model : {Chain(12), pk::MakeModel("1cmt_iv_emax"), pk::MakeModel("2cmt_iv_mm"),
                            pk::MakeModel("1cmt_oral_mm"),
                            pk::LoadModelFile(std::string(PK_SOURCE_DIR) + "/models/1cmt_oral_mm.pkm")}) {
    INFO(model->name());
    const pk::internal::OdeSystem sys(*model);
    const int n = sys.n();
    const Eigen::VectorXd theta = Spread(*model);
    const int steps = 3, stages = 6;
    std::vector<Eigen::VectorXd> points, weights;
    for (int k = 0; k < steps * stages; ++k) {
      Eigen::VectorXd x(n), w(n);
      for (int i = 0; i < n; ++i) {
        x(i) = 5.0 + 3.0 * i + 0.7 * k;
        w(i) = std::sin(1.0 + i + 2.0 * k);
      }
      points.push_back(x);
      weights.push_back(w);
    }
    // The same stages through both, the recording's first (the compressed one does not use the tape).
    std::vector<Eigen::VectorXd> f_of[2], wfx_of[2];
    Eigen::VectorXd theta_of[2];
    for (int compressed = 0; compressed < 2; ++compressed) {
      pk::internal::StageTape tape(sys, theta, compressed == 1);
      CHECK(tape.compressed() == (compressed == 1));
      for (int step = 0; step < steps; ++step) {
        tape.NewStep();
        for (int s = 0; s < stages; ++s) {
          Eigen::VectorXd f;
          tape.Record(points[static_cast<size_t>(step * stages + s)], &f);
          f_of[compressed].push_back(f);
        }
        for (int s = stages - 1; s >= 0; --s) {
          Eigen::VectorXd wfx;
          tape.Sweep(s, weights[static_cast<size_t>(step * stages + s)], &wfx);
          wfx_of[compressed].push_back(wfx);
        }
      }
      theta_of[compressed] = tape.ThetaProduct();
      if (compressed == 1) {
        Eigen::VectorXd wfx;
        CHECK_THROWS_AS(tape.Sweep(stages, weights[0], &wfx), std::logic_error);  // not recorded this step
      }
    }
    for (size_t k = 0; k < f_of[0].size(); ++k) {
      CHECK(f_of[1][k] == f_of[0][k]);  // the same double operations
      CHECK(MaxAbs(wfx_of[1][k] - wfx_of[0][k]) <= 1e-14 * (1 + MaxAbs(wfx_of[0][k])));
    }
    CHECK(MaxAbs(theta_of[1] - theta_of[0]) <= 1e-14 * (1 + MaxAbs(theta_of[0])));
  }
}

TEST_CASE("the discrete adjoint with compressed Jacobians: the recording's gradient, differences, forward",
          "[coloured][rk][gradient]") {
  // Catalogue models over the event scenarios: the same loss, and the gradient of the recording's to
  // rounding (amplified by the sum over steps: measured 1e-13).
  for (const char* name : {"1cmt_oral_mm", "2cmt_iv_mm", "1cmt_iv_emax"}) {
    const auto model = pk::MakeModel(name);
    for (const pk_test::Scenario& sc : pk_test::OdeScenarios()) {
      INFO(name << " / " << sc.name);
      const auto data = pk_test::ScenarioData(sc);
      const pk::Objective compressed(model, data, 0, RkOptions(1e-10, true));
      const pk::Objective recorded(model, data, 0, RkOptions(1e-10, false));
      Eigen::VectorXd values;
      std::vector<int> free;
      pk_test::ScenarioValues(compressed, sc, &values, &free);
      const auto a = compressed.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kAdjoint);
      const auto b = recorded.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kAdjoint);
      REQUIRE(a.ok);
      REQUIRE(b.ok);
      CHECK(a.value == b.value);
      CHECK(MaxAbs(a.gradient - b.gradient) <= 1e-12 * MaxAbs(b.gradient));
    }
  }
  // The chain of 16 (6 lanes for 48 columns) against central differences of the objective solved to
  // 1e-12 and against forward sensitivities. Before the adjoint's forward pass kept its steps within
  // Dormand–Prince's stability boundary (rk_solver.cc, kStableStep) this was 4e-6 off.
  const auto chain = Chain(16);
  const auto data = ChainData();
  const pk::Objective obj(chain, data, 0, RkOptions(1e-10, true));
  const pk::Objective recorded(chain, data, 0, RkOptions(1e-10, false));
  const pk::Objective tight(chain, data, 0, RkOptions(1e-12, true));
  const Eigen::VectorXd values = obj.DefaultValues();
  std::vector<int> free;
  for (int i = 0; i < 32; i += 3) free.push_back(i);
  const auto adj = obj.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kAdjoint);
  const auto rec = recorded.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kAdjoint);
  const auto fwd = obj.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kForward);
  REQUIRE(adj.ok);
  REQUIRE(rec.ok);
  REQUIRE(fwd.ok);
  const Eigen::VectorXd fd = pk_test::CentralDifferences(tight, values, free);
  const double scale = MaxAbs(fwd.gradient);
  INFO("adjoint " << adj.gradient.transpose() << "\nfd      " << fd.transpose());
  CHECK(MaxAbs(adj.gradient - fd) <= 1e-6 * scale);
  CHECK(MaxAbs(adj.gradient - fwd.gradient) <= 1e-8 * scale);
  CHECK(MaxAbs(adj.gradient - rec.gradient) <= 1e-10 * scale);

  // adjoint_store_all_segments = false: the same agreement. (The rk solver stores every segment whatever
  // the option, RkSolver::stores_every_segment, so this is the same route; what it replays backward are
  // steady-state cycles, covered by the scenarios above.)
  pk::ObjectiveOptions replay_options = RkOptions(1e-10, true);
  replay_options.ode.adjoint_store_all_segments = false;
  pk::ObjectiveOptions replay_recorded = replay_options;
  replay_recorded.ode.compressed_jacobians = false;
  const pk::Objective replay(chain, data, 0, replay_options), replay_rec(chain, data, 0, replay_recorded);
  const auto radj = replay.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kAdjoint);
  const auto rrec = replay_rec.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kAdjoint);
  REQUIRE(radj.ok);
  REQUIRE(rrec.ok);
  CHECK(MaxAbs(radj.gradient - rrec.gradient) <= 1e-10 * scale);
  CHECK(MaxAbs(radj.gradient - fd) <= 1e-6 * scale);
  CHECK(MaxAbs(radj.gradient - fwd.gradient) <= 1e-8 * scale);
}

namespace {

// Sets which clone pk::internal::CallOnLanes takes, and restores it.
class LanesClone {
 public:
  // The clone only where the CPU runs it (elsewhere its instructions would fault): the baseline then.
  explicit LanesClone(bool avx2) : saved_(pk::internal::LanesOnAvx2()) {
    pk::internal::LanesOnAvx2() = avx2 && pk::internal::CpuRunsAvx2Clone();
  }
  ~LanesClone() { pk::internal::LanesOnAvx2() = saved_; }
  LanesClone(const LanesClone&) = delete;
  LanesClone& operator=(const LanesClone&) = delete;

 private:
  bool saved_;
};

template <int W>
struct FixedDualBits {
  double value = 0;
  double lanes[W] = {};
  bool operator==(const FixedDualBits& o) const {
    return std::memcmp(this, &o, sizeof *this) == 0;  // NaN and −0 compared as bits
  }
};

template <int W>
FixedDualBits<W> ExpressionOnLanes(bool avx2) {
  pk::FixedDual<W> a(1.7), b(0.6);
  for (int j = 0; j < W; ++j) {
    a.derivative(j) = std::sin(1.0 + j);
    b.derivative(j) = std::cos(2.0 + 3 * j);
  }
  FixedDualBits<W> out;
  const LanesClone clone(avx2);
  pk::internal::CallOnLanes([&] {
    const pk::FixedDual<W> r = Expression(a, b);
    out.value = r.value();
    for (int j = 0; j < W; ++j) out.lanes[j] = r.derivative(j);
  });
  return out;
}

// A Michaelis–Menten model with an oral depot, written as model text (an interpreted program on lanes).
const char kTextModel[] = R"($PROBLEM text  oral depot, saturable elimination
$PARAM
KA   = 1.2 1/h
VMAX = 20  mg/h
KM   = 2   mg/L
V    = 30  L
$CMT
DEPOT    dose
CENTRAL  central
$ODE
C = CENTRAL / V
d/dt(DEPOT) = -KA * DEPOT
d/dt(CENTRAL) = KA * DEPOT - VMAX * C / (KM + C)
$OUTPUT
CP = C
)";

}  // namespace

TEST_CASE("The AVX2 clone of f on lanes and of the sweep gives the baseline's bits", "[coloured][rk][gradient]") {
  if (!pk::internal::CpuRunsAvx2Clone()) {
    WARN("this build or CPU has no AVX2 clone: both halves of each comparison run the baseline lanes");
  }
  // Every operation and function of FixedDual, at each width libpk uses.
  CHECK(ExpressionOnLanes<4>(true) == ExpressionOnLanes<4>(false));
  CHECK(ExpressionOnLanes<6>(true) == ExpressionOnLanes<6>(false));
  CHECK(ExpressionOnLanes<8>(true) == ExpressionOnLanes<8>(false));
  // The adjoint (f on lanes and the sweeps) and forward sensitivities (f on lanes for k ≤ 8): a
  // catalogue model over every event scenario, model text, and the chain (6 lanes, 4 of them θ's).
  struct Case {
    std::shared_ptr<const pk::Model> model;
    std::shared_ptr<pk::Dataset> data;
    const pk_test::Scenario* scenario;
  };
  std::vector<Case> cases;
  for (const pk_test::Scenario& sc : pk_test::OdeScenarios()) {
    cases.push_back({pk::MakeModel("1cmt_oral_mm"), pk_test::ScenarioData(sc), &sc});
  }
  cases.push_back({pk::ParseModel(kTextModel, "text.pkm"), ChainData(), nullptr});
  cases.push_back({Chain(16), ChainData(), nullptr});
  for (const Case& c : cases) {
    INFO(c.model->name() << " / " << (c.scenario ? c.scenario->name : "one bolus"));
    const pk::Objective obj(c.model, c.data, 0, RkOptions(1e-8, true));
    Eigen::VectorXd values = obj.DefaultValues();
    std::vector<int> free;
    for (int i = 0; i < c.model->num_parameters(); ++i) free.push_back(i);
    if (c.scenario != nullptr) pk_test::ScenarioValues(obj, *c.scenario, &values, &free);
    for (const auto route : {pk::GradientRoute::kAdjoint, pk::GradientRoute::kForward}) {
      pk::Objective::Evaluation on, off;
      {
        const LanesClone clone(true);
        on = obj.Evaluate(values, free, Need::kGradient, route);
      }
      {
        const LanesClone clone(false);
        off = obj.Evaluate(values, free, Need::kGradient, route);
      }
      REQUIRE(on.ok);
      REQUIRE(off.ok);
      CHECK(on.value == off.value);
      CHECK(on.gradient == off.gradient);
    }
  }
}

TEST_CASE("The rk adjoint on the stages its forward pass kept gives the recomputing adjoint's bits",
          "[coloured][rk][gradient]") {
  // OdeOptions::adjoint_keeps_stages: the forward pass evaluates f on the lanes, keeps each stage, and
  // the backward pass sweeps them; false evaluates the stages again from each step's start. The same
  // points, the same sweeps in the same order: the same loss and gradient to the bit, including the
  // steady-state scenarios (whose cycles are replayed segment by segment in the backward pass,
  // RkSolver::AdjointSegment) and a segment that stiffens and is handed to RODAS4 midway. A kept stage
  // off by one slot (measured: 33 of 180 checks fail) or a rejected try's stage kept changes the bits;
  // the kept route is seen to run by what it stores.
  struct Case {
    std::shared_ptr<const pk::Model> model;
    std::shared_ptr<pk::Dataset> data;
    const pk_test::Scenario* scenario;
    double km = 0;  // > 0: KM set to it
  };
  std::vector<Case> cases;
  for (const char* name : {"1cmt_oral_mm", "2cmt_iv_mm"}) {
    for (const pk_test::Scenario& sc : pk_test::OdeScenarios()) {
      cases.push_back({pk::MakeModel(name), pk_test::ScenarioData(sc), &sc});
    }
  }
  cases.push_back({pk::ParseModel(kTextModel, "text.pkm"), ChainData(), nullptr});
  cases.push_back({Chain(16), ChainData(), nullptr});
  // A segment that stiffens as the drug clears (KM far below the concentrations): Dormand–Prince's
  // steps are given up midway and RODAS4 takes it from its start (test_rk.cc).
  cases.push_back({pk::MakeModel("1cmt_iv_mm"),
                   std::make_shared<pk::Dataset>(pk::ParseDataset(
                       "ID,TIME,AMT,EVID,DV\n1,0,100,1,.\n1,0.5,0,0,4\n1,2,0,0,3\n1,48,0,0,0.01\n1,72,0,0,0.001\n",
                       "stiffening.csv")),
                   nullptr, 0.002});
  for (const Case& c : cases) {
    INFO(c.model->name() << " / " << (c.scenario ? c.scenario->name : "one bolus"));
    pk::ObjectiveOptions kept = RkOptions(1e-8, true), again = kept;
    again.ode.adjoint_keeps_stages = false;
    const pk::Objective recomputing(c.model, c.data, 0, again);
    Eigen::VectorXd values = recomputing.DefaultValues();
    std::vector<int> free;
    for (int i = 0; i < c.model->num_parameters(); ++i) free.push_back(i);
    if (c.scenario != nullptr) pk_test::ScenarioValues(recomputing, *c.scenario, &values, &free);
    if (c.km > 0) values(recomputing.ParameterIndex("KM")) = c.km;
    const auto b = recomputing.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kAdjoint);
    REQUIRE(b.ok);
    // Budgets of kept stages (OdeOptions::adjoint_kept_stage_bytes): one step's (the first segment's
    // first step; its later ones are evaluated again on the same lanes), every stage (none runs out), a
    // third of that, and this machine's default: the same bits whichever steps were kept. One step's
    // comes first: the thread's slots would otherwise hold every stage of this very evaluation from
    // before, and a step past the kept ones read from them would go unseen. What is kept shows in the
    // storage beyond the recomputing adjoint's.
    const long slot_bytes = SlotBytes(*c.model);
    const auto adjoint = [&](long budget) {
      kept.ode.adjoint_kept_stage_bytes = budget;
      const pk::Objective objective(c.model, c.data, 0, kept);
      const auto a = objective.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kAdjoint);
      REQUIRE(a.ok);
      CHECK(a.value == b.value);
      CHECK(a.gradient == b.gradient);
      if (c.km > 0) CHECK(a.ode_statistics.stiff_steps > 0);  // RODAS4 took the stiffening segment
      return a.ode_statistics.peak_adjoint_bytes - b.ode_statistics.peak_adjoint_bytes;
    };
    {
      INFO("one step's budget");
      CHECK(adjoint(10 * slot_bytes) == 7 * slot_bytes);  // its 6 stages and the next one's first
    }
    const long every_stage = adjoint(std::numeric_limits<long>::max());
    CHECK(every_stage > 7 * slot_bytes);
    {
      INFO("a third of every stage");
      const long third = adjoint(every_stage / 3);
      CHECK(third > 0);
      CHECK(third < every_stage);
    }
    {
      INFO("the default budget");
      CHECK(adjoint(0) > 0);
      const long l2 = sysconf(_SC_LEVEL2_CACHE_SIZE);  // the default: half of it, 512 KiB when unknown
      CHECK(adjoint(0) == adjoint(l2 > 0 ? l2 / 2 : 512L * 1024));
    }
  }
}

TEST_CASE("A negative budget of kept stages is an invalid option", "[coloured][rk]") {
  pk::OdeOptions o;
  std::string why;
  CHECK(o.IsValid(&why));
  o.adjoint_kept_stage_bytes = 0;
  CHECK(o.IsValid(&why));
  o.adjoint_kept_stage_bytes = -1;
  CHECK_FALSE(o.IsValid(&why));
  CHECK(why == "the adjoint's budget of kept stages must be >= 0 bytes");
}

TEST_CASE("The rk adjoint keeps stages while the next step's fit in the budget, and switches midway",
          "[coloured][rk][gradient]") {
  // One segment of many steps (a bolus, one sample 2 h later, before the chain stiffens as the drug
  // clears and RODAS4 takes the segment): a step's 6 stages and the next step's
  // first slope take 7 slots, each further step 6 more. A budget of 12 slots keeps one step, 13 keep two,
  // 6 none; the segment's later steps are evaluated again backward on the same lanes, to the same bits.
  const auto chain = Chain(4);
  const auto data = std::make_shared<pk::Dataset>(
      pk::ParseDataset("ID,TIME,AMT,EVID,CMT,DV\n1,0,100,1,1,.\n1,2,0,0,0,1\n", "one_segment.csv"));
  pk::ObjectiveOptions kept = RkOptions(1e-8, true), again = kept;
  again.ode.adjoint_keeps_stages = false;
  const pk::Objective recomputing(chain, data, 0, again);
  const Eigen::VectorXd values = recomputing.DefaultValues();
  std::vector<int> free;
  for (int i = 0; i < chain->num_parameters(); ++i) free.push_back(i);
  const auto b = recomputing.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kAdjoint);
  REQUIRE(b.ok);
  REQUIRE(b.ode_statistics.steps > 5);  // the budgets below run out midway
  REQUIRE(b.ode_statistics.stiff_steps == 0);
  const long slot = SlotBytes(*chain);
  for (const std::pair<long, long>& budget_kept : {std::pair<long, long>{13, 13}, {12, 7}, {6, 0}, {19, 19}}) {
    INFO("a budget of " << budget_kept.first << " slots");
    kept.ode.adjoint_kept_stage_bytes = budget_kept.first * slot;
    const pk::Objective objective(chain, data, 0, kept);
    const auto a = objective.Evaluate(values, free, Need::kGradient, pk::GradientRoute::kAdjoint);
    REQUIRE(a.ok);
    CHECK(a.value == b.value);
    CHECK(a.gradient == b.gradient);
    CHECK(a.ode_statistics.peak_adjoint_bytes - b.ode_statistics.peak_adjoint_bytes == budget_kept.second * slot);
  }
}

TEST_CASE("Stage lanes of a model that leaves a row unset or adds to it start from 0 at every step",
          "[coloured]") {
  const auto chain = Chain(4);
  CHECK(pk::internal::ColouredJacobian::ColouringOf(*dynamic_cast<const pk::OdeModel*>(chain.get()))->sets_every_row);
  for (const auto& model : {Small("unset_row", 2, UnsetRow()), Small("adds_to_row", 2, AddsToRow())}) {
    INFO(model->name());
    const auto* ode = dynamic_cast<const pk::OdeModel*>(model.get());
    const Eigen::VectorXd theta = model->default_parameters();
    CHECK_FALSE(pk::internal::ColouredJacobian::ColouringOf(*ode)->sets_every_row);
    const auto lanes = pk::internal::ColouredJacobian::For(*ode, theta);
    REQUIRE(lanes != nullptr);
    Eigen::VectorXd x(2), f, expected, wfx;
    x << 2.0, 3.0;
    ode->Rhs(x, theta, &expected);
    const Eigen::Vector2d w(1.0, 0.0);  // picks row 0 of f_x: 0 (unset), or −K (added to)
    for (int step = 0; step < 3; ++step) {
      lanes->NewStep();
      lanes->Record(x, &f);
      CHECK(f == expected);
      lanes->Sweep(0, w, &wfx);
      CHECK(wfx(0) == (model->name() == "unset_row" ? 0.0 : -theta(0)));
    }
  }
}

TEST_CASE("StateJacobian into a kept matrix, models of other n and m in turn: f_x as from the unit directions",
          "[coloured]") {
  // Its unit and zero directions are kept per thread and remade when n or m changes: (2, 2), (2, 4)
  // and (3, 6) in turn, twice, each against f_x from directions made for the call (m growing at the
  // same n would read past a zero matrix kept too small).
  const std::vector<std::shared_ptr<const pk::Model>> models = {Small("unset_row", 2, UnsetRow()), Chain(2),
                                                                Chain(3)};
  Eigen::MatrixXd kept;
  for (int round = 0; round < 2; ++round) {
    for (const auto& model : models) {
      INFO(model->name() << " with " << model->num_parameters() << " parameters, round " << round);
      const auto* ode = dynamic_cast<const pk::OdeModel*>(model.get());
      const int n = model->num_compartments(), m = model->num_parameters();
      const Eigen::VectorXd theta = Spread(*model), x = Eigen::VectorXd::LinSpaced(n, 1.5, 4.0);
      Eigen::VectorXd f;
      Eigen::MatrixXd expected;
      ode->RhsDirectional(x, theta, Eigen::MatrixXd::Identity(n, n), Eigen::MatrixXd::Zero(m, n), &f, &expected);
      const pk::internal::OdeSystem sys(*model);
      sys.StateJacobian(x, theta, &kept);
      CHECK(kept == expected);
      CHECK(sys.StateJacobian(x, theta) == expected);
    }
  }
}
