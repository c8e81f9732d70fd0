# SUNDIALS without Debian's libsundials-dev, which depends on MPI, PETSc,
# hypre and gfortran (about 150 packages, 110 MB) for parallel vectors that
# riccati never uses. riccati needs CVODE and ARKODE only: their runtime
# packages (libsundials-cvode6, libsundials-arkode5; each library holds the
# serial vector and the dense matrix and solver too) and the headers, which
# scripts/install-deps.sh unpacks from libsundials-dev into
# RICCATI_SUNDIALS_HEADERS. Defines the targets SUNDIALS' own CMake package
# would: SUNDIALS::cvode_shared and SUNDIALS::arkode_shared.
set(RICCATI_SUNDIALS_HEADERS "${PROJECT_SOURCE_DIR}/build/_deps/sundials/include"
    CACHE PATH "SUNDIALS' headers when libsundials-dev is not installed (scripts/install-deps.sh)")
find_path(SUNDIALS_INCLUDE_DIR sundials/sundials_config.h HINTS "${RICCATI_SUNDIALS_HEADERS}")
if(NOT SUNDIALS_INCLUDE_DIR)
  message(FATAL_ERROR "SUNDIALS: neither libsundials-dev nor its headers in ${RICCATI_SUNDIALS_HEADERS} "
                      "(scripts/install-deps.sh installs what is missing)")
endif()
file(STRINGS "${SUNDIALS_INCLUDE_DIR}/sundials/sundials_config.h" _sundials_version_line
     REGEX "^#define SUNDIALS_VERSION \"[0-9.]+\"")
string(REGEX MATCH "[0-9][0-9.]*" SUNDIALS_VERSION "${_sundials_version_line}")
if(SUNDIALS_VERSION VERSION_LESS 6.4)
  message(FATAL_ERROR "SUNDIALS ${SUNDIALS_VERSION} in ${SUNDIALS_INCLUDE_DIR}: riccati needs 6.4 or later")
endif()
string(REGEX MATCH "^[0-9]+" _sundials_major "${SUNDIALS_VERSION}")
foreach(_sundials_package cvode arkode)
  # The runtime packages ship libsundials_X.so.N only (the unversioned name
  # is libsundials-dev's). ARKODE's soname is one below CVODE's in 6.x.
  find_library(SUNDIALS_${_sundials_package}_LIBRARY
               NAMES sundials_${_sundials_package} libsundials_${_sundials_package}.so.${_sundials_major}
                     libsundials_${_sundials_package}.so.5)
  if(NOT SUNDIALS_${_sundials_package}_LIBRARY)
    message(FATAL_ERROR "SUNDIALS: libsundials_${_sundials_package} not found (libsundials-${_sundials_package}*)")
  endif()
  add_library(SUNDIALS::${_sundials_package}_shared SHARED IMPORTED)
  set_target_properties(SUNDIALS::${_sundials_package}_shared PROPERTIES
    IMPORTED_LOCATION "${SUNDIALS_${_sundials_package}_LIBRARY}"
    INTERFACE_INCLUDE_DIRECTORIES "${SUNDIALS_INCLUDE_DIR}")
endforeach()
message(STATUS "SUNDIALS ${SUNDIALS_VERSION}: headers ${SUNDIALS_INCLUDE_DIR}, ${SUNDIALS_cvode_LIBRARY}, "
               "${SUNDIALS_arkode_LIBRARY}")
