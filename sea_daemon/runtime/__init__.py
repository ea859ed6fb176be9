"""The estimation service on the exoskeleton controller.

Owns the one fixed-rate loop (:mod:`.loop`: read → control → write → estimate → log → sleep to an
absolute deadline), the single fault policy (:mod:`.safety`), the off-loop log writer
(:mod:`.logwriter`), systemd notification (:mod:`.notify`) and the service around them
(:mod:`.service`).  May import ``drivers``, :mod:`sea_daemon.io`, :mod:`sea_daemon.core` and
:mod:`sea_daemon.errors`.
"""
