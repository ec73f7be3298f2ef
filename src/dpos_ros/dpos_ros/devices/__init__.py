"""Sensor data sources of the device nodes: the simulated devices with flow control
(:mod:`.sim_device`, streams from :mod:`.sim_streams`) and the relay of real drivers (:mod:`.relay`)."""
