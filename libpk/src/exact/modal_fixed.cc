// The modal evaluator for 2 to 4 states, sizes fixed at compile time (its own
// translation unit: see modal_evaluator.h).
#include "modal_evaluator.h"

namespace pk {
namespace internal {

std::unique_ptr<ModalEvaluator> NewFixedSizeModal(const LinearModel& model) {
  using modal_detail::Modal;
  switch (model.num_compartments()) {
    case 2: return std::unique_ptr<ModalEvaluator>(new Modal<2, 2>(model));
    case 3: return std::unique_ptr<ModalEvaluator>(new Modal<3, 3>(model));
    case 4: return std::unique_ptr<ModalEvaluator>(new Modal<4, 4>(model));
    default: return nullptr;
  }
}

}  // namespace internal
}  // namespace pk
