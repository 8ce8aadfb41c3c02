//! Occupancy grid, frontiers, A*, path shortcutting, the greedy follower and forward dynamics.
