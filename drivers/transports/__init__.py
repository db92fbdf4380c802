"""Transports: timeouts, bounded retries, reconnects and raw-frame logging for I2C, serial and Modbus."""
