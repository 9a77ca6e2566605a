#!/usr/bin/env bash
# Installs the built libpk into a scratch prefix, then configures, builds and
# runs a consumer project against it with find_package(libpk).
set -euo pipefail
build_dir=$1; src=$2; work=$3
rm -rf "$work"; mkdir -p "$work"
cmake --install "$build_dir" --prefix "$work/prefix" >/dev/null
# The library's own compiler: Eigen's allocation differs between compilers under ASan (GCC defines
# __SANITIZE_ADDRESS__ and Eigen then aligns by hand; clang does not), so objects cannot cross.
compiler=$(sed -n 's/^CMAKE_CXX_COMPILER:[A-Z]*=//p' "$build_dir/CMakeCache.txt")
extra=(-DCMAKE_CXX_COMPILER="$compiler")
if grep -q "PK_SANITIZE:BOOL=ON" "$build_dir/CMakeCache.txt"; then
  extra+=(-DCMAKE_CXX_FLAGS="-fsanitize=address,undefined" -DCMAKE_EXE_LINKER_FLAGS="-fsanitize=address,undefined")
fi
cmake -S "$src" -B "$work/build" -DCMAKE_PREFIX_PATH="$work/prefix" "${extra[@]}" >/dev/null
cmake --build "$work/build" >/dev/null
"$work/build/consumer"
