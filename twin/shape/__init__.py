"""The paper's second model (§7): an object's contour predicted from finger positions and torques by
a small feed-forward network, trained offline on sweep datasets and evaluated on whole trajectories it
never saw. Reads datasets and readings only (never a backend)."""
