"""Running nodes: parameters <-> frozen config dataclasses (:mod:`.params`), node start-up and clean
shutdown (:mod:`.node_main`), the launch-free graph runner (:mod:`.graph`)."""
