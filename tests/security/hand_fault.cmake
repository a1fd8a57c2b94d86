# The fault suite for the hand (hand_fault_test.cpp) drives haptic_server with the misbehaving
# test plugin and the bridge's reference client: build them first.
if(TARGET security_tests)
  add_dependencies(security_tests tactus_test_plugin_fault tactus-bridge-client)
endif()
