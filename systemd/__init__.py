"""The systemd units and default configuration, installed by ``stereod install-service``."""
