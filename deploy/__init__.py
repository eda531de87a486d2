"""What a robot-cell PC runs: the service, its command-line interface and configuration."""
