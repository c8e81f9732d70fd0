# What `cmake --install build --prefix P` puts where:
#
#   P/bin/riccatid, riccati, riccati-engine
#   P/lib/riccati/models/*.so       the built-in model plugins
#   P/include/riccati/              the model SDK: model_abi.h, model.hpp, dual.hpp
#   P/<libdir>/cmake/riccati/       find_package(riccati): riccati::model_sdk and
#                                   riccati_add_model_plugin(), for plugin authors
#
# The models directory is fixed relative to bin/: default_models_dir()
# (server/engine/models/plugin_loader.cpp) looks in <dir of the binary>/../lib/riccati/models,
# as it does in the build tree (build/bin, build/lib/riccati/models). It is
# therefore not CMAKE_INSTALL_LIBDIR, which is lib/x86_64-linux-gnu under
# /usr on Debian: plugins are private to riccati, like /usr/lib/<package>.
include(CMakePackageConfigHelpers)

if(NOT CMAKE_INSTALL_BINDIR STREQUAL "bin")
  message(FATAL_ERROR "CMAKE_INSTALL_BINDIR must be bin: riccatid finds its models in ../lib/riccati/models "
                      "relative to its own directory")
endif()
set(RICCATI_INSTALL_MODELSDIR lib/riccati/models)
set(RICCATI_INSTALL_CMAKEDIR ${CMAKE_INSTALL_LIBDIR}/cmake/riccati)

install(TARGETS riccatid riccati riccati-engine RUNTIME DESTINATION ${CMAKE_INSTALL_BINDIR} COMPONENT runtime)

get_property(riccati_plugins GLOBAL PROPERTY RICCATI_MODEL_PLUGINS)
install(TARGETS ${riccati_plugins} LIBRARY DESTINATION ${RICCATI_INSTALL_MODELSDIR} COMPONENT runtime)

# The SDK: headers, and a CMake package so that a plugin builds the way the
# built-in ones do (riccati_add_model_plugin).
install(DIRECTORY ${PROJECT_SOURCE_DIR}/models/sdk/include/riccati DESTINATION ${CMAKE_INSTALL_INCLUDEDIR}
        COMPONENT sdk)
install(TARGETS riccati_model_sdk EXPORT riccatiTargets COMPONENT sdk)
install(EXPORT riccatiTargets NAMESPACE riccati:: DESTINATION ${RICCATI_INSTALL_CMAKEDIR} COMPONENT sdk)
# The package twice: for an install (its prefix computed from where the
# config file lands), and for this build tree, so that
# -DCMAKE_PREFIX_PATH=<build dir> works too: there the targets are exported
# in place (the SDK's include directory in the source tree) and the models
# directory is the build tree's, <build>/lib/riccati/models, the same layout.
configure_package_config_file(${PROJECT_SOURCE_DIR}/cmake/riccatiConfig.cmake.in
                              ${PROJECT_BINARY_DIR}/cmake-install/riccatiConfig.cmake
                              INSTALL_DESTINATION ${RICCATI_INSTALL_CMAKEDIR}
                              PATH_VARS RICCATI_INSTALL_MODELSDIR)
configure_package_config_file(${PROJECT_SOURCE_DIR}/cmake/riccatiConfig.cmake.in
                              ${PROJECT_BINARY_DIR}/riccatiConfig.cmake
                              INSTALL_DESTINATION ${PROJECT_BINARY_DIR}
                              INSTALL_PREFIX ${PROJECT_BINARY_DIR}
                              PATH_VARS RICCATI_INSTALL_MODELSDIR)
export(EXPORT riccatiTargets NAMESPACE riccati:: FILE ${PROJECT_BINARY_DIR}/riccatiTargets.cmake)
write_basic_package_version_file(${PROJECT_BINARY_DIR}/riccatiConfigVersion.cmake
                                 COMPATIBILITY SameMinorVersion ARCH_INDEPENDENT)
install(FILES ${PROJECT_BINARY_DIR}/cmake-install/riccatiConfig.cmake ${PROJECT_BINARY_DIR}/riccatiConfigVersion.cmake
        DESTINATION ${RICCATI_INSTALL_CMAKEDIR} COMPONENT sdk)
