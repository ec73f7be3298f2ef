"""ifa_node: in-flight alignment (ADD2) of the main POS against GNSS."""
