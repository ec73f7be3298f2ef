"""sar_nav_node: SINS/SAR/barometer navigation of the main POS ([Yan2016]; docs/sar.md)."""
