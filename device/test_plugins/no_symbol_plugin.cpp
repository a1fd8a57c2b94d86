// Test fixture: a shared library that loads but does not export tactus_device_plugin.
extern "C" int tactus_not_a_device_plugin(void) { return 42; }
