"""Transfer alignment of the sub-IMUs against the main POS ([Gong2018])."""
