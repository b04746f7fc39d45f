"""The runtime layer under the stages: bus, supervisor, stage start-up."""
