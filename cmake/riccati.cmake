# Shared build helpers: one way to add a model plugin, one way to add a test.

# Warnings for our own targets.
function(riccati_warnings target)
  target_compile_options(${target} PRIVATE -Wall -Wextra -Wpedantic -Wshadow -Wno-missing-field-initializers
                                            # A unity build includes each file: GCC then takes a file's
                                            # own anonymous-namespace types for a header's.
                                            $<$<CXX_COMPILER_ID:GNU>:-Wno-subobject-linkage>)
endfunction()

# riccati_add_model_plugin(NAME src...): a model plugin (shared module) named
# NAME.so in the plugin directory, exporting only its entry point.
function(riccati_add_model_plugin name)
  add_library(model_${name} MODULE ${ARGN})
  target_link_libraries(model_${name} PRIVATE riccati::model_sdk)
  set_target_properties(model_${name} PROPERTIES
    PREFIX ""
    OUTPUT_NAME ${name}
    LIBRARY_OUTPUT_DIRECTORY ${RICCATI_PLUGIN_DIR}
    CXX_VISIBILITY_PRESET hidden
    VISIBILITY_INLINES_HIDDEN ON)
  # Math without errno lets the compiler vectorise sqrt across points; the
  # host checks every result for NaN/Inf itself. No contraction of a * b + c
  # into one fused operation: the vectorised points (lanes.hpp) and the one-
  # point path then round alike on every architecture, to the bit.
  target_compile_options(model_${name} PRIVATE -fno-math-errno -ffp-contract=off)
  riccati_warnings(model_${name})
  set_property(GLOBAL APPEND PROPERTY RICCATI_MODEL_PLUGINS model_${name})
endfunction()

# riccati_add_test(NAME SOURCES src... LIBS lib...): a GoogleTest binary whose
# tests are registered with CTest. Tests find their data and the built-in
# plugins through the two compile definitions below.
# The test PKI (tests/data/tls) as riccatid may use it: git keeps only
# 0644/0755, and riccatid refuses a private key others can read, so the keys
# are copied here with mode 0600 (RICCATI_TEST_TLS_DIR).
set(RICCATI_TEST_TLS_DIR "${PROJECT_BINARY_DIR}/test-tls")
file(GLOB _riccati_test_tls "${PROJECT_SOURCE_DIR}/tests/data/tls/*")
file(COPY ${_riccati_test_tls} DESTINATION "${RICCATI_TEST_TLS_DIR}")
file(GLOB _riccati_test_keys "${RICCATI_TEST_TLS_DIR}/*.key")
file(CHMOD ${_riccati_test_keys} PERMISSIONS OWNER_READ OWNER_WRITE)

function(riccati_add_test name)
  cmake_parse_arguments(T "" "" "SOURCES;LIBS;LABELS" ${ARGN})
  add_executable(${name} ${T_SOURCES})
  target_link_libraries(${name} PRIVATE ${T_LIBS} GTest::gtest GTest::gtest_main)
  target_include_directories(${name} PRIVATE ${PROJECT_SOURCE_DIR}/tests)
  target_compile_definitions(${name} PRIVATE
    RICCATI_TEST_DATA_DIR="${PROJECT_SOURCE_DIR}/tests/data"
    RICCATI_TEST_TLS_DIR="${RICCATI_TEST_TLS_DIR}"
    RICCATI_TEST_PLUGIN_DIR="${RICCATI_PLUGIN_DIR}")
  if(RICCATI_SANITIZE)
    # Tests that measure memory (RSS) leave that check out under sanitizers,
    # whose shadow memory and quarantine make RSS meaningless, and tests that
    # load the daemon do less work (testing::kSanitized).
    target_compile_definitions(${name} PRIVATE RICCATI_SANITIZED=1)
  endif()
  riccati_warnings(${name})
  get_property(plugins GLOBAL PROPERTY RICCATI_MODEL_PLUGINS)
  if(plugins)
    add_dependencies(${name} ${plugins})
  endif()
  # An idle client channel hears a stopping daemon's GOAWAY only when gRPC's
  # backup poller runs (every 5 s by default), and until then the daemon
  # waits for the connection, up to its grace period: the tests' clients poll
  # every 100 ms, so that each stop of a daemon does not cost them 5 s.
  gtest_discover_tests(${name} DISCOVERY_MODE PRE_TEST PROPERTIES LABELS "${T_LABELS}"
    ENVIRONMENT "GRPC_CLIENT_CHANNEL_BACKUP_POLL_INTERVAL_MS=100")
endfunction()
