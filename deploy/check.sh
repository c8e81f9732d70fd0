#!/usr/bin/env bash
# What can be checked of deploy/ here, on Debian 12 without a container
# engine, a cluster or systemd running:
#
#   deploy/check.sh
#
#   image      the image's build stage script (build and cmake --install into a
#              temporary /opt/riccati), its runtime packages checked against what
#              the install links (install-runtime-deps.sh --check), the
#              Dockerfile's COPY sources, user, port and health check, the
#              scripts' syntax
#   install    riccatid started from the install (through the image's
#              entrypoint) on loopback with a temporary data directory finds its
#              4 built-in models by itself; riccati health says SERVING; SIGTERM
#              stops it cleanly
#   sdk        a model plugin built outside the tree with find_package(riccati)
#              from the install loads into that riccatid
#   configs    the riccatid.yaml and client.yaml of the image, of compose, of the
#              Kubernetes ConfigMap and of systemd, each run by that riccatid
#              with TLS and tokens from compose/make-dev-secrets.sh (paths moved
#              to a temporary directory, listening on loopback): riccati health
#              through the client.yaml answers SERVING, riccati models with the
#              token lists the 4 models
#   postgres   with RICCATI_TEST_POSTGRES_URL (scripts/with-postgres.sh): the
#              compose topology, two riccatid started at once on one new
#              database, the password through RICCATI_DATABASE_PASSWORD_FILE,
#              both SERVING
#   systemd    systemd-analyze verify of riccatid.service (no warning allowed)
#              and its offline security exposure at most 2.0
#   kubernetes every object of deploy/kubernetes/base against the API's schemas,
#              with no unknown field and consistent references (deploy/validate.mjs;
#              npm ci of deploy/package-lock.json); kubectl kustomize's output too
#              when kubectl is there
#   compose    deploy/compose.yaml against the compose specification's schema,
#              its services, healthchecks, secrets and database URL
#   reference  the configuration reference in docs/operations.md is riccatid --help's
#
# Uses the build in $RICCATI_BUILD_DIR (default build/; configured by
# scripts/build.sh) and builds what is missing. Exits non-zero if any check
# fails, after running them all.
set -uo pipefail
cd "$(dirname "$0")/.." || exit 2
root=$PWD
export RICCATI_BUILD_DIR=${RICCATI_BUILD_DIR:-build}
work=$(mktemp -d "${TMPDIR:-/tmp}/riccati-deploy-check-XXXXXX")
prefix=$work/opt/riccati
secrets=$work/secrets
pids=()
pg_db=

cleanup() {
  for pid in "${pids[@]}"; do
    kill -TERM "$pid" 2>/dev/null && wait "$pid" 2>/dev/null
  done
  if [ -n "$pg_db" ]; then
    PGPASSWORD=$pg_password /usr/lib/postgresql/15/bin/dropdb -h "$pg_host" -p "$pg_port" -U "$pg_user" \
      --if-exists "$pg_db" 2>/dev/null || true
  fi
  rm -rf "$work"
}
trap cleanup EXIT
trap 'exit 130' INT
trap 'exit 143' TERM

results=()
passed=0
failed=0
check() {  # check NAME DESCRIPTION FUNCTION: runs it, records ok or FAIL
  local name=$1 what=$2
  shift 2
  echo "== $name: $what"
  if "$@"; then
    results+=("ok    $name: $what")
    passed=$((passed + 1))
  else
    results+=("FAIL  $name: $what")
    failed=$((failed + 1))
    return 1
  fi
}

# --- riccatid from the install ------------------------------------------------

# start NAME ARGS...: riccatid through the image's entrypoint, on a free
# loopback port; sets $port and $pid. Flags given after the config win.
start() {
  local name=$1
  shift
  rm -f "$work/$name.port"
  RICCATI_PREFIX=$prefix "$root/deploy/container/entrypoint.sh" "$@" --listen 127.0.0.1:0 \
    --port-file "$work/$name.port" --data-dir "$work/data-$name" --log-level "${RICCATI_CHECK_LOG_LEVEL:-warn}" \
    2>"$work/$name.log" &
  pid=$!
  pids+=("$pid")
  for _ in $(seq 300); do
    [ -s "$work/$name.port" ] && break
    kill -0 "$pid" 2>/dev/null || break
    sleep 0.1
  done
  if [ ! -s "$work/$name.port" ]; then
    echo "   riccatid ($name) did not start; its log:" >&2
    sed 's/^/   | /' "$work/$name.log" >&2
    return 1
  fi
  port=$(cat "$work/$name.port")
}

