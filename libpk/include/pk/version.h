// libpk: the library's version, as the apps print it with --version and the reports state it.
#ifndef PK_VERSION_H_
#define PK_VERSION_H_

namespace pk {

/// "MAJOR.MINOR.PATCH" of the libpk that was built (CMake's project version).
const char* Version();

}  // namespace pk

#endif  // PK_VERSION_H_
