// Placeholder until the device library's code lands.