# stop PID: SIGTERM, and riccatid must exit 0 (a clean drain).
stop() {
  local target=$1 status=0
  kill -TERM "$target" 2>/dev/null
  wait "$target" 2>/dev/null || status=$?
  local kept=()
  for p in "${pids[@]}"; do [ "$p" = "$target" ] || kept+=("$p"); done
  pids=("${kept[@]}")
  if [ $status -ne 0 ]; then
    echo "   riccatid exited $status after SIGTERM" >&2
    return 1
  fi
}

riccati() { "$prefix/bin/riccati" --timeout 5 "$@"; }

# expect_serving ARGS...: riccati ARGS health prints SERVING and exits 0.
expect_serving() {
  local out status=0
  out=$(riccati "$@" health 2>"$work/health.err") || status=$?
  if [ $status -ne 0 ] || [ "$out" != "SERVING" ]; then
    echo "   riccati health: exit $status, \"$out\" $(cat "$work/health.err")" >&2
    return 1
  fi
  echo "   riccati health: SERVING"
}

# expect_models ARGS...: riccati ARGS models lists the 4 built-in models.
expect_models() {
  local out
  out=$(riccati "$@" models 2>&1) || { echo "   riccati models: $out" >&2; return 1; }
  local m missing=0
  for m in two_tank rotating_arm rotary_pendulum flexible_manipulator; do
    grep -q "^$m " <<<"$out" || { echo "   riccati models: no $m in:" >&2; echo "$out" >&2; missing=1; }
  done
  [ $missing -eq 0 ] && echo "   riccati models: the 4 built-in models"
}

# --- the checks ---------------------------------------------------------------

image_build() {
  deploy/container/build-install.sh "$prefix" || return 1
  local f
  for f in bin/riccatid bin/riccati lib/riccati/models/two_tank.so include/riccati/model_abi.h \
           include/riccati/model.hpp include/riccati/dual.hpp lib/cmake/riccati/riccatiConfig.cmake; do
    [ -e "$prefix/$f" ] || { echo "   $f is not installed" >&2; return 1; }
  done
  echo "   installed: $(cd "$prefix" && find . -type f | sort | tr '\n' ' ')"
}

image_runtime_packages() {
  command -v readelf >/dev/null || { echo "   readelf (binutils) is missing" >&2; return 1; }
  deploy/container/install-runtime-deps.sh --check "$prefix"
}

