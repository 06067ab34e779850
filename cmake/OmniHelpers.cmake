# omni_add_gtest(NAME SOURCES a.cc b.cc LIBS lib1 lib2 [LABELS l1])
# One GoogleTest executable; each TEST becomes its own ctest entry. Tests see the datasets
# folder as OMNI_DATASETS_DIR and the source/build roots as OMNI_SOURCE_DIR/OMNI_BINARY_DIR.
include(GoogleTest)
function(omni_add_gtest name)
  cmake_parse_arguments(ARG "" "TIMEOUT" "SOURCES;LIBS;LABELS" ${ARGN})
  add_executable(${name} ${ARG_SOURCES})
  target_link_libraries(${name} PRIVATE ${ARG_LIBS} GTest::gtest GTest::gtest_main omni_warnings)
  target_compile_definitions(${name} PRIVATE
    OMNI_DATASETS_DIR="${OMNI_DATASETS_DIR}"
    OMNI_SOURCE_DIR="${CMAKE_SOURCE_DIR}"
    OMNI_BINARY_DIR="${CMAKE_BINARY_DIR}")
  if(NOT ARG_TIMEOUT)
    set(ARG_TIMEOUT 120)
  endif()
  # testing::TempDir() is this executable's own folder in the build tree (gtest reads
  # TEST_TMPDIR), not the shared /tmp: two build trees (a sanitizer build, a second checkout)
  # can run their tests at the same time without overwriting each other's files.
  set(tmpdir "${CMAKE_CURRENT_BINARY_DIR}/${name}.tmp")
  file(MAKE_DIRECTORY "${tmpdir}")
  # (An empty LABELS value would be dropped and shift the pairs: only given when set.)
  set(props TIMEOUT ${ARG_TIMEOUT} ENVIRONMENT "TEST_TMPDIR=${tmpdir}")
  if(ARG_LABELS)
    list(APPEND props LABELS "${ARG_LABELS}")
  endif()
  gtest_discover_tests(${name}
    WORKING_DIRECTORY "${CMAKE_BINARY_DIR}"
    DISCOVERY_TIMEOUT 60
    PROPERTIES ${props})
endfunction()

# Adds every immediate subfolder of the current folder that has a CMakeLists.txt.
function(omni_add_subdirectories)
  file(GLOB children RELATIVE "${CMAKE_CURRENT_SOURCE_DIR}" "${CMAKE_CURRENT_SOURCE_DIR}/*")
  list(SORT children)
  foreach(child ${children})
    if(IS_DIRECTORY "${CMAKE_CURRENT_SOURCE_DIR}/${child}" AND
       EXISTS "${CMAKE_CURRENT_SOURCE_DIR}/${child}/CMakeLists.txt")
      add_subdirectory(${child})
    endif()
  endforeach()
endfunction()
