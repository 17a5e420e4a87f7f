"""The running service: threads, capture, processing, output, status, reload and systemd."""
