"""Simulators: one physical world and protocol-level fakes of every device the drivers talk to."""
