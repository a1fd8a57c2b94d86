# viewer_test starts the real tactus-viewer binary.
add_dependencies(viewer_test tactus-viewer)
