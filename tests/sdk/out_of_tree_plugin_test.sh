#!/usr/bin/env bash
# A model plugin built outside the tree with exactly the commands of
# docs/operations.md ("A model plugin built outside the tree"): the
# CMakeLists.txt is taken from the page, the source is the two-tank plugin's;
# built against the build tree and against an install of the sdk component,
# then loaded by riccati-engine.
#
#   tests/sdk/out_of_tree_plugin_test.sh BUILD_DIR SOURCE_DIR
set -euo pipefail
build=$(cd "$1" && pwd)
source=$(cd "$2" && pwd)
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

# The page's CMakeLists.txt: the indented block after "# CMakeLists.txt".
mkdir -p "$work/my_model"
awk '/^    # CMakeLists.txt$/ {on = 1; next} on && /^$/ {exit} on {sub(/^    /, ""); print}' \
  "$source/docs/operations.md" >"$work/my_model/CMakeLists.txt"
grep -q 'riccati_add_model_plugin(my_model my_model.cpp)' "$work/my_model/CMakeLists.txt" ||
  { echo "FAIL: no CMakeLists.txt found in docs/operations.md"; exit 1; }
cp "$source/models/two_tank/two_tank.cpp" "$work/my_model/my_model.cpp"

check_loads() {  # $1: the build directory of my_model
  mkdir -p "$work/models-$2"
  chmod 755 "$work/models-$2"
  cp "$1/my_model.so" "$work/models-$2/"
  chmod 644 "$work/models-$2/my_model.so"
  out=$("$build/bin/riccati-engine" models --models-dir "$work/models-$2")
  echo "$out" | grep -q two_tank || { echo "FAIL ($2): the plugin did not load:"; echo "$out"; exit 1; }
}

# Against the build tree, as the page says.
cmake -S "$work/my_model" -B "$work/my_model/build" -DCMAKE_PREFIX_PATH="$build" >/dev/null
cmake --build "$work/my_model/build" >/dev/null
check_loads "$work/my_model/build" build-tree

# Against an install of the SDK (cmake --install ... --component sdk).
cmake --install "$build" --prefix "$work/prefix" --component sdk >/dev/null
cmake -S "$work/my_model" -B "$work/my_model/build-installed" -DCMAKE_PREFIX_PATH="$work/prefix" >/dev/null
cmake --build "$work/my_model/build-installed" >/dev/null
check_loads "$work/my_model/build-installed" install
echo "out-of-tree plugin: built against the build tree and an install, and loaded"
