"""The evaluation room: the estimators run on simulated sessions and compared with the truth.

The only part of the core that sees both the simulator (:mod:`dpos_core.sim`) and the estimation
packages (:mod:`dpos_core.ta`, :mod:`dpos_core.ifa`, :mod:`dpos_core.sar`, :mod:`dpos_core.filters`):
the estimation packages import neither the simulator nor this room (test/test_layering.py).

- :mod:`.ifa`: Monte Carlo of the in-flight alignment (ADD2 / DD2 / AEKF) on simulated sessions;
- :mod:`.ta`: a simulated session as the transfer alignment's inputs, and its truth;
- :mod:`.sar`: Monte Carlo of the SINS/SAR/baro navigation ([Yan2016]);
- :mod:`.mismatch`: simulated sessions whose world differs from the filter's configuration.
"""
