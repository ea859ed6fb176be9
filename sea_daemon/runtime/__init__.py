"""The runtime: everything that runs in cycles against the hardware, one home per concept.

Owns the one fixed-rate loop (:mod:`.loop`: read → update → write → estimate → record → sleep
to an absolute deadline) that the estimation service (:mod:`.service`), the offline simulator
(:mod:`.sim_runner`) and the hardware-in-the-loop session (:mod:`.hil_session`) all run; the
hardware a run is against (:mod:`.rig`), the scenario's controller (:mod:`.controller`; its
PID and still-arm open loop are the core's, :mod:`sea_daemon.core.control`), the single fault policy (:mod:`.safety`), the
off-loop log writer (:mod:`.logwriter`) and its other outputs for labs (:mod:`.sinks`: the LSL
stream, the MCAP recording), the Theorem-1 bound's worker process (:mod:`.bound_worker`),
the counts through pipes that order the rings those two share with the loop (:mod:`.counts`)
and systemd notification (:mod:`.notify`).  May import
``sea_daemon.hw``, :mod:`sea_daemon.io`, :mod:`sea_daemon.core` and :mod:`sea_daemon.errors`.
"""
