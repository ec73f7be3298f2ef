"""pos_master_node: the main POS (master IMU + GNSS devices, mechanization, IFA feedback)."""
