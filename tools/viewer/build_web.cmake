# Builds the live view page into OUT: copies package.json and package-lock.json, runs `npm ci`
# when the lock changed (packages from the npm registry, pinned by the lock; nothing from a CDN),
# bundles SRC/src/main.js with esbuild into OUT/dist/app.js and copies the static files.
# Invoked by the tactus-viewer-web target and by scripts/view:
#   cmake -DSRC=<web sources> -DOUT=<build dir> -DNPM=npm -DNODE=node -P build_web.cmake
foreach(v SRC OUT NPM NODE)
  if(NOT ${v})
    message(FATAL_ERROR "build_web.cmake: -D${v}=... is required")
  endif()
endforeach()
file(MAKE_DIRECTORY ${OUT}/dist)
file(COPY ${SRC}/package.json ${SRC}/package-lock.json DESTINATION ${OUT})
set(_stamp ${OUT}/node_modules/.tactus-lock)
set(_need_ci TRUE)
if(EXISTS ${_stamp})
  file(READ ${_stamp} _old)
  file(READ ${SRC}/package-lock.json _new)
  if(_old STREQUAL _new)
    set(_need_ci FALSE)
  endif()
endif()
if(_need_ci)
  message(STATUS "viewer page: npm ci in ${OUT}")
  execute_process(COMMAND ${NPM} ci --no-audit --no-fund --prefer-offline --loglevel=error
                  WORKING_DIRECTORY ${OUT} RESULT_VARIABLE _rc)
  if(NOT _rc EQUAL 0)
    message(FATAL_ERROR "viewer page: `npm ci` failed in ${OUT} (no network access to the npm "
                        "registry?). Retry when online, or configure with -DTACTUS_VIEWER_WEB=OFF "
                        "to build without the page.")
  endif()
  configure_file(${SRC}/package-lock.json ${_stamp} COPYONLY)
endif()
# esbuild resolves `three` from OUT/node_modules through NODE_PATH (the sources stay in the repo)
set(_esbuild ${OUT}/node_modules/.bin/esbuild)
execute_process(
  COMMAND ${CMAKE_COMMAND} -E env NODE_PATH=${OUT}/node_modules
          ${_esbuild} ${SRC}/src/main.js --bundle --minify --sourcemap --format=esm
          --target=es2020 --log-level=warning --outfile=${OUT}/dist/app.js
  RESULT_VARIABLE _rc)
if(NOT _rc EQUAL 0)
  message(FATAL_ERROR "viewer page: esbuild failed")
endif()
file(COPY ${SRC}/index.html ${SRC}/style.css DESTINATION ${OUT}/dist)
