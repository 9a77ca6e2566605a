#!/usr/bin/env bash
# Installs what is missing, builds, and runs every test: once in an optimised
# build, once under AddressSanitizer + UBSan.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/install-deps.sh
jobs=$(nproc 2>/dev/null || echo 2)
# Ninja for a new tree (CMake keeps an existing tree's generator, and refuses to change it).
generator() { [ -f "$1/CMakeCache.txt" ] || echo "-GNinja"; }

# The optimised tree is compiled a file at a time, as users and demo.sh build it (whose tree this is),
# so that a source missing an #include fails here; the sanitizer tree below is a unity build.
cmake -S . -B build $(generator build) -DCMAKE_BUILD_TYPE=Release -DPK_UNITY_BUILD=OFF >/dev/null
cmake --build build -j "$jobs"
ctest --test-dir build --output-on-failure -j "$jobs"

# -g1: line tables for the sanitizers' stack traces, at a fraction of -g's build time. Clang (installed
# for the fuzzer): it compiles this tree under ASan+UBSan in about 0.8 of GCC's time (10.3 → 8.1 min
# on two cores), the largest step of this script; the optimised build above stays GCC's. A unity build
# (PK_UNITY_BUILD: sources compiled in batches of eight): 428 s here with Ninja, where a file at a time
# took 552 (docs/performance.md §11).
CC=clang CXX=clang++ cmake -S . -B build-asan $(generator build-asan) -DPK_SANITIZE=ON \
      -DCMAKE_BUILD_TYPE=RelWithDebInfo -DPK_BUILD_BENCHMARKS=OFF \
      -DPK_UNITY_BUILD=ON -DCMAKE_CXX_FLAGS_RELWITHDEBINFO="-O1 -g1" >/dev/null
cmake --build build-asan -j "$jobs"
ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
  ctest --test-dir build-asan --output-on-failure -j "$jobs"

# The dataset reader and its filters under libFuzzer for a short budget on every core (fork mode: 370 000
# inputs in a CI run, where 30 s of one process ran 260 000; scripts/fuzz.sh N for longer).
scripts/fuzz.sh 20
