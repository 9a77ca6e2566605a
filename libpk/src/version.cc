#include "pk/version.h"

namespace pk {

// PK_VERSION is defined by libpk/CMakeLists.txt from the project's version.
const char* Version() { return PK_VERSION; }

}  // namespace pk
