"""Mapping and loop closing: the map, its graphs, local BA, place recognition, pose-graph optimisation."""
