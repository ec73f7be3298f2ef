"""pos_master_node: the main POS (master IMU + GNSS devices, mechanization, IFA feedback).

Modules: :mod:`pos_master_node.node` (the node: chooses and wires a source and a navigator),
:mod:`pos_master_node.sources` (``device``: simulated device or driver relay),
:mod:`pos_master_node.navigators` (``alignment``: what /master/nav is), :mod:`pos_master_node.params`.
"""

#: the node's default name; also the name of its /pos_master/status entry
NODE_NAME = "pos_master_node"
