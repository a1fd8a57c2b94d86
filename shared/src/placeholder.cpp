// Placeholder until the shared library's code lands.
