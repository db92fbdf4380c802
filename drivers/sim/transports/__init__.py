"""The simulated wires, mirroring drivers/transports/: the register-level I2C bus and the wire a USB bridge
drives, a pty pair for serial firmware, and the USB bridges' HID and pyusb fakes."""
