#!/usr/bin/env bash
# Compares two records made by record.sh: every CSV and text output, numbers to 1e-12 relative
# (2e-12 absolute below 1), text exactly; timing columns and the report's HTML/SVG are left out.
# Prints each difference and exits 1 when there is any.
set -uo pipefail
a=$1; b=$2; tol=${3:-1e-12}
status=0
while IFS= read -r rel; do
  fa="$a/$rel"; fb="$b/$rel"
  if [ ! -f "$fb" ]; then echo "missing in $b: $rel"; status=1; continue; fi
  awk -v tol="$tol" -v file="$rel" -F',' '
    function num(x) { return x ~ /^[-+]?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][-+]?[0-9]+)?$/ }
    function abs(x) { return x < 0 ? -x : x }
    NR == FNR { lines[FNR] = $0; n = FNR; next }
    {
      if (FNR == 1) { for (i = 1; i <= NF; ++i) skip[i] = ($i ~ /SECONDS|_MS$|^MS$|WALL/) }
      if (!(FNR in lines)) { print file ": extra line " FNR; bad = 1; next }
      m = split(lines[FNR], old, ",")
      if (m != NF) { print file ":" FNR ": " m " fields against " NF; bad = 1; next }
      for (i = 1; i <= NF; ++i) {
        if (skip[i] || old[i] == $i) continue
        if (num(old[i]) && num($i)) {
          d = abs(old[i] - $i); s = abs(old[i]) > abs($i) ? abs(old[i]) : abs($i)
          if (d <= tol * (s > 1 ? s : 2)) continue
        }
        # Timings inside text ("12.3 ms", "0.5 s") are not numbers to keep.
        if (old[i] ~ /[0-9.]+ m?s\)?$/ && $i ~ /[0-9.]+ m?s\)?$/) continue
        print file ":" FNR ":" i ": " old[i] " -> " $i; bad = 1
      }
    }
    END { if (FNR < n) { print file ": " n - FNR " lines fewer"; bad = 1 } exit bad }
  ' "$fa" "$fb" || status=1
done < <(cd "$a" && find . -type f ! -name '*.html' ! -name '*.svg' | sed 's|^\./||' | sort)
[ $status -eq 0 ] && echo "no differences"
exit $status
