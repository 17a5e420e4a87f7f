"""The udev rules for the Minoru, installed by ``stereod install-service``."""
