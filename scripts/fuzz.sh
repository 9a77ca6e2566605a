#!/usr/bin/env bash
# Fuzzes the dataset reader and its IGNORE/ACCEPT filters with libFuzzer (clang) for SECONDS
# (default 30) on every core (libFuzzer's fork mode: one fuzzing process a core, their corpora merged),
# after running every saved regression input and seed once. Seeds: the bundled datasets and
# tests/fuzz/regressions/; dictionary: tests/fuzz/dataset.dict. A finding is saved in
# build-fuzz/findings/ (crash-*, leak-*, timeout-*, oom-*) and fails the run; add it to
# tests/fuzz/regressions/ once fixed.
#
#   scripts/fuzz.sh           # 30 s (scripts/test.sh runs 20)
#   scripts/fuzz.sh 3600      # an hour
set -euo pipefail
cd "$(dirname "$0")/.."
seconds=${1:-30}
jobs=$(nproc 2>/dev/null || echo 2)
CC=clang CXX=clang++ cmake -S . -B build-fuzz -DCMAKE_BUILD_TYPE=RelWithDebInfo -DPK_FUZZ=ON -DPK_BUILD_TESTS=OFF \
  -DPK_BUILD_APPS=OFF -DPK_BUILD_BENCHMARKS=OFF >/dev/null
cmake --build build-fuzz --target pk_fuzz_dataset -j "$jobs"
fuzzer=build-fuzz/tests/fuzz/pk_fuzz_dataset
# The saved regressions and the seeds, each run once (fork mode's first merge would skip a seed that crashes).
"$fuzzer" -timeout=10 tests/fuzz/regressions/* datasets/*.csv 2>build-fuzz/regressions.log ||
  { tail -40 build-fuzz/regressions.log; echo "fuzz: a saved regression input or seed fails"; exit 1; }
corpus=build-fuzz/corpus
rm -rf "$corpus"; mkdir -p "$corpus"
cp datasets/*.csv tests/fuzz/regressions/* "$corpus/"
# Fork mode ignores timeouts and running out of memory unless told, exits with its last job's code,
# and does not wait for the job still running at the end: so every finding (crash-*, leak-*,
# timeout-*, oom-*, an input that takes over 10 s) is written to findings/, and any file there fails
# the run, whatever the exit code.
findings=build-fuzz/findings
rm -rf "$findings"; mkdir -p "$findings"
(cd build-fuzz && "../$fuzzer" -fork="$jobs" -max_total_time="$seconds" -max_len=4096 -timeout=10 \
   -ignore_crashes=0 -ignore_timeouts=0 -ignore_ooms=0 -artifact_prefix=findings/ \
   -dict=../tests/fuzz/dataset.dict corpus 2>fuzz.log) || { tail -60 build-fuzz/fuzz.log; echo "fuzz: finding above"; exit 1; }
if [ -n "$(ls -A "$findings")" ]; then
  tail -60 build-fuzz/fuzz.log; echo "fuzz: findings in $findings: $(ls "$findings" | tr '\n' ' ')"; exit 1
fi
grep -E "^#[0-9]+: cov" build-fuzz/fuzz.log | tail -1
echo "fuzz: no finding in ${seconds} s on $jobs processes"
