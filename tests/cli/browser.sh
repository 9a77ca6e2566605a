# Sourced by the report tests: headless Chromium as a person's browser. Needs $work, $chromium and a
# fail() function.

browse() {  # browse ARGS... : headless Chromium with a profile of its own (it runs as root in CI)
  timeout 120 "$chromium" --headless --no-sandbox --disable-gpu --hide-scrollbars --no-first-run \
    --disable-background-networking --disable-component-update --disable-sync \
    --user-data-dir="$work/profile" "$@" 2>>"$work/chromium.log"
}

# check_screenshot PAGE: a screenshot of PAGE ($work/report.png) must be far larger than one of a
# blank page of the same size, which is rendered too so that the threshold is known to tell them
# apart. Sets report_bytes.
check_screenshot() {
  browse --window-size=1400,2400 --screenshot="$work/report.png" "file://$1" >/dev/null
  printf '<!DOCTYPE html><html><body></body></html>\n' >"$work/blank.html"
  browse --window-size=1400,2400 --screenshot="$work/blank.png" "file://$work/blank.html" >/dev/null
  report_bytes=$(stat -c %s "$work/report.png" 2>/dev/null || echo 0)
  local blank_bytes
  blank_bytes=$(stat -c %s "$work/blank.png" 2>/dev/null || echo 0)
  [ "$blank_bytes" -gt 0 ] || fail "Chromium made no screenshot (see $work/chromium.log)"
  [ "$report_bytes" -gt $((blank_bytes * 10)) ] && [ "$report_bytes" -gt 100000 ] ||
    fail "the report's screenshot ($report_bytes bytes) looks blank next to a blank page's ($blank_bytes bytes)"
}
