// The registry that names the catalogue models.
#include "pk/catalogue.h"

#include <cstdlib>
#include <functional>
#include <utility>

#include "catalogue_models.h"
#include "pk/error.h"
#include "pk/model_file.h"
#include "internal_text.h"

namespace pk {
namespace {

using Factory = std::function<std::shared_ptr<const Model>()>;

const std::vector<std::pair<std::string, Factory>>& Registry() {
  static const std::vector<std::pair<std::string, Factory>> registry = {
      {"1cmt_iv", models::OneCmtIv},   {"1cmt_oral", models::OneCmtOral},
      {"2cmt_iv", models::TwoCmtIv},   {"2cmt_oral", models::TwoCmtOral},
      {"3cmt_iv", models::ThreeCmtIv}, {"3cmt_oral", models::ThreeCmtOral},
      {"tf1", [] { return models::TransferFunction(1); }}, {"tf2", [] { return models::TransferFunction(2); }},
      {"tf3", [] { return models::TransferFunction(3); }}, {"tf4", [] { return models::TransferFunction(4); }},
      {"1cmt_iv_mm", models::OneCmtIvMm},     {"1cmt_oral_mm", models::OneCmtOralMm},
      {"2cmt_iv_mm", models::TwoCmtIvMm},     {"1cmt_oral_transit", [] { return models::OneCmtOralTransit(3); }},
      {"1cmt_iv_emax", models::OneCmtIvEmax},
  };
  return registry;
}

}  // namespace

std::vector<std::string> CatalogueModelNames() {
  std::vector<std::string> names;
  for (const auto& entry : Registry()) names.push_back(entry.first);
  return names;
}

std::shared_ptr<const Model> MakeModel(const std::string& spec, RandomEffects etas) {
  // A model file: a name ending in .pkm, or a path.
  const bool file = (spec.size() > 4 && internal::ToLower(spec.substr(spec.size() - 4)) == ".pkm") ||
                    spec.find('/') != std::string::npos;
  if (file) return LoadModelFile(spec, etas);
  // Model options follow the name: "1cmt_oral_transit:NTR=5".
  const size_t colon = spec.find(':');
  const std::string name = spec.substr(0, colon);
  if (colon != std::string::npos) {
    const std::string option = internal::ToUpper(spec.substr(colon + 1));
    if (internal::ToUpper(name) != "1CMT_ORAL_TRANSIT" || option.rfind("NTR=", 0) != 0) {
      throw InputError("model '" + name + "' has no option '" + spec.substr(colon + 1) +
                                     "' (only 1cmt_oral_transit takes one: NTR=<1..50>)");
    }
    char* end = nullptr;
    const long ntr = std::strtol(option.c_str() + 4, &end, 10);
    if (*end != '\0' || end == option.c_str() + 4 || ntr < 1 || ntr > 50) {
      throw InputError("NTR must be an integer from 1 to 50, not '" + option.substr(4) + "'");
    }
    return models::OneCmtOralTransit(static_cast<int>(ntr));
  }
  for (const auto& entry : Registry()) {
    if (internal::ToUpper(entry.first) == internal::ToUpper(name)) return entry.second();
  }
  const std::string closest = ClosestName(name, CatalogueModelNames());
  throw InputError("unknown model '" + name + "'" + (closest.empty() ? "" : " (did you mean " + closest + "?)") +
                   "; give a model file (NAME.pkm) or a model of the catalogue, which has " +
                   internal::Join(CatalogueModelNames(), ", "));
}

}  // namespace pk
