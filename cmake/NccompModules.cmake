# Core modules: each folder under core/ is an OBJECT library `nccomp_core_<name>`; the static
# library `nccomp_core` is assembled from all of them. A module's tests link only the objects they
# need, so work in one module never breaks the build of another.
#
#   nccomp_core_module(NAME creep SOURCES a.cpp b.cpp [DEPENDS base ...])
function(nccomp_core_module)
  cmake_parse_arguments(M "" "NAME" "SOURCES;DEPENDS" ${ARGN})
  set(tgt nccomp_core_${M_NAME})
  add_library(${tgt} OBJECT ${M_SOURCES})
  target_link_libraries(${tgt} PUBLIC nccomp_core_headers)
  foreach(dep ${M_DEPENDS})
    # Usage requirements only; objects are linked by nccomp_core or by the test that names them.
    target_include_directories(${tgt} PUBLIC
      $<TARGET_PROPERTY:nccomp_core_${dep},INTERFACE_INCLUDE_DIRECTORIES>)
  endforeach()
  set_target_properties(${tgt} PROPERTIES POSITION_INDEPENDENT_CODE ON)
  nccomp_set_warnings(${tgt})
  set_property(GLOBAL APPEND PROPERTY NCCOMP_CORE_MODULES ${tgt})
  set_property(TARGET ${tgt} PROPERTY NCCOMP_DEPENDS "${M_DEPENDS}")
endfunction()

# The objects of a module and of every module it depends on, transitively.
function(nccomp_core_objects out)
  set(result "")
  set(queue ${ARGN})
  while(queue)
    list(POP_FRONT queue m)
    if(NOT "nccomp_core_${m}" IN_LIST result)
      list(APPEND result nccomp_core_${m})
      get_target_property(deps nccomp_core_${m} NCCOMP_DEPENDS)
      if(deps)
        list(APPEND queue ${deps})
      endif()
    endif()
  endwhile()
  set(${out} ${result} PARENT_SCOPE)
endfunction()

# Subcommands of the operator command `nccomp`: each is an OBJECT library that registers itself
# (see tools/nccomp/command.hpp); `nccomp` links every one that exists.
#   nccomp_command(NAME grind SOURCES cmd_grind.cpp LIBS ...)
function(nccomp_command)
  cmake_parse_arguments(C "" "NAME" "SOURCES;LIBS" ${ARGN})
  set(tgt nccomp_cmd_${C_NAME})
  add_library(${tgt} OBJECT ${C_SOURCES})
  target_link_libraries(${tgt} PUBLIC nccomp_cli_support ${C_LIBS})
  nccomp_set_warnings(${tgt})
  set_property(GLOBAL APPEND PROPERTY NCCOMP_COMMANDS ${tgt})
endfunction()
