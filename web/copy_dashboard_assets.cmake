# Build-time step of web/CMakeLists.txt: copies the page and the three.js files it imports into
# OUT_DIR, and writes assets/vendor.json saying whether three.js is there. Never fails for a
# missing node_modules (the page then says that its 3D view is absent).
foreach(var PAGE_DIR THREE_DIR OUT_DIR)
  if(NOT DEFINED ${var})
    message(FATAL_ERROR "copy_dashboard_assets.cmake: ${var} not set")
  endif()
endforeach()

file(MAKE_DIRECTORY "${OUT_DIR}/assets")
file(COPY "${PAGE_DIR}/" DESTINATION "${OUT_DIR}")

set(three_files
    "build/three.module.js:three.module.js"
    "build/three.core.js:three.core.js"
    "examples/jsm/controls/OrbitControls.js:addons/controls/OrbitControls.js"
    "LICENSE:LICENSE")
set(three_present TRUE)
foreach(pair IN LISTS three_files)
  string(REPLACE ":" ";" pair "${pair}")
  list(GET pair 0 from)
  if(NOT EXISTS "${THREE_DIR}/${from}")
    set(three_present FALSE)
  endif()
endforeach()

set(three_version "")
if(three_present)
  foreach(pair IN LISTS three_files)
    string(REPLACE ":" ";" pair "${pair}")
    list(GET pair 0 from)
    list(GET pair 1 to)
    get_filename_component(to_dir "${OUT_DIR}/assets/three/${to}" DIRECTORY)
    file(MAKE_DIRECTORY "${to_dir}")
    file(COPY_FILE "${THREE_DIR}/${from}" "${OUT_DIR}/assets/three/${to}" ONLY_IF_DIFFERENT)
  endforeach()
  file(READ "${THREE_DIR}/package.json" three_package)
  string(JSON three_version ERROR_VARIABLE json_error GET "${three_package}" version)
  set(vendor "{\"three\": true, \"threeVersion\": \"${three_version}\"}\n")
else()
  # A stale copy from an earlier build would make the page load a three.js it was not built with.
  file(REMOVE_RECURSE "${OUT_DIR}/assets/three")
  message(STATUS "dashboard: ${THREE_DIR} incomplete (run npm ci): the page has no 3D view")
  set(vendor "{\"three\": false}\n")
endif()
file(CONFIGURE OUTPUT "${OUT_DIR}/assets/vendor.json" CONTENT "${vendor}")
