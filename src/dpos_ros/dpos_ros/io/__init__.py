"""Recordings: rosbag2 read/write (:mod:`.bag`), the crash-safe spill of transfer_align_node
(:mod:`.spill`), a recorded session as arrays (:mod:`.session`), dpos-record (:mod:`.record`) and
dpos-play (:mod:`.play`)."""
