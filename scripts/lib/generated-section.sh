# A generated section of a document: the lines from a BEGIN marker to its END
# marker, which a script rewrites from the code and the tests check against
# it. Sourced by scripts/gen-config-reference.sh and
# scripts/gen-settings-reference.sh.
#
#   section_current DOC BEGIN END         prints the section, markers included
#   section_replaced DOC BEGIN END FILE   prints DOC with the section replaced by FILE
#                                         (FILE holds the markers too)
#   section_update DOC BEGIN END FILE     rewrites DOC so
#   section_check DOC BEGIN END FILE NAME fails, with the difference and the command that
#                                         updates it, when the section is not FILE

section_current() {
  awk -v b="$2" -v e="$3" '$0 == b { on = 1 } on { print } $0 == e { on = 0 }' "$1"
}

section_replaced() {
  awk -v b="$2" -v e="$3" -v f="$4" '
    $0 == b { while ((getline l < f) > 0) print l; skip = 1; next }
    $0 == e { skip = 0; next }
    !skip { print }' "$1"
}

section_update() {
  grep -qxF "$2" "$1" || { echo "$1 has no line $2" >&2; return 1; }
  section_replaced "$@" >"$1.tmp" && mv "$1.tmp" "$1"
}

section_check() {
  if ! diff -u <(section_current "$1" "$2" "$3") "$4" >&2; then
    echo "$5: the section of $1 above is out of date: run scripts/$5.sh --update" >&2
    return 1
  fi
}
