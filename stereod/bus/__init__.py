"""The wire: message models, Zenoh keys, the daemon's publisher, text subscriber and images."""