image_dockerfile() {
  local dockerfile=deploy/container/Dockerfile status=0 src
  # Every COPY from the build context names files of the repository.
  while read -r src; do
    [ -e "$src" ] || { echo "   $dockerfile: COPY $src: no such file" >&2; status=1; }
  done < <(sed -n 's/^COPY \(--chown=[^ ]* \)\{0,1\}\([^-].*\) [^ ]*$/\2/p' "$dockerfile" | tr ' ' '\n' | grep -v '^\.$')
  # Every script a RUN calls exists and is executable.
  while read -r script; do
    local path=$script
    case $script in /usr/local/lib/riccati-setup/*) path=deploy/container/${script##*/} ;; esac
    [ -x "$path" ] || { echo "   $dockerfile: RUN $script: not an executable script here" >&2; status=1; }
  done < <(grep -o '\(scripts\|deploy/container\|/usr/local/lib/riccati-setup\)/[a-z-]*\.sh' "$dockerfile" | sort -u)
  grep -q '^FROM debian:12-slim AS build$' "$dockerfile" || { echo "   no debian:12-slim build stage" >&2; status=1; }
  [ "$(grep -c '^FROM debian:12-slim' "$dockerfile")" -eq 2 ] || { echo "   the runtime stage is not debian:12-slim" >&2; status=1; }
  grep -q '^USER 10001:10001$' "$dockerfile" || { echo "   not USER 10001:10001" >&2; status=1; }
  grep -q 'CMD \["riccati", .*"health"\]' "$dockerfile" || { echo "   no HEALTHCHECK through riccati health" >&2; status=1; }
  local exposed listen
  exposed=$(sed -n 's/^EXPOSE \([0-9]*\).*$/\1/p' "$dockerfile")
  listen=$(sed -n 's/^listen: .*:\([0-9]*\)$/\1/p' deploy/container/riccatid.yaml)
  [ -n "$exposed" ] && [ "$exposed" = "$listen" ] ||
    { echo "   EXPOSE $exposed is not the port of container/riccatid.yaml ($listen)" >&2; status=1; }
  # The scripts parse.
  for f in deploy/container/*.sh deploy/compose/*.sh deploy/check.sh scripts/*.sh; do
    bash -n "$f" || status=1
  done
  sh -n deploy/container/entrypoint.sh && sh -n deploy/container/setup-runtime.sh || status=1
  if command -v shellcheck >/dev/null; then
    shellcheck -S warning deploy/container/*.sh deploy/compose/*.sh deploy/check.sh || status=1
  fi
  [ $status -eq 0 ] && echo "   COPY sources, RUN scripts, base images, USER, EXPOSE, HEALTHCHECK, script syntax"
  return $status
}

install_layout() {
  start install || return 1
  local status=0
  # No --models-dir: riccatid finds lib/riccati/models next to its bin/.
  expect_serving --server "127.0.0.1:$port" || status=1
  expect_models --server "127.0.0.1:$port" || status=1
  grep -q "refused" "$work/install.log" && { echo "   plugins refused:" >&2; cat "$work/install.log" >&2; status=1; }
  stop "$pid" || status=1
  return $status
}

# A plugin built outside the tree against the installed SDK (find_package(riccati),
# riccati_add_model_plugin) loads into the installed riccatid.
sdk_plugin() {
  mkdir -p "$work/sdk" "$work/sdk-models"
  cp models/two_tank/two_tank.cpp "$work/sdk/my_model.cpp"
  cat >"$work/sdk/CMakeLists.txt" <<'CMAKE'
cmake_minimum_required(VERSION 3.22)
project(my_model CXX)
find_package(riccati REQUIRED)
riccati_add_model_plugin(my_model my_model.cpp)
CMAKE
  cmake -S "$work/sdk" -B "$work/sdk/build" -G Ninja -DCMAKE_BUILD_TYPE=Release -DCMAKE_PREFIX_PATH="$prefix" \
    >"$work/sdk.log" 2>&1 && ninja -C "$work/sdk/build" >>"$work/sdk.log" 2>&1 ||
    { sed 's/^/   | /' "$work/sdk.log" >&2; return 1; }
  cp "$work/sdk/build/my_model.so" "$work/sdk-models/"
  start sdk --models-dir "$work/sdk-models" || return 1
  local out status=0
  out=$(riccati --server "127.0.0.1:$port" models 2>&1) || status=1
  grep -q '^two_tank ' <<<"$out" || { echo "   the plugin did not load: $out" >&2; status=1; }
  stop "$pid" || status=1
  [ $status -eq 0 ] && echo "   my_model.so, built with find_package(riccati), loads as two_tank"
  return $status
}

# A deployment's riccatid.yaml and client.yaml with their paths moved here.
map_paths() {
  sed -e "s|/etc/riccati/tls/tls.crt|$secrets/tls.crt|g" -e "s|/etc/riccati/tls/tls.key|$secrets/tls.key|g" \
      -e "s|/etc/riccati/tls/ca.crt|$secrets/ca.crt|g" -e "s|/etc/riccati/tokens/tokens|$secrets/tokens|g" \
      -e "s|/run/secrets/tls_cert|$secrets/tls.crt|g" -e "s|/run/secrets/tls_key|$secrets/tls.key|g" \
      -e "s|/run/secrets/ca_cert|$secrets/ca.crt|g" -e "s|/run/secrets/tokens|$secrets/tokens|g" \
      -e "s|/run/credentials/riccatid.service/|$secrets/|g" -e "s|/var/lib/riccati|$work/var-lib-riccati|g" "$1"
}

# config NAME RICCATID_YAML CLIENT_YAML [ARGS...]: riccatid runs with that
# config (and the args), the client config reaches it.
config() {
  local name=$1 server_config=$2 client_config=$3
  shift 3
  map_paths "$server_config" >"$work/$name-riccatid.yaml"
  # A configured metrics port becomes a free loopback one.
  grep -q '^metrics_listen:' "$server_config" && set -- --metrics-listen 127.0.0.1:0 "$@"
  start "$name" --config "$work/$name-riccatid.yaml" "$@" || return 1
  local status=0
  if [ -n "$client_config" ]; then
    map_paths "$client_config" >"$work/$name-client.yaml"
    RICCATI_CONFIG=$work/$name-client.yaml expect_serving --server "127.0.0.1:$port" || status=1
    RICCATI_CONFIG=$work/$name-client.yaml RICCATI_TOKEN_FILE=$secrets/token \
      expect_models --server "127.0.0.1:$port" || status=1
  else
    expect_serving --server "127.0.0.1:$port" || status=1
    expect_models --server "127.0.0.1:$port" || status=1
  fi
  stop "$pid" || status=1
  return $status
}

configs() {
  RICCATI_SECRETS_DIR=$secrets PATH=$prefix/bin:$PATH deploy/compose/make-dev-secrets.sh >/dev/null || return 1
  local status=0
  echo "-- container/riccatid.yaml, container/client.yaml"
  config image deploy/container/riccatid.yaml deploy/container/client.yaml || status=1
  echo "-- compose/riccatid.yaml, compose/client.yaml"
  config compose deploy/compose/riccatid.yaml deploy/compose/client.yaml || status=1
  echo "-- kubernetes/base ConfigMap riccatid-config (its database replaced by SQLite here)"
  node deploy/validate.mjs configmap-key deploy/kubernetes/base riccatid-config riccatid.yaml >"$work/k8s-riccatid.yaml" &&
    node deploy/validate.mjs configmap-key deploy/kubernetes/base riccatid-config client.yaml >"$work/k8s-client.yaml" &&
    config kubernetes "$work/k8s-riccatid.yaml" "$work/k8s-client.yaml" --database sqlite || status=1
  echo "-- systemd/riccatid.yaml (loopback, no TLS)"
  config systemd deploy/systemd/riccatid.yaml "" || status=1
  return $status
}

postgres_topology() {
  local url=$RICCATI_TEST_POSTGRES_URL
  # postgresql://user:password@host:port/db
  pg_user=$(sed -E 's|^[a-z]+://([^:@/]+).*|\1|' <<<"$url")
  pg_password=$(sed -E 's|^[a-z]+://[^:@/]+:([^@/]*)@.*|\1|' <<<"$url")
  pg_host=$(sed -E 's|^[a-z]+://[^@/]*@([^:/]+).*|\1|' <<<"$url")
  pg_port=$(sed -E 's|^[a-z]+://[^@/]*@[^:/]+:([0-9]+).*|\1|' <<<"$url")
  local db=riccati_deploy_check_$$
  PGPASSWORD=$pg_password /usr/lib/postgresql/15/bin/createdb -h "$pg_host" -p "$pg_port" -U "$pg_user" "$db" ||
    return 1
  pg_db=$db
  printf '%s' "$pg_password" >"$work/postgres_password"
  map_paths deploy/compose/riccatid.yaml >"$work/pg-riccatid.yaml"
  map_paths deploy/compose/client.yaml >"$work/pg-client.yaml"
  # As compose.yaml runs them: no password in the URL, the password from a file.
  local database="postgresql://$pg_user@$pg_host:$pg_port/$db" status=0 one two port_one
  export RICCATI_DATABASE_PASSWORD_FILE=$work/postgres_password
  RICCATI_PREFIX=$prefix "$root/deploy/container/entrypoint.sh" --config "$work/pg-riccatid.yaml" --database "$database" \
    --instance-id riccatid-1 --metrics-listen 127.0.0.1:0 --listen 127.0.0.1:0 --port-file "$work/pg-1.port" --data-dir "$work/data-pg-1" --log-level warn 2>"$work/pg-1.log" &
  one=$!
  pids+=("$one")
  RICCATI_PREFIX=$prefix "$root/deploy/container/entrypoint.sh" --config "$work/pg-riccatid.yaml" --database "$database" \
    --instance-id riccatid-2 --metrics-listen 127.0.0.1:0 --listen 127.0.0.1:0 --port-file "$work/pg-2.port" --data-dir "$work/data-pg-2" --log-level warn 2>"$work/pg-2.log" &
  two=$!
  pids+=("$two")
  unset RICCATI_DATABASE_PASSWORD_FILE
  for _ in $(seq 300); do
    [ -s "$work/pg-1.port" ] && [ -s "$work/pg-2.port" ] && break
    sleep 0.1
  done
  for n in 1 2; do
    if [ ! -s "$work/pg-$n.port" ]; then
      echo "   riccatid $n on PostgreSQL did not start; its log:" >&2
      sed 's/^/   | /' "$work/pg-$n.log" >&2
      status=1
      continue
    fi
    port_one=$(cat "$work/pg-$n.port")
    RICCATI_CONFIG=$work/pg-client.yaml expect_serving --server "127.0.0.1:$port_one" || status=1
    RICCATI_CONFIG=$work/pg-client.yaml RICCATI_TOKEN_FILE=$secrets/token \
      expect_models --server "127.0.0.1:$port_one" || status=1
  done
  stop "$one" || status=1
  stop "$two" || status=1
  return $status
}

systemd_unit() {
  command -v systemd-analyze >/dev/null || { echo "   no systemd-analyze (Debian package systemd): not checked"; return 0; }
  mkdir -p "$work/systemd"
  # The unit as installed, but with the binary of this install.
  sed "s|/opt/riccati|$prefix|g" deploy/systemd/riccatid.service >"$work/systemd/riccatid.service"
  local out status=0
  out=$(systemd-analyze verify "$work/systemd/riccatid.service" 2>&1) || status=1
  if [ -n "$out" ]; then
    echo "$out" | sed 's/^/   | /' >&2
    status=1
  fi
  out=$(systemd-analyze security --offline=true --threshold=20 "$work/systemd/riccatid.service" 2>&1) || status=1
  grep -i 'overall exposure' <<<"$out" | sed 's/^/   /'
  grep -i 'unknown\|ignoring' <<<"$out" | sed 's/^/   | /' >&2 && status=1
  [ $status -eq 0 ] && echo "   systemd-analyze verify: no warning"
  return $status
}

npm_tools() {
  if ! command -v node >/dev/null || ! command -v npm >/dev/null; then
    echo "   installing nodejs and npm (Debian)"
    local sudo_cmd=()
    [ "$(id -u)" -eq 0 ] || sudo_cmd=(sudo)
    DEBIAN_FRONTEND=noninteractive "${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends nodejs npm \
      >/dev/null || return 1
  fi
  (cd deploy && npm ci --no-audit --no-fund --loglevel=error >/dev/null) || return 1
  echo "   node $(node --version), deploy/package-lock.json installed"
}

kubernetes() {
  local status=0
  node deploy/validate.mjs kubernetes deploy/kubernetes/base || status=1
  if command -v kubectl >/dev/null; then
    echo "   kubectl kustomize deploy/kubernetes/base:"
    kubectl kustomize deploy/kubernetes/base >"$work/kustomized.yaml" && node deploy/validate.mjs kubernetes - \
      <"$work/kustomized.yaml" | tail -1 || status=1
  else
    echo "   no kubectl: the kustomization's build is not checked (its resources are)"
  fi
  return $status
}

compose() {
  node deploy/validate.mjs compose deploy/compose.yaml "$secrets"
}

reference() {
  scripts/gen-config-reference.sh --check "$prefix/bin/riccatid"
}

check image "the build stage's script installs riccati" image_build
if [ -x "$prefix/bin/riccatid" ]; then
  check image "the runtime packages provide every library the install links" image_runtime_packages
  check install "riccatid from the install: its models, SERVING, a clean SIGTERM" install_layout
  check sdk "a plugin built against the installed SDK loads" sdk_plugin
  have_npm=0
  check tools "npm ci of deploy/package-lock.json" npm_tools && have_npm=1
  if [ $have_npm -eq 1 ]; then
    check configs "the image's, compose's, Kubernetes' and systemd's configs run, health and token" configs
  fi
  if [ -n "${RICCATI_TEST_POSTGRES_URL:-}" ]; then
    check postgres "two riccatid on one PostgreSQL database as compose runs them" postgres_topology
  else
    results+=("skip  postgres: no RICCATI_TEST_POSTGRES_URL (run under scripts/with-postgres.sh)")
  fi
  check systemd "riccatid.service verifies, exposure at most 2.0" systemd_unit
  check reference "docs/operations.md's configuration reference is riccatid --help's" reference
  if [ $have_npm -eq 1 ]; then
    check kubernetes "deploy/kubernetes/base against the API schemas" kubernetes
    check compose "deploy/compose.yaml against the compose schema" compose
  fi
fi
check image "the Dockerfile's sources, scripts, user, port and health check" image_dockerfile

echo
echo "deploy/check.sh:"
printf '  %s\n' "${results[@]}"
echo "$passed passed, $failed failed"
[ $failed -eq 0 ]
