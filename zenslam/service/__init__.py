"""What makes zenslam a service: sources, bus, recorder, supervisor, configuration, evaluation, CLI."""
