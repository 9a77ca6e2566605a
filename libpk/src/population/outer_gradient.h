// The gradient of a subject's OFV_i with respect to the packed population parameters x, by the
// implicit function theorem on its conditional mode (not installed; outer_gradient.cc has the
// formulas, docs/population.md derives them). FO (at η = 0, which does not move), FOCE and FOCEI
// from first and second derivatives of the predictions; Laplace, whose OFV_i holds log det of the
// exact ½∇²l, from third ones too.
#ifndef PK_SRC_POPULATION_OUTER_GRADIENT_H_
#define PK_SRC_POPULATION_OUTER_GRADIENT_H_

#include <string>

#include <Eigen/Core>

#include "population/conditional.h"
#include "population/packing.h"

namespace pk {
namespace internal {

/// dOFV_i/dx at x (p = packing.Unpack(x) made into a point), given the subject's mode at p.
/// False with `why` when the predictions or their sensitivities cannot be evaluated there.
/// *differenced says why the predictions' second derivatives were differences of the exact first
/// ones (the higher orders failed: Objective::SecondDerivatives' `why`), and is empty when the second-order
/// sensitivities served. Laplace then fails (`why`): its H was differenced too.
bool SubjectOuterGradient(const SubjectModel& s, const PopulationPoint& p, const Packing& packing,
                          const Eigen::VectorXd& x, const SubjectMode& mode, Eigen::VectorXd* gradient,
                          std::string* differenced, std::string* why);

}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_POPULATION_OUTER_GRADIENT_H_
