#include "objective/output_offsets.h"

#include <map>
#include <utility>

#include "exact/exact_routes.h"
#include "exact/second_order.h"
#include "exact/third_order.h"
#include "pk/hyper_dual.h"

namespace pk {
namespace internal {
namespace {

// Calls visit(k, key, set) for each sample k whose output row (key, 1-based) has an offset.
template <class Visit>
void ForEachOffsetSample(const LinearModel& model, const PreparedSubject& s, const Visit& visit) {
  int count = 0;
  const std::vector<int> sample = SampleIndex(s, &count);
  for (size_t r = 0; r < sample.size(); ++r) {
    const int key = s.cmt[r] + 1;
    if (sample[r] < 0 || model.output_offset_terms(key).empty()) continue;
    visit(sample[r], key, s.set_of_record[r]);
  }
}

// The model parameters of a set on HyperDual3 along `dir`: part 1 << c is the derivative along
// dir[c]. They enter linearly in the free parameters (hyper_dual_sets.h), so no mixed parts.
std::vector<HyperDual3> SeedParameters(const DualVector& set, int m, const std::array<int, 3>& dir) {
  std::vector<HyperDual3> theta(static_cast<size_t>(m));
  for (int j = 0; j < m; ++j) {
    HyperDual3& t = theta[static_cast<size_t>(j)];
    t = HyperDual3(set(j).value());
    const auto& d = set(j).derivatives();  // empty for a constant
    if (d.size() == 0) continue;
    for (int c = 0; c < 3; ++c) {
      if (dir[static_cast<size_t>(c)] >= 0) t.part(1 << c) = d(dir[static_cast<size_t>(c)]);
    }
  }
  return theta;
}

// The offset of row `key` on [θ; ψ] of any scalar type.
template <typename T, typename Extended>
T OffsetOn(const LinearModel& model, int key, const Extended& extended) {
  T d(0.0);
  for (const LinearTerm& term : model.output_offset_terms(key)) {
    d = d + LinearModel::TermValue<T>(term, [&](int i) { return extended[static_cast<size_t>(i)]; });
  }
  return d;
}

}  // namespace

void AddOutputOffsets(const LinearModel& model, const PreparedSubject& s, Eigen::VectorXd* yhat) {
  const int m = model.num_parameters();
  ForEachOffsetSample(model, s, [&](int k, int key, int set) {
    (*yhat)(k) += model.OutputOffset<double>(key, s.sets[static_cast<size_t>(set)].head(m));
  });
}

Eigen::MatrixXd OutputOffsetJacobian(const LinearModel& model, const PreparedSubject& s,
                                     const std::vector<DualVector>& sets, int num_free) {
  const int m = model.num_parameters();
  int count = 0;
  SampleIndex(s, &count);
  Eigen::MatrixXd jacobian = Eigen::MatrixXd::Zero(count, num_free);
  std::map<std::pair<int, int>, Eigen::VectorXd> done;  // per (key, set): a set is shared by many samples
  ForEachOffsetSample(model, s, [&](int k, int key, int set) {
    auto it = done.find({key, set});
    if (it == done.end()) {
      const DualVector theta = sets[static_cast<size_t>(set)].head(m);
      const Dual d = model.OutputOffset<Dual>(key, theta);
      Eigen::VectorXd g = Eigen::VectorXd::Zero(num_free);
      if (d.derivatives().size() == num_free) g = d.derivatives();
      it = done.emplace(std::make_pair(key, set), std::move(g)).first;
    }
    jacobian.row(k) = it->second.transpose();
  });
  return jacobian;
}

void AddOutputOffsetDerivatives(const LinearModel& model, const PreparedSubject& s, const std::vector<DualVector>& sets,
                                int num_free, const std::vector<std::array<int, 3>>& directions,
                                std::vector<Eigen::VectorXd>* out) {
  const int m = model.num_parameters();
  for (size_t t = 0; t < directions.size(); ++t) {
    const std::array<int, 3>& dir = directions[t];
    std::map<std::pair<int, int>, double> done;  // per (key, set)
    ForEachOffsetSample(model, s, [&](int k, int key, int set) {
      auto it = done.find({key, set});
      if (it == done.end()) {
        const DualVector& theta = sets[static_cast<size_t>(set)];
        double part = 0;
        if (dir[2] < 0) {  // ∂²d along dir[0], dir[1]: ψ's second order (evaluate_second) suffices
          part = OffsetOn<HyperDual>(model, key, ExtendedSecond(model, theta, num_free, dir[0], dir[1])).e12();
        } else {  // ∂³d along all three
          part = OffsetOn<HyperDual3>(model, key, ExtendedThird(model, SeedParameters(theta, m, dir))).part(7);
        }
        it = done.emplace(std::make_pair(key, set), part).first;
      }
      (*out)[t](k) += it->second;
    });
  }
}

}  // namespace internal
}  // namespace pk
