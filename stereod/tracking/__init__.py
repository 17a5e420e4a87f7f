"""3D observations to tracks: association, Kalman filters, lifecycle and motion (speed, heading)."""
