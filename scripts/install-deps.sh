#!/usr/bin/env bash
# Installs, with apt-get, only the Debian 12 packages libpk needs that are missing.
set -euo pipefail

packages=(
  g++ cmake make                    # toolchain
  ninja-build                       # scripts/test.sh's builds: starts a target's sources as soon as they are ready
  clang                             # libFuzzer for the dataset reader's fuzz target (scripts/fuzz.sh)
  libeigen3-dev                     # linear algebra, matrix exponential, AutoDiff
  libsundials-dev                   # CVODES (ODE propagator)
  libnlopt-cxx-dev                  # NLopt optimisers
  libcminpack-dev                   # MINPACK's lmder (Levenberg-Marquardt)
  libboost-program-options-dev      # command-line parsing in the apps
  libfccp-dev                       # CSV line reading
  catch2                            # unit tests (Catch2 v2)
  libbenchmark-dev                  # benchmarks
  libkainjow-mustache-dev           # pkfit's HTML report is rendered from a template
  nlohmann-json3-dev                # pkfit's machine-readable run summary (summary.json)
  libfmt-dev                        # shortest digits of a double (Dragonbox), for pksim's output
  chromium                          # the report's screenshot test (tests/cli/test_report.sh)
  fonts-dejavu-core                 # a font for Chromium to render the report with
  locales                           # localedef's sources: the tests read and write numbers under a comma-decimal locale
  libopenmpi-dev openmpi-bin        # pkpop across MPI processes (pk::mpi), and its mpirun test
)

missing=()
for p in "${packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done
if [ ${#missing[@]} -eq 0 ]; then
  exit 0
fi
echo "install-deps: installing ${missing[*]}"
SUDO=""
if [ "$(id -u)" -ne 0 ]; then
  command -v sudo >/dev/null || { echo "install-deps: need root (or sudo) to install ${missing[*]}" >&2; exit 1; }
  SUDO=sudo
fi
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
