"""SINS/SAR/baro integrated navigation ([Yan2016]): the 16-state error model with an attitude-error
quaternion (model.py), its filters - EKF, UKF, the particle filters of filters/pf.py and the
oracle (pipeline.py); its Monte Carlo evaluation on simulated sessions is :mod:`dpos_core.evaluation.sar`."""
