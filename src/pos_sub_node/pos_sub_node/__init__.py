"""pos_sub_node: one sub-IMU device per node instance."""
