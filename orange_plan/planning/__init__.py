"""Planning: energy roadmap, paths, speed profiles and reachability."""
