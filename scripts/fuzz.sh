#!/usr/bin/env bash
# Fuzzes the dataset reader and its IGNORE/ACCEPT filters with libFuzzer (clang) for SECONDS
# (default 30) on every core (libFuzzer's fork mode: one fuzzing process a core, their corpora merged),
# after running every saved regression input once. Seeds: the bundled datasets and
# tests/fuzz/regressions/; dictionary: tests/fuzz/dataset.dict. A finding is saved in build-fuzz/
# as crash-* and fails the run; add it to tests/fuzz/regressions/ once fixed.
#
#   scripts/fuzz.sh           # 30 s, as scripts/test.sh runs it
#   scripts/fuzz.sh 3600      # an hour
set -euo pipefail
cd "$(dirname "$0")/.."
seconds=${1:-30}
jobs=$(nproc 2>/dev/null || echo 2)
CC=clang CXX=clang++ cmake -S . -B build-fuzz -DCMAKE_BUILD_TYPE=RelWithDebInfo -DPK_FUZZ=ON -DPK_BUILD_TESTS=OFF \
  -DPK_BUILD_APPS=OFF -DPK_BUILD_BENCHMARKS=OFF >/dev/null
cmake --build build-fuzz --target pk_fuzz_dataset -j "$jobs"
fuzzer=build-fuzz/tests/fuzz/pk_fuzz_dataset
"$fuzzer" tests/fuzz/regressions/* 2>build-fuzz/regressions.log ||
  { tail -40 build-fuzz/regressions.log; echo "fuzz: a saved regression input fails"; exit 1; }
corpus=build-fuzz/corpus
rm -rf "$corpus"; mkdir -p "$corpus"
cp datasets/*.csv tests/fuzz/regressions/* "$corpus/"
# Fork mode stops at the first crash, leak or timeout of any process, saves it as crash-* (leak-*,
# timeout-*) in build-fuzz/ and exits non-zero.
(cd build-fuzz && "../$fuzzer" -fork="$jobs" -max_total_time="$seconds" -max_len=4096 \
   -dict=../tests/fuzz/dataset.dict corpus 2>fuzz.log) || { tail -60 build-fuzz/fuzz.log; echo "fuzz: finding above"; exit 1; }
grep -E "^#[0-9]+: cov" build-fuzz/fuzz.log | tail -1
echo "fuzz: no finding in ${seconds} s on $jobs processes"
