"""Hardware interfaces and real-protocol drivers (ESP300, USB2000+, PTP camera)."""
