"""The simulated true plant: the SEA exoskeleton with a human forearm, as the estimator never sees it.

:mod:`.plant` — nominal model plus hidden effects, integrated by RK4 at a fine substep;
:mod:`.sensors` — absolute encoders (quantisation, offsets) and motor-torque noise.  The device
model (``sea_daemon.hw.device_model``) and the offline simulation (:mod:`sea_daemon.runtime`) run it.
Part of :mod:`sea_daemon.core`: numpy/scipy only.
"""
