#!/usr/bin/env bash
# libpk reads and writes numbers independently of the C locale: the [locale] tests run again under a
# German locale (decimal comma) and a Turkish one (toupper('i') is a dotted capital I), generated here
# with localedef (Debian's locales package).
set -uo pipefail
tests=$1; work=$2
rm -rf "$work"; mkdir -p "$work"
localedef -i de_DE -f UTF-8 "$work/de_DE.UTF-8" 2>"$work/localedef.err" ||
  { echo "FAIL: localedef could not make de_DE.UTF-8 (apt-get install locales)"; cat "$work/localedef.err"; exit 1; }
localedef -i tr_TR -f ISO-8859-9 "$work/tr_TR.ISO-8859-9" 2>"$work/localedef.err" ||
  { echo "FAIL: localedef could not make tr_TR.ISO-8859-9 (apt-get install locales)"; cat "$work/localedef.err"; exit 1; }
LOCPATH=$work PK_TEST_COMMA_LOCALE=de_DE.UTF-8 PK_TEST_DOTTED_I_LOCALE=tr_TR.ISO-8859-9 "$tests" "[locale]"
