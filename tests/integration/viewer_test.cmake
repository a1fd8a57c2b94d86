# Browser test of the live view (included from tests/integration/CMakeLists.txt): sim_server,
# tactus-viewer and headless Chromium driven by puppeteer-core from the page's node_modules.
# Exits 77 (skipped) only when Chromium is absent; scripts/install_deps.sh installs it.
# sim_server and Chromium load both cores (about 10 s): it holds both core slots, so no test that
# computes runs beside it (tests/CMakeLists.txt, WAITS).
if(TARGET tactus-viewer AND TACTUS_NODE AND TACTUS_VIEWER_NODE_MODULES)
  add_test(NAME viewer_browser
    COMMAND ${TACTUS_NODE} ${CMAKE_CURRENT_SOURCE_DIR}/viewer_test.mjs
            --build ${PROJECT_BINARY_DIR} --source ${PROJECT_SOURCE_DIR}
            --node-modules ${TACTUS_VIEWER_NODE_MODULES}
            --out ${PROJECT_BINARY_DIR}/test-artifacts/viewer)
  set_tests_properties(viewer_browser PROPERTIES
    LABELS "integration;viewer" RESOURCE_GROUPS cores:2 TIMEOUT 90 SKIP_RETURN_CODE 77)
else()
  message(STATUS "viewer_browser test not registered: node/npm missing or TACTUS_VIEWER_WEB=OFF")
endif()
