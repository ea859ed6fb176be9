"""The simulated true plant: the SEA exoskeleton with a human forearm, as the estimator never sees it.

:mod:`.plant` — nominal model plus hidden effects, integrated by RK4 at a fine substep;
:mod:`.sensors` — absolute encoders (quantisation, offsets) and motor-torque noise;
:mod:`.sampling` — one sample of every simulated run (the plant stepped and read like the
hardware, the row it records); :mod:`.session` — sessions built from parts (any reference,
subject, the still arm) over those samples; :mod:`.subject` — a subject doing a task.  The
device model (``sea_daemon.hw.device_model``) and the offline simulation (:mod:`sea_daemon.runtime`,
over :class:`sea_daemon.hw.sim_hw.SimHardware`, which reads through :class:`.sampling.SampledPlant`) run it.
Part of :mod:`sea_daemon.core`: numpy/scipy only.
"""
