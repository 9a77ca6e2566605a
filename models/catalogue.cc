// The registry that names the catalogue models.
#include "pk/catalogue.h"

#include <functional>
#include <utility>

#include "catalogue_models.h"
#include "pk/error.h"
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
  };
  return registry;
}

}  // namespace

std::vector<std::string> CatalogueModelNames() {
  std::vector<std::string> names;
  for (const auto& entry : Registry()) names.push_back(entry.first);
  return names;
}

std::shared_ptr<const Model> MakeModel(const std::string& name) {
  for (const auto& entry : Registry()) {
    if (internal::ToUpper(entry.first) == internal::ToUpper(name)) return entry.second();
  }
  throw InputError("", 0, 0, "unknown model '" + name + "'; the catalogue has " +
                                 internal::Join(CatalogueModelNames(), ", "));
}

}  // namespace pk
