# The fault suite for the hand (hand_fault_test.cpp) drives haptic_server with the misbehaving
# test plugin and the bridge's reference client: build them first.
if(TARGET hand_fault_test)
  add_dependencies(hand_fault_test tactus_test_plugin_fault tactus-bridge-client)
endif()
