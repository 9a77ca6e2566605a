#!/usr/bin/env bash
# pkpop under mpirun with 2 processes gives the same estimates, covariance, sdtab, subject table and
# NONMEM .ext/.phi as one process: byte for byte, since every subject's numbers come from one process and
# are summed in subject order (pk/population.h, SubjectDistribution).
set -uo pipefail
pkpop=$1; root=$2; work=$3; mpirun=$4; sanitized=${5:-OFF}
rm -rf "$work"; mkdir -p "$work"
failures=0
fail() { echo "FAIL: $*"; failures=$((failures + 1)); }
# As root on these machines; shared-memory transport without cross-memory attach (containers).
# Under the sanitizers the MPI processes keep every memory-error check but not LeakSanitizer's:
# OpenMPI leaves its own allocations from MPI_Init (ompi_op_base_op_select, components unloaded
# at MPI_Finalize) unfreed. The one-process runs of the same cases are leak-checked.
mpi=("$mpirun" --allow-run-as-root --oversubscribe --mca btl self,vader --mca btl_vader_single_copy_mechanism none
     -x "ASAN_OPTIONS=${ASAN_OPTIONS:+$ASAN_OPTIONS:}detect_leaks=0" -np 2)

compare() {  # name, then pkpop's arguments
  local name=$1; shift
  "$pkpop" "$@" -q -o "$work/$name.1" || fail "$name: one process exited non-zero"
  "${mpi[@]}" "$pkpop" "$@" -q -o "$work/$name.2" >"$work/$name.mpi.txt" 2>&1 ||
    fail "$name: mpirun -np 2 exited non-zero: $(tail -5 "$work/$name.mpi.txt")"
  # MPI really split the subjects (a process that missed its launcher would run them all as one).
  grep -q "subjects split across 2 processes" "$work/$name.2/report.txt" || fail "$name: not split across 2 processes"
  grep -q "subjects split across" "$work/$name.1/report.txt" && fail "$name: one process reports a split"
  for f in population_estimates.csv covariance.csv sdtab.csv subjects.csv iterations.csv pkpop.ext pkpop.phi; do
    [ -s "$work/$name.1/$f" ] || fail "$name: one process wrote no $f"
    cmp -s "$work/$name.1/$f" "$work/$name.2/$f" || fail "$name: $f differs between 1 and 2 processes"
  done
}
compare pheno --model 1cmt_iv --data "$root/datasets/phenobarbital.csv" --eta CL,V --error proportional
# The second case (differences of the OFV, an Ω block, 2 threads per process) takes 45 s under the
# sanitizers and 3 s optimised; the sanitizer build runs the first alone.
if [ "$sanitized" != "ON" ]; then
  compare theo --model 1cmt_oral --data "$root/datasets/theophylline.csv" --eta KA,CL,V --block CL,V --method foce \
    --error additive --gradient fd -j 2
  # Laplace with censored samples (M3) and its exact gradient (third-order sensitivities).
  compare theo_m3 --model 1cmt_oral --data "$root/datasets/theophylline_blq.csv" --eta KA,CL,V --method laplace \
    --error additive
fi

# A process that cannot read its input stops and says so to the others, which stop too instead of
# waiting for it in their first MPI_Allreduce forever (before, this hung). MPMD: the second process
# is given a data file that does not exist.
launcher=("${mpi[@]:0:${#mpi[@]}-2}")  # the options above without -np 2
timeout 120 "${launcher[@]}" -np 1 "$pkpop" --model 1cmt_iv --data "$root/datasets/phenobarbital.csv" --eta CL,V \
  --error proportional -q -o "$work/stop.1" : -np 1 "$pkpop" --model 1cmt_iv --data "$work/missing.csv" --eta CL,V \
  --error proportional -q -o "$work/stop.2" >"$work/stop.txt" 2>&1
rc=$?
[ $rc -eq 124 ] && fail "one process without its input: the other waited for it until the timeout"
[ $rc -eq 0 ] && fail "one process without its input: mpirun exited 0"
grep -q "missing.csv: cannot open" "$work/stop.txt" || fail "the failed process's message is missing: $(tail -3 "$work/stop.txt")"
grep -q "another MPI process stopped before the fit" "$work/stop.txt" || fail "the other process did not say why it stopped"
[ -e "$work/stop.1" ] && fail "the process with its input wrote outputs without a fit"

[ $failures -eq 0 ] && echo "pkpop under MPI: all checks passed"
exit $failures
