"""transfer_align_node: buffers the session, runs the smoother at its end, publishes antenna poses."""
