#include "objective/output_offsets.h"

#include <map>
#include <utility>

#include "exact/exact_routes.h"
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

void AddOutputOffsetDerivatives(const LinearModel& model, const PreparedSubject& s,
                                const std::vector<DualVector>& sets,
                                const std::vector<std::array<int, 3>>& directions, std::vector<Eigen::VectorXd>* out) {
  const int m = model.num_parameters();
  for (size_t t = 0; t < directions.size(); ++t) {
    const std::array<int, 3>& dir = directions[t];
    const int part = dir[2] < 0 ? 3 : 7;  // ∂²d along dir[0], dir[1]; or ∂³d along all three
    std::map<std::pair<int, int>, double> done;
    ForEachOffsetSample(model, s, [&](int k, int key, int set) {
      auto it = done.find({key, set});
      if (it == done.end()) {
        const std::vector<HyperDual3> extended =
            ExtendedThird(model, SeedParameters(sets[static_cast<size_t>(set)], m, dir));
        HyperDual3 d(0.0);
        for (const LinearTerm& term : model.output_offset_terms(key)) {
          d = d + LinearModel::TermValue<HyperDual3>(term, [&](int i) { return extended[static_cast<size_t>(i)]; });
        }
        it = done.emplace(std::make_pair(key, set), d.part(part)).first;
      }
      (*out)[t](k) += it->second;
    });
  }
}

}  // namespace internal
}  // namespace pk
