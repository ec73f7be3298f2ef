"""Readers of real sensor logs (no ROS): IMU CSV logs with a column mapping, RTKLIB time tags and
RTKLIB ``.pos`` solutions.  ``dpos-import`` (dpos_ros.cli.import_) turns their output into bags."""
