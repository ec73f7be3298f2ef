"""Composable estimation pieces: point sets, Gaussian filters (KF, UKF, DD2) and smoothers
(RTS, URTSS), particle filters and smoothers.  Everything is batched over leading axes (e.g.
particles) and vectorized over sigma points / particles."""
