# Sanitizers for the whole build (presets `dev` = address;undefined, `tsan` = thread).
if(NCCOMP_SANITIZE)
  string(REPLACE ";" "," _san "${NCCOMP_SANITIZE}")
  add_compile_options(-fsanitize=${_san} -fno-omit-frame-pointer -fno-sanitize-recover=all)
  add_link_options(-fsanitize=${_san})
  if("thread" IN_LIST NCCOMP_SANITIZE)
    # Eigen and the standard library are fine under TSan; nothing to exclude.
    add_compile_definitions(NCCOMP_TSAN=1)
  endif()
  if("address" IN_LIST NCCOMP_SANITIZE)
    add_compile_definitions(NCCOMP_ASAN=1)
  endif()
endif()
