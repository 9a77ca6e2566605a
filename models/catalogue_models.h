// The catalogue models, one short file each (not installed).
#ifndef PK_MODELS_CATALOGUE_MODELS_H_
#define PK_MODELS_CATALOGUE_MODELS_H_

#include <memory>

#include "pk/linear_model.h"
#include "pk/ode_model.h"

namespace pk {
namespace models {

std::shared_ptr<const LinearModel> OneCmtIv();
std::shared_ptr<const LinearModel> OneCmtOral();
std::shared_ptr<const LinearModel> TwoCmtIv();
std::shared_ptr<const LinearModel> TwoCmtOral();
std::shared_ptr<const LinearModel> ThreeCmtIv();
std::shared_ptr<const LinearModel> ThreeCmtOral();
std::shared_ptr<const LinearModel> TransferFunction(int order);
std::shared_ptr<const LinearModel> OneCmtOralTransit(int num_transit);
std::shared_ptr<const OdeModel> OneCmtIvMm();
std::shared_ptr<const OdeModel> OneCmtOralMm();
std::shared_ptr<const OdeModel> TwoCmtIvMm();
std::shared_ptr<const OdeModel> OneCmtIvEmax();

}  // namespace models
}  // namespace pk

#endif  // PK_MODELS_CATALOGUE_MODELS_H_
