# jitter_replay_test: the snapshot file format (shared) and the jitter tool's replay rig, which
# lives in tactus_jitter_core; the integration test runs tactus-bench and tactus-jitter by path.
if(TARGET jitter_replay_test AND TARGET tactus_jitter_core)
  target_link_libraries(jitter_replay_test PRIVATE tactus_jitter_core)
  add_dependencies(jitter_replay_test tactus-bench tactus-jitter sim_server)
endif()
