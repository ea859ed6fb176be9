"""The estimation service on the exoskeleton controller: loop, logging, systemd glue."""
