"""Transfer alignment of the sub-IMUs against the main POS (seed 000)."""
