"""What every daemon process shares with the system: real-time set-up and systemd's notify."""
